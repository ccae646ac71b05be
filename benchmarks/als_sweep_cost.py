"""CPU cost of the compiled ALS sweep programs (:func:`homofac.fit.als.sweep`) per slot shape: their compilation
(the first sweep) and one sweep, on random grid data of 5 456 texels and 32-texel lines, for each pair count in
turn in one process (docs/notes/speed.md, "The candidate loop, seventeenth session": why the candidates' slots are
not padded into one program; "balanced's programs, twenty-first session": the sweep in blocks of pairs, whose
programs a fit on a multiple of the block's pairs reuses).

    PYTHONPATH=src python benchmarks/als_sweep_cost.py 75000 2,1,0,0 2,1,1,2 2,3,2,2   # pairs, then slots
    PYTHONPATH=src python benchmarks/als_sweep_cost.py 75000,300000 2,1,1,2 --block 75000
"""
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from homofac.fit import als

argv = sys.argv[1:]
block = 0
if "--block" in argv:
    i = argv.index("--block")
    block = int(argv[i + 1])
    argv = argv[:i] + argv[i + 2:]
args = argv
counts = [int(x) for x in args[0].split(",")]
n = 5456 // 2
Sw = 32
rng = np.random.default_rng(0)


def data(N, K):
    a = rng.integers(0, n, N).astype(np.int32)
    b = rng.integers(0, n, N).astype(np.int32)
    vi = np.stack([rng.integers(0, Sw - 1, N)] * 2, -1).astype(np.int32)
    vi[:, 1] += 1
    vw = np.full((N, 2), .5, np.float32)
    hi = np.repeat(vi[:, None, :], K, 1)
    hw = np.repeat(vw[:, None, :], K, 1)
    nb = rng.integers(0, n, (n, 4)).astype(np.int32)
    return a, b, vi, vw, hi, hw, nb


for slots in [als.Slots(*map(int, s.split(","))) for s in args[1:]]:
    K = slots.terms
    for N in counts:
        a, b, vi, vw, hi, hw, nb = data(N, K)
        d = als.GridData(jnp.asarray(a), jnp.asarray(b), jnp.asarray(vi), jnp.asarray(vw),
                         jnp.asarray(rng.random((N, 3)), jnp.float32), jnp.asarray(nb), jnp.ones((n, 4), jnp.float32),
                         jnp.ones(N, jnp.float32), jnp.asarray(hi) if slots.high else None,
                         jnp.asarray(hw) if slots.high else None, tuple(jnp.asarray(hi) for _ in range(slots.extra)),
                         tuple(jnp.asarray(hw) for _ in range(slots.extra)))
        d = als.blocks(d, block) if hasattr(als, "blocks") else d
        m = als.Masks(*(jnp.ones(K, jnp.float32) for _ in range(5)), jnp.ones((slots.extra, K), jnp.float32))
        P = jnp.ones((K, n, 3))
        W = jnp.ones((K, Sw, 3))
        C = tuple(jnp.ones((K, Sw, 3)) for _ in range(slots.extra))
        t0, c0 = time.perf_counter(), time.process_time()
        out = als.sweep(P, P, W, W, C, d, jnp.float32(0.01), m, slots=slots)
        jax.block_until_ready(out[:5])
        tc, cc = time.perf_counter() - t0, time.process_time() - c0
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(5):
            out = als.sweep(P, P, W, W, C, d, jnp.float32(0.01), m, slots=slots)
            jax.block_until_ready(out[:5])
        print(slots, N, f"block {block}: first {tc:.2f}s wall {cc:.2f} cpu; per sweep "
              f"{(time.perf_counter() - t0) / 5:.3f}s wall {(time.process_time() - c0) / 5:.3f} cpu", flush=True)
