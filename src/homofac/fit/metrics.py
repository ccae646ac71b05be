"""Error metrics between an approximation a and the exact values e (docs/conventions.md, pinned names).

Each metric is computed per RGB channel over the samples and then averaged over the channels, as
the thesis reports its tables (§5.7: "all values are the arithmetic averages over the RGB
components").

* ``avg_abs`` mean |a - e|, ``max_abs`` max |a - e|
* ``avg_rel`` mean(|a - e| / max(e, tau)), ``max_rel`` its maximum, with tau = 1e-3 mean(e)
* ``rms`` sqrt(mean((a - e)^2)) (the thesis' RMS I; RMS II is the same on the 8-bit textures)
* ``nrmse`` ||a - e|| / ||e||
* ``log_rms`` RMS of log((a + eps alpha) / (e + eps alpha)) with alpha = mean(e) (the log-space
  error the homomorphic factorization minimises, eq. 26)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..factorization import evaluate_by_factor

NAMES = ("avg_abs", "max_abs", "avg_rel", "max_rel", "rms", "nrmse", "log_rms")


def _channel(xp, a, e, eps):
    """The pinned metrics per channel in the array namespace ``xp`` (numpy in float64, or jax.numpy).

    Sums of squares are taken of the values divided by their largest magnitude per channel ``s`` (and the
    results scaled back): one environment pixel of 1e30 made float32 squares overflow and every rms and
    nrmse inf (null in factorization.json); rel, max and log terms are computed as they are."""
    diff = a - e
    ad = xp.abs(diff)
    mean_e = xp.mean(e, axis=0)
    tau = 1e-3 * xp.maximum(mean_e, 1e-30)
    rel = ad / xp.maximum(e, tau)
    alpha = xp.maximum(mean_e, 1e-30)
    log_err = xp.log((xp.maximum(a, 0.0) + eps * alpha) / (xp.maximum(e, 0.0) + eps * alpha))
    s = xp.maximum(xp.max(xp.maximum(xp.abs(a), xp.abs(e)), axis=0), 1e-30)
    ds, es = diff / s, e / s
    return {
        "avg_abs": xp.mean(ad, axis=0),
        "max_abs": xp.max(ad, axis=0),
        "avg_rel": xp.mean(rel, axis=0),
        "max_rel": xp.max(rel, axis=0),
        "rms": s * xp.sqrt(xp.mean(ds * ds, axis=0)),
        "nrmse": xp.sqrt(xp.sum(ds * ds, axis=0)) / xp.maximum(xp.sqrt(xp.sum(es * es, axis=0)), 1e-30 / s),
        "log_rms": xp.sqrt(xp.mean(log_err * log_err, axis=0)),
    }


@jax.jit
def channel_metrics(approx: Float[Array, "N C"], exact: Float[Array, "N C"], eps: float = 1e-5) -> dict:
    """The pinned metrics per channel (column), as (C,) arrays: :func:`metric_arrays` averages them over
    RGB; a material library stacks its targets' channels side by side and measures them in one pass."""
    return _channel(jnp, approx, exact, eps)


def metric_arrays(approx: Float[Array, "N 3"], exact: Float[Array, "N 3"], eps: float = 1e-5) -> dict:
    """All pinned metrics as 0-d arrays (pure and differentiable; average over RGB)."""
    return {k: jnp.mean(v) for k, v in channel_metrics(approx, exact, eps).items()}


def metrics(approx, exact, eps: float = 1e-5) -> dict[str, float]:
    """The pinned metrics as plain floats (for reports and factorization.json), accumulated in float64
    with numpy (the same formulas as :func:`metric_arrays`)."""
    a, e = np.asarray(approx, np.float64), np.asarray(exact, np.float64)
    with np.errstate(all="ignore"):  # a NaN or inf in the values gives a NaN metric (reported), not a warning
        return {k: float(np.mean(v)) for k, v in _channel(np, a, e, float(eps)).items()}


#: Pairs per call of the model's evaluation in :func:`measure`: every call (the last padded) has this
#: shape, so one compiled evaluation per structure serves the candidates' validation figure and the kept
#: structure's training and validation metrics, whatever the pair counts.
CHUNK = 32768


def _chunks(fn, a, b, chunk: int) -> np.ndarray:
    """``fn(a, b)`` over calls of exactly ``chunk`` pairs (the last padded with copies of the first pair,
    its padding cut off): one program shape for every pair count. Padded, sliced and joined on the host
    (``jnp`` here compiled a program per operation and pair count)."""
    a, b = np.asarray(a), np.asarray(b)
    n = int(a.shape[0])
    pad = (-n) % chunk
    if pad:
        a = np.concatenate([a, np.broadcast_to(a[:1], (pad, a.shape[1]))])
        b = np.concatenate([b, np.broadcast_to(b[:1], (pad, b.shape[1]))])
    return np.concatenate([np.asarray(fn(a[i:i + chunk], b[i:i + chunk])) for i in range(0, n + pad, chunk)],
                          axis=0)[:n]


def measure(result, target, samples, eps: float = 1e-5, chunk: int = CHUNK,
            splits: tuple[str, ...] = ("train", "validation"), kinds: tuple[str, ...] = ("float", "quantized")) -> dict:
    """Pinned metrics of a :class:`~homofac.fit.result.Result` on training and validation samples, for the
    float and the 8-bit textures: ``{train, validation} x {float, quantized} -> metric dict``.

    ``quantized`` is the thesis' RMS II (§4.3, §6.1.8 step 10): the 8-bit RGBA textures of
    ``result.encoded()`` with their decode rule. Values are compared as the target shows them
    (:meth:`homofac.target.Target.shown`: f cos theta_i for BRDFs). ``splits``, ``kinds``: a subset
    (a chooser's candidates need only the validation float figure their vote reads). The model is
    evaluated in calls of ``chunk`` pairs (:data:`CHUNK`, the last padded), the float textures factor by
    factor (:func:`homofac.factorization.evaluate_by_factor`: the candidates of a chooser share the lookup
    programs instead of compiling one evaluation per structure).
    """
    if result.quantized is None and "quantized" in kinds:
        result = result.replace(quantized=result.encoded())  # encode once, not per chunk
    out = {}
    for split, a, b, y in (
        ("train", samples.a, samples.b, samples.y),
        ("validation", samples.val_a, samples.val_b, samples.val_y),
    ):
        if len(a) == 0 or split not in splits:
            continue
        a, b = np.asarray(a), np.asarray(b)
        exact = target.shown(a, np.asarray(y))  # on the host, as the metrics (float64) are
        out[split] = {}
        for name, quant in ((k, k == "quantized") for k in kinds):
            values = _chunks((lambda x, z: result.evaluate(x, z, quantized=True)) if quant
                             else (lambda x, z: evaluate_by_factor(result.model, x, z)), a, b, int(chunk))
            out[split][name] = metrics(target.shown(a, values), exact, eps)
    return out
