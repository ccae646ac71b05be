"""Sampling sharded across devices (issue 5, "beyond one machine").

The lighting computation of a grouped sample set is independent per normal, so the G normals (and
their P views each) are split evenly over the devices of a 1-D mesh with :func:`jax.shard_map`; the
target (BRDF parameters, environment) is replicated. Each device runs the same per-normal fast path
(:meth:`homofac.light.Lighting.grouped`) on its block, so the result equals the unsharded one up to
the rounding of identical float operations (the same code on the same rows).

On one host, CPU devices are made with ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` (set
before JAX is imported); GPUs and TPUs are found as they are. On several hosts, call
``jax.distributed.initialize()`` first in every process: ``jax.devices()`` then lists the devices of
all hosts and the same call shards over them (docs/notes/readme-history.md, "Scaling out").
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, PartitionSpec as P
from jaxtyping import Array, Float


def grouped_sharded(fn, normals: Float[Array, "G 3"], views: Float[Array, "G P 3"], devices=None
                    ) -> Float[Array, "G P 3"]:
    """``fn.grouped(normals, views)`` with the normal axis split over ``devices`` (default: all)."""
    devices = list(devices) if devices is not None else jax.devices()
    nd = len(devices)
    g = normals.shape[0]
    pad = (-g) % nd
    if pad:  # pad with copies of the first group (computed and dropped)
        normals = jnp.concatenate([normals, jnp.broadcast_to(normals[:1], (pad, 3))])
        views = jnp.concatenate([views, jnp.broadcast_to(views[:1], (pad,) + views.shape[1:])])
    mesh = Mesh(np.asarray(devices), ("d",))
    params, static = eqx.partition(fn, eqx.is_array)
    out = _run(params, static, normals, views, mesh)
    return out[:g]


def _run(params, static, normals, views, mesh):
    def body(p, n, v):
        return eqx.combine(p, static).grouped(n, v)

    f = jax.shard_map(body, mesh=mesh, in_specs=(P(), P("d"), P("d")), out_specs=P("d"))
    return jax.jit(f)(params, normals, views)


__all__ = ["grouped_sharded"]
