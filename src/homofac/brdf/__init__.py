"""homofac.brdf: BRDF models, analytic and measured; pure functions of (wi, wo) in the local frame.

Convention (docs/conventions.md, pinned): ``f(wi, wo) -> (..., 3)`` RGB, local frame (z = normal), without the
cosine factor, exactly 0 where ``wi.z <= 0`` or ``wo.z <= 0``; isotropic.

A model is a :class:`ModelSpec` (data plus a pure function) registered by name in :data:`MODELS`;
a :class:`BRDF` is an equinox module ``(model, params)``; :func:`make` builds one by name with
defaults and validation, and there is one constructor per model::

    brdf = hf.brdf.cook_torrance(kd=(0.05, 0.04, 0.02), ks=1.0, roughness=0.3, f0=(1.0, 0.78, 0.34))
    brdf(wi, wo)              # (..., 3)
    hf.brdf.albedo(brdf, wo)  # directional albedo, (..., 3)

Submodules: ``core`` (registry, BRDF, make, validation), ``analytic`` (models with formulas and
sources), ``measured`` (MERL files, lookup, tabulation), ``integrate`` (directional albedo).
"""

from .core import BRDF, MODELS, Microfacet, ModelSpec, Shaped, check_value, evaluate, from_config, make, options_model, options_union, register
from .analytic import blinn_phong, cook_torrance, ggx, lambert, modified_phong, phong, ward
from .measured import (
    MERL_DIMS,
    MERL_SCALE,
    count_holes,
    from_half_diff,
    half_diff_angles,
    load_merl,
    merl,
    merl_grid,
    save_merl,
    tabulate_merl,
)
from .integrate import albedo
from .gltf import gltf

__all__ = [
    "BRDF",
    "MERL_DIMS",
    "MERL_SCALE",
    "MODELS",
    "Microfacet",
    "ModelSpec",
    "Shaped",
    "albedo",
    "blinn_phong",
    "check_value",
    "cook_torrance",
    "count_holes",
    "evaluate",
    "from_config",
    "from_half_diff",
    "ggx",
    "gltf",
    "half_diff_angles",
    "lambert",
    "load_merl",
    "make",
    "merl",
    "merl_grid",
    "options_model",
    "options_union",
    "modified_phong",
    "phong",
    "register",
    "save_merl",
    "tabulate_merl",
    "ward",
]
