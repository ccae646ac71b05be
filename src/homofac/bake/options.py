"""The bake's options (one pydantic model, shared by ``hf.bake`` and ``python -m homofac.bake``)."""

from __future__ import annotations

from typing import ClassVar, Literal, Optional

from pydantic import Field, model_validator

from ..options import Options


class BakeOptions(Options):
    """What a bake computes. ``preset`` picks the structure (:func:`homofac.bake.plan.plan`: 4, 8 and 16
    lookups per pixel); the rest override it or set sizes."""

    TAG: ClassVar[str] = "bake"
    preset: Literal["fast", "balanced", "best"] = "balanced"
    min_roughness: float = Field(0.045, ge=0.01, le=0.5, description="the sharpest roughness layer")
    max_size: Optional[int] = Field(None, ge=8, le=512, description="largest P face size; default: the source's detail (lat-long width / 4), at most 256 (and the sharp block's face: block_size)")
    block_size: Optional[int] = Field(
        None, ge=8, le=512, description="face of the sharp layers' shared block; default: max_size when it is given, else the "
                                        "source's detail (lat-long width / 4), at most 256; 128 on a 256-wide source "
                                        "sharpens roughness < 0.15 at about twice the bake's time")
    nv_size: int = Field(32, ge=4, le=256, description="n.v columns of the weight tables")
    diffuse_size: Optional[int] = Field(None, ge=8, le=256, description="face size of the diffuse maps E_d (default: the preset's, 16 for balanced, 32 for fast and best)")
    later_face: Optional[int] = Field(
        None, ge=1, le=8, description="P_2..P_K stored at 1 / later_face of their layer's face (at least 8; the layer's map "
                          "box-averaged per face); default: the preset's, 2 for balanced, 1 for best")
    layers: Optional[int] = Field(None, ge=3, le=32, description="roughness layers (default: the preset's)")
    terms: Optional[int] = Field(None, ge=1, le=8, description="specular products (default: the preset's)")
    samples: int = Field(512, ge=64, le=65536, description="directions of the data the diffuse weights are fitted on (the specular layers are fitted at their maps' texels)")
    data_resolution: int = Field(16, ge=4, le=256, description="light resolution of the diffuse data and of the SH9 projection")
    diffuse: Optional[Literal["texture", "sh9"]] = Field(
        None, description="the diffuse maps E_d as cube textures (1 lookup each) or as 9 SH coefficients each, "
                          "evaluated in the shader from constants (0 lookups; docs/format.md); default: the preset's, "
                          "sh9 for balanced, texture for fast and best")
    analytic_source: bool = Field(
        True, description="take the environment's brightest compact source out of the maps and shade it as a point "
                          "light with the exact glTF lobes (0 lookups; homofac.bake.sources)")
    harmonic: Optional[float] = Field(
        None, ge=0.0, le=1.0,
        description="the layers from this roughness up also store the luminance's second azimuthal harmonic about "
                    "their axis (a tensor map per layer, read as t^T M t; docs/format.md); 0: off; default: the preset's")
    mixed: Optional[bool] = Field(
        None, description="with harmonic: the harmonic layers store K - 1 products and the harmonic in the K-th "
                          "product's channels (fewer fetches; docs/format.md); default: the preset's")
    shared_gain: Optional[bool] = Field(
        None, description="with harmonic (not mixed): one table channel h_A whose gain scales both I_A and I_B "
                          "(docs/format.md); default: the preset's, on for balanced")
    exr: Literal["half", "float32"] = "half"
    ktx2: bool = Field(False, description="also write each texture as <name>.ktx2 (RGBA half or float, as exr)")

    @model_validator(mode="after")
    def _pow2(self):
        for name in ("max_size", "block_size", "diffuse_size", "later_face"):
            v = getattr(self, name)
            if v is not None and v & (v - 1):
                raise ValueError(f"{name} must be a power of two, got {v}")
        return self


__all__ = ["BakeOptions"]
