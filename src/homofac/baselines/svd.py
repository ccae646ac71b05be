"""Mahajan et al. 2008's in-out analysis: how many product terms a lighting target needs.

The target is sampled on a grid of pairs (a_i, b_j): a = n over the texel centres of a mapper, b = r
(``pair: nr``, v = 2 (n.r) n - r) or b = v (``pair: nv``) over the same centres. Rows and columns are
weighted by the square roots of the texel solid angles, so that the Frobenius norm of the matrix
approximates the L2 norm of the function over the sphere x sphere; each RGB channel is a matrix of its
own (a texture product is a product per channel) and the errors are averaged over the channels, as the
pinned metrics are. Half of the grid is not a valid pair
(n.b <= 0): those entries are *missing*, not zeros, so the best rank-K approximation is the masked
low-rank problem ``min ||M o (A - X_K)||`` (Mahajan et al. 2008 §4, the in-out analysis; Srebro &
Jaakkola 2003), solved by alternating least squares over the observed entries (each factor's rows are small linear
solves), warm-started from rank K - 1 plus the next direction of the residual. The error curve is ``e(K) = ||M o (A - X_K)|| / ||M o A||``
(Eckart-Young's ``sqrt(sum_{k > K} sigma_k^2 / sum sigma_k^2)`` when nothing is missing) and
:meth:`SVDAnalysis.rank_for` gives the smallest K with e(K) <= a target error; the singular values
are those of the completed rank-``max_rank`` matrices (channel means).

It measures the *structure* of the target in the chosen parametrization (a product of bilinear
textures can do no better than its rank-K approximation on the grid), not a fit.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import jax.numpy as jnp
import numpy as np

from ..errors import HomofacError
from ..param import mappers
from ..target import Target, evaluate

PAIRS = ("nr", "nv")


class SVDAnalysis(NamedTuple):
    """Singular values of the gridded target and its rank-K error curve."""

    pair: str
    mapper: str
    size: int
    singular_values: np.ndarray  # (N,), descending (mean over the channels)
    error: np.ndarray  # e(K) for K = 0, 1, 2, ...: relative error of the best rank-K approximation

    def rank_for(self, target_error: float) -> int | None:
        """The smallest K whose rank-K error is at most ``target_error`` (None: not within the grid's rank)."""
        k = np.nonzero(self.error <= target_error)[0]
        return int(k[0]) if k.size else None

    def summary(self, errors=(0.2, 0.1, 0.05)) -> str:
        """One line for a run report."""
        e = ", ".join(f"rank {k} leaves {self.error[k]:.1%}" for k in (1, 2, 4, 8) if k < len(self.error))
        r = ", ".join(f"{t:g}: K = {self.rank_for(t)}" for t in errors)
        return f"Mahajan analysis ({self.pair[0]}, {self.pair[1]}) on {self.mapper} {self.size}: {e}; K for error {r}"

    def record(self) -> dict:
        """JSON-friendly summary (the first 32 singular values and errors)."""
        return {"pair": self.pair, "mapper": self.mapper, "size": self.size,
                "singular_values": [float(x) for x in self.singular_values[:32]],
                "error": [float(x) for x in self.error[:33]],
                "rank_for": {str(t): self.rank_for(t) for t in (0.2, 0.1, 0.05, 0.02)}}


def grid(mapper: str, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions and solid angles of the in-domain texel centres of a mapper's grid."""
    m = mappers.get(mapper)
    if m.scalar or not m.covers_sphere:
        raise HomofacError(f"the in-out analysis needs a sphere mapper (dual_paraboloid, cube, octahedral), got {mapper}")
    inside = mappers.inside_mask(m, size)
    d = np.asarray(mappers.texel_directions(m, size), np.float64)[inside]
    w = np.asarray(mappers.texel_solid_angles(m, size), np.float64)[inside]
    return d / np.linalg.norm(d, axis=1, keepdims=True), w


def matrix(target: Target, pair: str = "nr", mapper: str = "dual_paraboloid", size: int = 16
           ) -> tuple[np.ndarray, np.ndarray]:
    """``(A, mask)``: the weighted matrices ``sqrt(w_i) L_c(a_i, b_j) sqrt(w_j)`` (3, N, N), one per channel,
    and the mask (N, N) of the valid entries (n.b > 0)."""
    if pair not in PAIRS:
        raise HomofacError(f"analysis pair must be one of {', '.join(PAIRS)}, got {pair!r}")
    if getattr(target, "kind", None) != "lighting":
        raise HomofacError("the in-out analysis is for lighting targets (a = n, b = r or v)")
    d, w = grid(mapper, size)
    N = len(d)
    n = np.repeat(d, N, axis=0)
    b = np.tile(d, (N, 1))
    c = np.sum(n * b, axis=1)
    ok = c > 1e-4
    v = 2 * c[:, None] * n - b if pair == "nr" else b
    y = np.zeros((N * N, 3))
    if ok.any():
        y[ok] = np.asarray(evaluate(target, jnp.asarray(n[ok], jnp.float32), jnp.asarray(v[ok], jnp.float32)), np.float64)
    if not np.all(np.isfinite(y)):
        raise HomofacError("the target gave non-finite values on the analysis grid")
    sw = np.sqrt(w)
    m = y.reshape(N, N, 3) * sw[:, None, None] * sw[None, :, None]
    return np.moveaxis(m, 2, 0), ok.reshape(N, N)


def _rows(a: np.ndarray, mask: np.ndarray, v: np.ndarray, ridge: float) -> np.ndarray:
    """Least-squares rows u_i of ``a ~ u v^T`` over each row's observed entries (a K x K solve per row)."""
    g = np.matmul((mask[:, :, None] * v[None]).transpose(0, 2, 1), v)  # (N, K, K): sum_j m_ij v_j v_j^T
    rhs = (np.where(mask, a, 0.0)) @ v  # (N, K)
    k = v.shape[1]
    g += ridge * np.eye(k)[None]
    return np.linalg.solve(g, rhs[..., None])[..., 0]


def _als(a: np.ndarray, mask: np.ndarray, max_rank: int, sweeps: int) -> tuple[list, np.ndarray]:
    """Masked rank-K approximations of one matrix for K = 1 .. max_rank by alternating least squares
    (each factor's subproblem is linear), warm-started from rank K - 1: errors and singular values."""
    m = mask.astype(np.float64)
    total = max(float(np.linalg.norm(a[mask])), 1e-300)
    ridge = 1e-10 * total * total / max(mask.sum(), 1)
    u0, s0, vt0 = np.linalg.svd(np.where(mask, a, 0.0), full_matrices=False)  # start: the zero-filled SVD
    v = vt0[:1].T * np.sqrt(s0[:1])
    err = [1.0]
    est = np.zeros_like(a)
    for k in range(1, max_rank + 1):
        if k > 1:  # the next direction of the residual's zero-filled SVD
            r = np.where(mask, a - est, 0.0)
            _, sr, vtr = np.linalg.svd(r, full_matrices=False)
            v = np.concatenate([v, vtr[:1].T * np.sqrt(max(sr[0], 1e-300))], axis=1)
        for _ in range(sweeps):
            u = _rows(a, m, v, ridge)
            v = _rows(a.T, m.T, u, ridge)
        est = u @ v.T
        err.append(float(np.linalg.norm((a - est)[mask])) / total)
    return err, np.linalg.svd(np.where(mask, a, est), compute_uv=False)


def analyse(target: Target, pair: Literal["nr", "nv"] = "nr", mapper: str = "dual_paraboloid", size: int = 16,
            max_rank: int = 16, sweeps: int = 12) -> SVDAnalysis:
    """The in-out analysis of a lighting target (see the module docstring)."""
    a, mask = matrix(target, pair, mapper, size)
    max_rank = int(min(max_rank, a.shape[1]))
    errs, sv = zip(*(_als(a[c], mask, max_rank, sweeps) for c in range(3)))
    return SVDAnalysis(pair, mapper, int(size), np.mean(sv, axis=0), np.mean(np.asarray(errs), axis=0))


def plot(analyses: dict[str, SVDAnalysis], path, title: str = "rank-K error of the in-out analysis") -> None:
    """Plot error curves ``{label: analysis}`` (log scale) to ``path`` (needs matplotlib)."""
    import matplotlib  # noqa: PLC0415 - optional plotting dependency, imported only to plot

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(6, 4))
    for label, a in analyses.items():
        k = np.arange(1, min(33, len(a.error)))
        ax.semilogy(k, a.error[k], marker="o", ms=3, label=label)
    ax.set_xlabel("K (separable terms)")
    ax.set_ylabel("relative error of the best rank-K fit")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


__all__ = ["PAIRS", "SVDAnalysis", "analyse", "grid", "matrix", "plot"]
