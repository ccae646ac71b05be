"""The floors of candidate bake forms: how much of a lobe's variation about r each form could keep.

The bake reads I_A, I_B as products P(a) W(n.v) about one axis a per layer (r, or r leant towards n). At a
pair's exact (n.v = x, roughness), with infinitely many terms, layers and texels, such a form reads the lobe's
azimuth mean about r (the kernel k_0(gamma), gamma = angle(r, l)): the form's floor
(:mod:`bake_breakdown`). Candidate forms that keep more of the lobe g(l) (times n.l), each at its own
least-squares optimum over the sphere of lights (uniform measure: the error under a point light, which is what
a sun or a lamp reflection is) at the pair's (x, roughness):

* ``r``: k_0(gamma) (today's form, the floor);
* ``r+sun``: k_0 on the environment without its brightest sources, plus those sources as point lights
  shaded with the exact lobe (:func:`sources`: zero texture fetches, a few lights' BRDF evaluations in the
  shader; the sources' direction, RGB power in bake.json); ``r+h2+sun`` the same with ``r+h2``;
* ``r+h1``: k_0(gamma) + k_1(gamma) cos(omega), omega the light's azimuth about r measured from the plane of
  incidence (towards n): the first azimuthal harmonic, a vector map P_1(r) read as P_1(r) . t with
  t = normalize(n - x r) (three more maps per term);
* ``r+h2``: with the second harmonic k_2(gamma) cos(2 omega) as well (a symmetric-tensor map, five more);
* ``r+h2o``: k_0 + k_2 cos(2 omega) (the second harmonic without the first);
* ``r+h2lum``: k_0 + k_2 cos(2 omega) with the harmonic's part from the luminance, coloured as the k_0 part
  (the tensor map in one channel per component: 5 channels, two RGBA textures with P's RGB at K = 1);
* ``r+h2B``: the second harmonic for I_B only;
* ``r+n``: k_r(gamma) + k_n(n.l): a second product about the normal (a map Q(n) per layer, as E_d but with
  the specular lobe's kernel), both kernels fitted jointly;
* ``r+-``: k_+(angle(a_+, l)) + k_-(angle(a_-, l)), a_+- = r rotated by +-``--pm`` alpha towards and away from
  n in the plane of incidence: two products about two axes, kernels fitted jointly (the same maps' form as
  today's two terms, each term read at its own axis);
* ``taps``: k(angle(a_+, l)) + k(angle(a_-, l)), one kernel read at two symmetric taps a_+- (angle beta from r
  in the plane of incidence, the best of :data:`TAPS` x alpha per pair): one map read twice, beta a weight-table
  channel (the lobe's elongation at grazing views is the second harmonic cos(2 omega)).

Per pair the forms are evaluated as point sums over the environment's light texels at ``--lights``
resolution, against the same point sum of the exact lobe (so only the form's error is measured, not the light
resolution's), on :mod:`bake_breakdown`'s draws of the benchmark's pairs and materials; reported: nrmse of L
(the reference's I_d, so only the specular terms' error counts) and |e_B| / |L|, and the idealized split-sum's
nrmse on the same pairs against the converged reference (for the ratio the goal reads).

    PYTHONPATH=src python benchmarks/bake_form.py studio --bands 2 [--pairs 150] [--lights 64]
    PYTHONPATH=src python benchmarks/bake_form.py city --bands 1 --lights 128 --forms r,r+h2,taps
    PYTHONPATH=src python benchmarks/bake_form.py --kernels 0.2,0.45   # point-light residuals per (x, rho)

Cost: about 0.2 s per pair per form, several seconds per pair with ``taps`` (six least-squares fits) or ``r+n``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.bake.kernels import _frame, _local
from homofac.brdf.gltf import gltf_lobes_at
from homofac.io.exr import read_exr
from homofac.light.integrals import material_radiance
from homofac.light.reference import reference_integrals, source_map

sys.path.insert(0, str(Path(__file__).parent))
import bake_accuracy as ba  # noqa: E402

FORMS = ("r", "r+sun", "r+h2+sun", "r+h1", "r+h2", "r+h2o", "r+h2lum", "r+h2B", "r+n", "r+-", "taps")

#: Rec. 709 luminance.
LUMA = np.array([0.2126, 0.7152, 0.0722])

#: the "taps" form's candidate tap angles, in units of alpha (the best per (x, rho) is kept).
TAPS = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0)

#: the "r+-" form's axes: r rotated by +-PM alpha towards and away from n in the plane of incidence.
PM = 0.5


def lobes(rho: float, x: float, l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(1 - s5) S n.l and s5 S n.l at lights ``l`` (..., 3) in the frame r = +z, n = (sin theta, 0, x)."""
    th = np.arccos(np.clip(x, -1.0, 1.0))
    n = np.array([np.sin(th), 0.0, np.cos(th)])
    v = 2 * x * n - np.array([0.0, 0.0, 1.0])
    nj = jnp.asarray(n)[None]
    t, b = _frame(nj)
    lj = jnp.asarray(l.reshape(-1, 3))
    wi = _local(lj, t, b, nj)
    wo = _local(jnp.asarray(v)[None], t, b, nj)
    above = wi[2] > 0
    wi = (jnp.where(above, wi[0], 0.0), jnp.where(above, wi[1], 0.0), jnp.where(above, wi[2], 1.0))
    _, ga, gb = gltf_lobes_at(rho, wi, wo)
    cos = jnp.where(above, wi[2], 0.0)
    return (np.asarray(ga * cos).reshape(l.shape[:-1]), np.asarray(gb * cos).reshape(l.shape[:-1]))


def _tables(rho: float, x: float, nodes: int = 384, azimuths: int = 96, mu_nodes: int = 320, joint: bool = True, forms=FORMS) -> dict:
    """Each form's kernels at (x, rho), fitted in least squares over the sphere of lights (uniform measure).

    Grid: q = sin(gamma/2) = u^2, u uniform (fine at the axis), omega in (0, pi) (the lobes are symmetric about
    the plane of incidence). Returns the tables: ``k0, k1, k2`` over the u nodes; ``kr`` over u and ``kn`` over
    mu = n.l uniform in [-1, 1] (``r+n``, the joint least squares)."""
    u = np.linspace(0.0, 1.0, nodes)
    q = u * u
    gam = 2 * np.arcsin(q)
    om = (np.arange(azimuths) + 0.5) * np.pi / azimuths
    G, O = np.meshgrid(gam, om, indexing="ij")
    l = np.stack([np.sin(G) * np.cos(O), np.sin(G) * np.sin(O), np.cos(G)], -1)
    th = np.arccos(x)
    mu = l @ np.array([np.sin(th), 0.0, np.cos(th)])
    w = np.broadcast_to((np.gradient(q) * q * 4)[:, None], G.shape) * (np.pi / azimuths)
    rowsum = np.maximum(w.sum(1), 1e-300)
    out = {}
    pos = (mu + 1) / 2 * (mu_nodes - 1)
    i0 = np.clip(np.floor(pos).astype(int), 0, mu_nodes - 2)
    f = pos - i0
    rows = np.broadcast_to(np.arange(nodes)[:, None], G.shape)
    parts = [(rows, np.ones_like(f)), (nodes + i0, 1 - f), (nodes + i0 + 1, f)]
    size = nodes + mu_nodes
    normal = np.zeros((size, size))
    for ii, wa in parts if joint else ():
        for jj, wb in parts:
            np.add.at(normal, (ii.ravel(), jj.ravel()), (w * wa * wb).ravel())
    normal += np.eye(size) * 1e-10 * np.trace(normal) / size
    pm = "r+-" in forms
    if pm:
        beta = PM * rho * rho
        ipm, wpm = [], []
        for sgn in (1.0, -1.0):
            ca = l @ np.array([sgn * np.sin(beta), 0.0, np.cos(beta)])
            pu = np.sqrt(np.sqrt(np.clip((1 - ca) / 2, 0.0, 1.0))) * (nodes - 1)
            j0 = np.clip(np.floor(pu).astype(int), 0, nodes - 2)
            ipm += [j0 + (0 if sgn > 0 else nodes), j0 + 1 + (0 if sgn > 0 else nodes)]
            wpm += [1 - (pu - j0), pu - j0]
        npm = np.zeros((2 * nodes, 2 * nodes))
        for ii, wa in zip(ipm, wpm):
            for jj, wb in zip(ipm, wpm):
                np.add.at(npm, (ii.ravel(), jj.ravel()), (w * wa * wb).ravel())
        npm += np.eye(2 * nodes) * 1e-10 * np.trace(npm) / (2 * nodes)
    taps = []
    if "taps" in forms:
        for be in TAPS:
            beta = min(be * rho * rho, 1.2)
            ii_, ww_ = [], []
            for sgn in (1.0, -1.0):
                ca = l @ np.array([sgn * np.sin(beta), 0.0, np.cos(beta)])
                pu = np.sqrt(np.sqrt(np.clip((1 - ca) / 2, 0.0, 1.0))) * (nodes - 1)
                j0 = np.clip(np.floor(pu).astype(int), 0, nodes - 2)
                ii_ += [j0, j0 + 1]
                ww_ += [1 - (pu - j0), pu - j0]
            nt = np.zeros((nodes, nodes))
            for ii, wa in zip(ii_, ww_):
                for jj, wb in zip(ii_, ww_):
                    np.add.at(nt, (ii.ravel(), jj.ravel()), (w * wa * wb).ravel())
            nt += np.eye(nodes) * 1e-10 * np.trace(nt) / nodes
            taps.append((beta, ii_, ww_, nt))
    for lobe, g in zip("AB", lobes(rho, x, l)):
        k0 = np.sum(w * g, 1) / rowsum
        c1, c2 = np.cos(om)[None], np.cos(2 * om)[None]
        k1 = np.sum(w * g * c1, 1) / np.maximum(np.sum(w * c1 * c1, 1), 1e-300)
        k2 = np.sum(w * g * c2, 1) / np.maximum(np.sum(w * c2 * c2, 1), 1e-300)
        rhs = np.zeros(size)
        for ii, wa in parts if joint else ():
            np.add.at(rhs, ii.ravel(), (w * wa * g).ravel())
        sol = np.linalg.solve(normal, rhs) if joint else np.zeros(size)
        out[lobe] = {"k0": k0, "k1": k1, "k2": k2, "kr": sol[:nodes], "kn": sol[nodes:]}
        if pm:
            rp = np.zeros(2 * nodes)
            for ii, wa in zip(ipm, wpm):
                np.add.at(rp, ii.ravel(), (w * wa * g).ravel())
            spm = np.linalg.solve(npm, rp)
            out[lobe]["kp"], out[lobe]["km"], out[lobe]["beta"] = spm[:nodes], spm[nodes:], beta
            gp = sum(wa * spm[ii] for ii, wa in zip(ipm, wpm))
        total = np.sum(w * g * g)
        res = {"r": g - k0[:, None], "r+h1": g - k0[:, None] - k1[:, None] * c1}
        res["r+h2"] = res["r+h1"] - k2[:, None] * c2
        res["r+n"] = g - sol[:nodes][:, None] - ((1 - f) * sol[nodes:][i0] + f * sol[nodes:][i0 + 1])
        if pm:
            res["r+-"] = g - gp
        if taps:
            best = None
            for beta, ii_, ww_, nt in taps:
                rt = np.zeros(nodes)
                for ii, wa in zip(ii_, ww_):
                    np.add.at(rt, ii.ravel(), (w * wa * g).ravel())
                kt = np.linalg.solve(nt, rt)
                e = g - sum(wa * kt[ii] for ii, wa in zip(ii_, ww_))
                err = float(np.sum(w * e * e))
                if best is None or err < best[0]:
                    best = (err, beta, kt, e)
            res["taps"] = best[3]
            out[lobe]["kt"], out[lobe]["tbeta"] = best[2], best[1]
        out[lobe]["residual"] = {k: float(np.sqrt(np.sum(w * e * e) / total)) for k, e in res.items()}
    return out


def sources(dirs: np.ndarray, power: np.ndarray, count: int = 4, radius: float = 0.15, ratio: float = 20.0):
    """The brightest compact sources of an environment as point lights: ``(light dirs (C, 3), power (C, 3),
    the light texels' power with those sources removed (L, 3))``. Greedily, the brightest remaining texel whose
    luminance per solid angle is at least ``ratio`` x the environment's mean seeds a source; the source takes the
    texels within ``radius`` rad of it whose radiance is at least 1/``ratio`` of the seed's, its direction their
    power-weighted mean, its power their sum; at most ``count`` sources."""
    lum = power @ LUMA
    rest = power.copy()
    out_d, out_p = [], []
    mean = lum.sum() / len(lum)
    for _ in range(count):
        cur = rest @ LUMA
        i = int(np.argmax(cur))
        if cur[i] < ratio * mean:
            break
        near = (dirs @ dirs[i] > np.cos(radius)) & (cur >= cur[i] / ratio)
        p = rest[near].sum(0)
        d = (rest[near] @ LUMA) @ dirs[near]
        out_d.append(d / np.linalg.norm(d))
        out_p.append(p)
        rest[near] = 0.0
    return np.array(out_d).reshape(-1, 3), np.array(out_p).reshape(-1, 3), rest


def _interp_u(table: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    u = np.sqrt(np.clip(np.sin(gamma / 2), 0.0, 1.0))
    return np.interp(u, np.linspace(0.0, 1.0, len(table)), table)


def pair_forms(rho: float, n: np.ndarray, v: np.ndarray, dirs: np.ndarray, power: np.ndarray, forms=FORMS,
               suns=None) -> dict:
    """(I_A, I_B) (3,) RGB each, per form and ``exact``: point sums over lights ``dirs`` (L, 3) of power (L, 3);
    ``suns`` :func:`sources`' output for the ``+sun`` forms."""
    x = float(n @ v)
    r = 2 * x * n - v
    t = n - x * r
    t = t / max(np.linalg.norm(t), 1e-12) if np.linalg.norm(t) > 1e-9 else np.cross(r, [0.0, 0.0, 1.0]) + [1e-3, 0, 0]
    t = t / np.linalg.norm(t)
    b = np.cross(r, t)
    lc = np.stack([dirs @ t, dirs @ b, dirs @ r], -1)  # lights in the frame r = +z, n in the x-z plane
    gamma = np.arccos(np.clip(lc[:, 2], -1.0, 1.0))
    omega = np.arctan2(lc[:, 1], lc[:, 0])
    mu = dirs @ n
    tab = _tables(rho, x, joint="r+n" in forms, forms=forms)
    ga, gb = lobes(rho, x, lc)
    out = {"exact": np.stack([ga @ power, gb @ power])}
    if suns is not None:
        sd, sp, rest = suns
        sc = np.stack([sd @ t, sd @ b, sd @ r], -1)
        sa_, sb_ = lobes(rho, x, sc) if len(sd) else (np.zeros(0), np.zeros(0))
        exact_suns = np.stack([sa_ @ sp, sb_ @ sp])
    for form in forms:
        vals = []
        pw = power
        if form.endswith("+sun"):
            pw, form = rest, form[:-4]
        for lobe in "AB":
            k = tab[lobe]
            if form == "taps":
                be = k["tbeta"]
                g = sum(_interp_u(k["kt"], np.arccos(np.clip(lc @ np.array([sg * np.sin(be), 0.0, np.cos(be)]), -1, 1)))
                        for sg in (1.0, -1.0))
            elif form == "r+-":
                be = k["beta"]
                g = sum(_interp_u(k[key], np.arccos(np.clip(lc @ np.array([sg * np.sin(be), 0.0, np.cos(be)]), -1, 1)))
                        for key, sg in (("kp", 1.0), ("km", -1.0)))
            elif form == "r+n":
                g = _interp_u(k["kr"], gamma) + np.interp(mu, np.linspace(-1, 1, len(k["kn"])), k["kn"])
            else:
                g = _interp_u(k["k0"], gamma)
                if form in ("r+h1", "r+h2"):
                    g = g + _interp_u(k["k1"], gamma) * np.cos(omega)
                if form in ("r+h2", "r+h2o") or (form == "r+h2B" and lobe == "B"):
                    g = g + _interp_u(k["k2"], gamma) * np.cos(2 * omega)
                if form == "r+h2lum":  # the harmonic from the luminance, coloured as the isotropic part
                    p0 = g @ pw
                    h2 = (_interp_u(k["k2"], gamma) * np.cos(2 * omega)) @ (pw @ LUMA)
                    vals.append(p0 * (1.0 + h2 / max(float(p0 @ LUMA), 1e-30)))
                    continue
            vals.append(g @ pw)
        out[form + ("+sun" if pw is not power else "")] = np.stack(vals) + (exact_suns if pw is not power else 0.0)
    return out


def main(argv=None):
    global PM
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("env", nargs="?", default="studio")
    ap.add_argument("--bands", nargs="+", type=int, default=[2])
    ap.add_argument("--pairs", type=int, default=150)
    ap.add_argument("--lights", type=int, default=64)
    ap.add_argument("--samples", type=int, default=8192)
    ap.add_argument("--forms", default="r,r+h1,r+h2", help=f"comma-separated, of {','.join(FORMS)}")
    ap.add_argument("--pm", type=float, default=PM, help="the r+- form's axis angle in units of alpha")
    ap.add_argument("--suns", type=int, default=4, help="at most this many sources for the +sun forms")
    ap.add_argument("--kernels", default=None, help="comma-separated roughnesses: print the point-light residuals per (x, rho)")
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    PM = args.pm
    if args.kernels:
        for rho in (float(s) for s in args.kernels.split(",")):
            for x in (0.05, 0.15, 0.3, 0.5, 0.7, 0.9):
                tab = _tables(rho, x, joint="r+n" in args.forms.split(","), forms=args.forms.split(","))
                print(json.dumps({"rho": rho, "x": x, **{f"{lobe}": {k: round(e, 3) for k, e in tab[lobe]["residual"].items()}
                                                        for lobe in "AB"}}), flush=True)
        return
    name = args.env
    src = source_map(read_exr(hf.light.bundled(name)), name)
    uniform = source_map(np.ones((8, 16, 3)))
    env = hf.light.load_environment(name, args.lights)
    dirs = np.asarray(env.directions, np.float64)
    power = np.asarray(env.radiance, np.float64) * np.asarray(env.solid_angle, np.float64)[:, None]
    suns = sources(dirs, power, args.suns)
    print(json.dumps({"env": name, "sources": [{"dir": [round(float(a), 4) for a in d], "power": [round(float(a), 4) for a in p]}
                                               for d, p in zip(*suns[:2])],
                      "source_share": round(float((suns[1] @ LUMA).sum() / (power @ LUMA).sum()), 4)}), flush=True)
    rng = np.random.default_rng(0)
    for _ in range(4 * list(hf.light.BUNDLED).index(name)):  # the benchmark's draws (bake_breakdown's)
        ba.pairs(args.pairs, rng), ba.materials(args.pairs, (0.0, 1.0), rng)
    draws = [(ba.pairs(args.pairs, rng), ba.materials(args.pairs, band, rng)) for band in ba.BANDS]
    for bi in args.bands:
        t0 = time.perf_counter()
        (n, v), (c, m, rho) = draws[bi]
        ref = np.asarray(reference_integrals(src, n, v, rho, samples=args.samples), np.float64)
        ideal = ba.ideal_split_sum(src, uniform, name, n, v, rho, args.samples)
        forms = args.forms.split(",")
        per = [pair_forms(float(rho[i]), n[i], v[i], dirs, power, forms, suns) for i in range(len(rho))]
        L = np.asarray(material_radiance(jnp.asarray(ref), c, m))
        f0 = (1 - m)[:, None] * 0.04 + m[:, None] * c
        row = {"env": name, "band": ba.BANDS[bi], "lights": args.lights, "suns": len(suns[0]),
               "ideal_vs_reference": round(float(np.linalg.norm(np.asarray(material_radiance(jnp.asarray(ideal), c, m)) - L)
                                                 / np.linalg.norm(L)), 4)}
        x = np.sum(n * v, 1)
        exact = np.stack([p["exact"] for p in per])  # (N, 2, 3)
        Le = np.asarray(material_radiance(jnp.asarray(np.concatenate([ref[:, :1], exact], 1)), c, m))
        for form in forms:
            got = np.stack([p[form] for p in per])
            Lf = np.asarray(material_radiance(jnp.asarray(np.concatenate([ref[:, :1], got], 1)), c, m))
            e2 = np.sum((Lf - Le) ** 2, 1)
            row[form] = {"nrmse_L": round(float(np.sqrt(e2.sum()) / np.linalg.norm(Le)), 4),
                         "A_share": round(float(np.linalg.norm(f0 * (got[:, 0] - exact[:, 0])) / np.linalg.norm(Le)), 4),
                         "B_share": round(float(np.linalg.norm(got[:, 1] - exact[:, 1]) / np.linalg.norm(Le)), 4),
                         "grazing_share": round(float(e2[x < 0.3].sum() / e2.sum()), 3)}
        row["pointsum_vs_reference"] = round(float(np.linalg.norm(Le - L) / np.linalg.norm(L)), 4)
        row["seconds"] = round(time.perf_counter() - t0, 1)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
