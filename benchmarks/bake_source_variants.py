"""Prototypes of the source rule's variants (not the built rule), docs/notes/bake.md "Studio below 0.15, twentieth session".

* ``bake ENV OUT [bake flags]``: a ``balanced`` bake with the rule's constants patched from the environment:
  ``MAXS`` (MAX_SOURCES), ``MINSHARE``, ``RADIUS_``, ``RATIO_``, or ``EXTENT=CAP``: the core is the seed's
  connected region of texels at >= 1/RATIO of it (neighbours within 1.5 texel widths), within CAP rad, with the
  fill from the texels within two texel widths around it (:func:`brightest_region`: a whole softbox as one source);
* ``count ENV...``: the shares (of the map each is taken from) of the cores the built rule takes in turn, at the
  balanced bake's lights (64, the sharp block's 256), up to nine.

    MAXS=8 PYTHONPATH=src python benchmarks/bake_source_variants.py bake studio /tmp/x/studio-balanced
    PYTHONPATH=src python benchmarks/bake_source_variants.py count city forest interior studio
"""
import functools
import os
import sys

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from homofac.light.environment import LUMINANCE
import homofac as hf
from homofac.bake import build as bb
from homofac.bake import sources as hs
from homofac.bake.sources import MIN_SHARE, RATIO


def brightest_region(env, radius=None, ratio=RATIO, min_share=MIN_SHARE, cap=0.2):
    """:func:`homofac.bake.sources.brightest_source` with the core the seed's connected region (module docstring)."""
    d = np.asarray(env.directions, np.float64)
    rad = np.asarray(env.radiance, np.float64)
    dw = np.asarray(env.solid_angle, np.float64)
    lum = rad @ np.asarray(LUMINANCE, np.float64)
    seed = int(np.argmax(lum))
    step = 1.5 * float(np.sqrt(dw.max()))  # neighbours: within 1.5 texel widths
    cos = d @ d[seed]
    cand = np.flatnonzero((cos > np.cos(cap)) & (lum >= lum[seed] / ratio))
    pc = d[cand]
    near = (pc @ pc.T) > np.cos(step)
    i, j = np.nonzero(near)
    _, lab = connected_components(coo_matrix((np.ones(len(i)), (i, j)), shape=(len(cand),) * 2), directed=False)
    core_idx = cand[lab == lab[int(np.flatnonzero(cand == seed)[0])]]
    core = np.zeros(len(d), bool); core[core_idx] = True
    # ring: texels within 2 texel widths of the core, not in it
    cd = d[core_idx]
    ball = np.flatnonzero(cos > np.cos(cap + 3 * step))
    dist = (d[ball] @ cd.T).max(1)
    ring_idx = ball[(dist > np.cos(2 * step)) & ~core[ball]]
    ring = np.zeros(len(d), bool); ring[ring_idx] = True
    return hs.take_core(env, core, ring, min_share)


def bake(argv):
    """A balanced bake with the patched rule (module docstring)."""
    if "MAXS" in os.environ:
        bb.MAX_SOURCES = int(os.environ["MAXS"])
    kw = {}
    for key, name in (("MINSHARE", "min_share"), ("RADIUS_", "radius"), ("RATIO_", "ratio")):
        if key in os.environ:
            kw[name] = float(os.environ[key])
    if os.environ.get("EXTENT"):
        bb.brightest_source = functools.partial(brightest_region, cap=float(os.environ["EXTENT"]), **kw)
    elif kw:
        bb.brightest_source = functools.partial(hs.brightest_source, **kw)
    from homofac.app.bake_cli import main as cli  # the app layer, looked up only here
    sys.argv = ["homofac.bake", argv[0], "--preset", "balanced", "--out", argv[1], "--exr", "float32"] + argv[2:]
    return cli()


def count(envs):
    """The built rule's cores in turn (module docstring)."""
    for env in envs:
        lights = bb._Lights(hf.light.bundled(env))
        out = []
        for _ in range(9):
            found, s = lights.take_source(64, bb.block_lights(64))
            out.append(round(s * 100, 2))
            if found is None:
                break
        print(env, "shares of each next (% of the map it is taken from):", out, flush=True)


if __name__ == "__main__":
    {"bake": bake, "count": count}[sys.argv[1]](sys.argv[2:])
