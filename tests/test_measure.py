"""measure: the model evaluated in fixed-size calls padded and joined on the host gives the metrics of one
evaluation of every pair (BRDF targets compare f cos theta_i)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import homofac as hf
from homofac.fit.metrics import measure, metrics


def test_measure_in_padded_chunks_is_the_metrics_of_all_pairs_at_once():
    target = hf.fit.brdf_target(hf.brdf.cook_torrance(kd=0.1, ks=1.0, roughness=0.4, f0=0.9))
    fac = hf.fit.factorize(target, "PQP", mapper="parabolic", texture_size=8,
                           sampling={"kind": "texels", "size": 6, "validation": 500, "cache": False}, keep_samples=True)
    s = fac.samples
    chunked = measure(fac, target, s, chunk=97)  # 97 does not divide the pair counts: the last call is padded
    for split, a, b, y in (("train", s.a, s.b, s.y), ("validation", s.val_a, s.val_b, s.val_y)):
        for kind in ("float", "quantized"):
            approx = np.asarray(fac.evaluate(jnp.asarray(a), jnp.asarray(b), quantized=kind == "quantized"))
            cos = np.maximum(a[:, 2:3], 0.0)  # what the metrics compare: f cos theta_i
            want = metrics(approx * cos, y * cos)
            for k, v in want.items():
                np.testing.assert_allclose(chunked[split][kind][k], v, rtol=1e-5, err_msg=f"{split} {kind} {k}")
    np.testing.assert_allclose(chunked["validation"]["float"]["nrmse"], fac.metrics["validation"]["float"]["nrmse"], rtol=1e-6)
