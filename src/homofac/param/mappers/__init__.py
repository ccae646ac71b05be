"""homofac.param.mappers: direction mappers (records), their texel tables, and the one bilinear lookup.

* :mod:`.records`: the :class:`Mapper` records and their math (direction <-> texel), written once for
  NumPy, JAX and shader code;
* :mod:`.geometry`: texture shapes, texel centres and directions, masks, solid angles;
* :mod:`.tables`: Laplacian neighbours, nearest valid texels, dilation;
* :mod:`.lookup`: :func:`bilinear` (thesis eq. 33-34) and :func:`lookup`.
"""

from __future__ import annotations

from .geometry import (
    check_size,
    inside_mask,
    texel_centers,
    texel_directions,
    texel_solid_angles,
    texture_shape,
    valid_mask,
)
from .lookup import bilinear, continuous_coords, face_uv, gather, lookup
from .records import CUBE_N, CUBE_SC, CUBE_TC, MAPPERS, Mapper, get, register, resolve
from .tables import dilate, nearest_valid, neighbours

__all__ = [
    "CUBE_N", "CUBE_SC", "CUBE_TC", "MAPPERS", "Mapper", "bilinear", "check_size", "continuous_coords", "dilate",
    "face_uv", "gather", "get", "inside_mask", "lookup", "nearest_valid", "neighbours", "register", "resolve",
    "texel_centers", "texel_directions", "texel_solid_angles", "texture_shape", "valid_mask",
]
