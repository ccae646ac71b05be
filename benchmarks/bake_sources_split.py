"""A saved converged cell's error split by analytic source, by angle from the sources, by n.v and by roughness.

On the pairs of ``bake_accuracy.py --save-pairs DIR`` (NAME-BAND.npz: the converged cell's weighted pairs and the
reference's (I_d, I_A, I_B)) and a saved bake (its sources), with the lat-long's cores taken by the rule of
:func:`homofac.bake.sources.brightest_source` repeated once per bake source on the reference's own pixels
(:func:`bake_source_floor.split_core`; the reference is linear in its image, so ref = sum_i ref(core_i) + ref(rest)):

* ``src`` = L(sum of the bake's analytic terms) - L(sum_i ref(core_i)); ``maps`` = L(the bake without its analytic
  terms) - L(ref(rest)): the maps' error with every source shaded exactly (the floor of the maps); their sum is the
  bake's error. The per-source split pairs source i with the i-th lat-long core, which need not be the same
  pixels (the bake finds its sources on cube lights), so only the sums are read;
* each part as its share of the cell's nrmse^2 (sum w |e|^2 / sum w |L|^2), binned by the angle between the mirror
  direction and the nearest source, by n.v and by roughness; the top pairs.

    PYTHONPATH=src python benchmarks/bake_sources_split.py PAIRS/studio-0.npz BAKES/studio-balanced studio [CACHE.npz]
"""
import sys
from pathlib import Path

import numpy as np

import homofac as hf
from homofac.bake.sources import source_terms
from homofac.io.exr import read_exr
from homofac.light.latlong import latlong_directions
from homofac.light.reference import reference_integrals, source_map

sys.path.insert(0, str(Path(__file__).parent))
from bake_source_floor import radiance, split_core  # noqa: E402

pairs, bake_dir, env = sys.argv[1], sys.argv[2], sys.argv[3]
cache = Path(sys.argv[4]) if len(sys.argv) > 4 else None
z = np.load(pairs)
n, v, c, m, rho, w = (z[k] for k in ("n", "v", "c", "m", "rho", "w"))
ref = z["reference_parts"].astype(np.float64)
L = radiance(ref, c, m)
print("check L vs saved reference", float(np.abs(L - z["reference"]).max()), float(np.abs(z["reference"]).max()))
b = hf.load(bake_dir)
image = read_exr(hf.light.bundled(env))[..., :3].astype(np.float64)
full = source_map(image)
# lat-long cores, repeated like brightest_source
rest = image
if cache is not None and cache.exists():
    zc = np.load(cache); refcs = list(zc["refcs"]); cdirs = list(zc["cdirs"])
else:
    refcs, cdirs = [], []
    h, wd = image.shape[:2]
    dirs = latlong_directions(h, wd).reshape(-1, 3)
    for i in range(len(b.sources)):
        core, rest = split_core(rest)
        cm = source_map(core)
        lum = core.reshape(-1, 3) @ np.array([0.2126, 0.7152, 0.0722])
        dmean = lum @ dirs; dmean /= np.linalg.norm(dmean)
        cdirs.append(dmean)
        refcs.append(reference_integrals(cm, n, v, rho, samples=4096) * (np.asarray(full.scale) / np.asarray(cm.scale))[None, None, :])
    if cache is not None:
        np.savez(cache, refcs=np.array(refcs), cdirs=np.array(cdirs))
an = [np.asarray(source_terms([s], n, v, rho), np.float64) for s in b.sources]
tot = np.asarray(b.terms(n, v, rho), np.float64)
maps = tot - sum(an)
x = np.sum(n * v, 1)
r = 2 * x[:, None] * n - v
den = np.sum(w * np.sum(L * L, 1))
def part(e, mask=None):
    mask = np.ones(len(e), bool) if mask is None else mask
    return float(np.sum((w * np.sum(e * e, 1))[mask]) / den)
bake_e = radiance(tot - ref, c, m)
print("bake nrmse", np.sqrt(part(bake_e)))
for i, s in enumerate(b.sources):
    ang = np.degrees(np.arccos(np.clip(cdirs[i] @ np.asarray(s.direction), -1, 1)))
    print(f"source {i}: {s.describe()}  latlong core dir off {ang:.2f} deg; refcore lum power")
es = [radiance(an[i] - refcs[i], c, m) for i in range(len(an))]
em = radiance(maps - (ref - sum(refcs)), c, m)
print("src errs^2 each", [round(part(e), 5) for e in es], "sum src", round(part(sum(es)), 5), "maps", round(part(em), 5), "maps nrmse", round(np.sqrt(part(em)), 4))
print("maps AB only", round(np.sqrt(part(radiance((maps - (ref - sum(refcs)))*np.array([0,1,1])[None,:,None], c, m))), 4))
# by angle of mirror from nearest source
dirs = np.array([s.direction for s in b.sources])
angs = np.degrees(np.arccos(np.clip(r @ dirs.T, -1, 1)))  # N, S
near = angs.argmin(1); amin = angs.min(1)
wL = w * np.sum(L * L, 1) / den
print("\nby angle to nearest source (deg): bins, weight share, L^2 share, bake err^2, src err^2, maps err^2, signed maps")
edges = [0, 1, 2, 3, 5, 8, 12, 20, 45, 90, 180]
for lo, hi in zip(edges[:-1], edges[1:]):
    mk = (amin >= lo) & (amin < hi)
    sg = float(np.sum((w * np.sum(em * L, 1))[mk]) / max(np.sum((w*np.sum(L*L,1))[mk]),1e-30))
    print(f"{lo:3d}-{hi:3d}: w {w[mk].sum()/w.sum():.3f} L2 {wL[mk].sum():.3f} bake {part(bake_e, mk):.5f} src {part(sum(es), mk):.5f} maps {part(em, mk):.5f} signed_maps {sg:+.3f} nearest {np.bincount(near[mk], minlength=len(dirs))}")
print("\nby source nearest (within 12 deg): bake / src_i / maps")
for i in range(len(dirs)):
    mk = (near == i) & (amin < 12)
    print(i, round(part(bake_e, mk), 5), round(part(es[i], mk), 5), round(part(em, mk), 5), "L2", round(wL[mk].sum(), 3))
print("\nby n.v")
for lo, hi in [(0, .1), (.1, .3), (.3, .7), (.7, 1.01)]:
    mk = (x >= lo) & (x < hi)
    print(f"{lo}-{hi}: L2 {wL[mk].sum():.3f} bake {part(bake_e, mk):.5f} src {part(sum(es), mk):.5f} maps {part(em, mk):.5f}")
print("\nby roughness")
for lo, hi in [(0.045, .07), (.07, .1), (.1, .125), (.125, .15)]:
    mk = (rho >= lo) & (rho < hi)
    print(f"{lo}-{hi}: L2 {wL[mk].sum():.3f} bake {part(bake_e, mk):.5f} src {part(sum(es), mk):.5f} maps {part(em, mk):.5f}")
ideal = z["split_sum_ideal"].astype(np.float64)
print("ideal nrmse", np.sqrt(part(ideal - L)))
order = np.argsort(-(w * np.sum(bake_e ** 2, 1)))[:12]
print("\ntop pairs: share rho nv angs(deg) | L | bake | src_e | maps_e (lum)")
Y = np.array([0.2126, 0.7152, 0.0722])
for k in order:
    print(f"{(w*np.sum(bake_e**2,1))[k]/den/part(bake_e):.3f} {rho[k]:.3f} {x[k]:.3f} m{m[k]:.2f} {np.round(angs[k],1)} | {L[k]@Y:.2f} | {radiance(tot, c, m)[k]@Y:.2f} | {sum(es)[k]@Y:+.2f} | {em[k]@Y:+.2f}")
