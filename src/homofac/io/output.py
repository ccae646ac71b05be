"""The pinned output directory: factorization.json, ``<name>.exr`` textures, optional samples.npz.

With ``png=True`` also ``<name>.png``: 8-bit RGBA textures with the thesis' alpha precision trick
(§4.3.2), decoded by the ``png_decode`` rule written into factorization.json. Cube-mapper textures are
also written as six face files and as one EXR with ``envmap = cube``. :func:`load` reads a directory
back and evaluates it from the float (EXR) or the 8-bit (PNG) textures.

Writing is atomic (DESIGN.md): everything goes into a temporary sibling directory that is renamed
into place only after every file was written. A directory homofac did not write is never replaced;
a previous homofac result is replaced whole, after the new one is complete.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..errors import HomofacError

FORMAT = "homofac.factorization"
SCHEMA_VERSION = 1
JSON_NAME = "factorization.json"


def _jsonable(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, Path):
        return str(v)
    if hasattr(v, "shape") and hasattr(v, "dtype"):
        a = np.asarray(v)
        return a.item() if a.ndim == 0 else a.tolist()
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    return v


def is_homofac_dir(path: Path) -> bool:
    """True when ``path`` holds a factorization.json written by homofac."""
    f = Path(path) / JSON_NAME
    try:
        return json.loads(f.read_text()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def check_output_dir(out_dir) -> Path:
    """Refuse output paths that are files or foreign non-empty directories (before any work)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise HomofacError(f"output path {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not is_homofac_dir(out):
        raise HomofacError(f"output directory {out} is not empty and was not written by homofac; refusing to overwrite it")
    parent = out.parent
    if parent.exists() and not parent.is_dir():
        raise HomofacError(f"output path {out}: parent {parent} is not a directory")
    return out


#: Cube face file suffixes, in the pinned face order +X, -X, +Y, -Y, +Z, -Z (as homofac.light reads them).
FACE_NAMES = ("px", "nx", "py", "ny", "pz", "nz")
#: EXR pixel types of the float textures.
EXR_TYPES = ("float32", "half")


def _check_options(png, exr) -> None:
    if exr not in EXR_TYPES:
        raise HomofacError(f"output.exr must be one of {', '.join(EXR_TYPES)}, got {exr!r}")
    if not isinstance(png, (bool, np.bool_)):
        raise HomofacError(f"output.png must be true or false, got {png!r}")


def cube_faces(texture: np.ndarray) -> list[np.ndarray]:
    """The six ``(S, S, C)`` faces of a pinned ``(S, 6S, C)`` cube texture (+X, -X, +Y, -Y, +Z, -Z)."""
    t = np.asarray(texture)
    S = t.shape[0]
    return [t[:, i * S : (i + 1) * S] for i in range(6)]


def cube_vertical(texture: np.ndarray) -> np.ndarray:
    """The OpenEXR cube-map layout ``(6S, S, C)``: the pinned faces stacked top to bottom."""
    return np.concatenate(cube_faces(texture), axis=0)


def document(fac, *, png: bool = False, exr: str = "float32", encoded=None) -> dict:
    """The factorization.json document of a :class:`~homofac.fit.factorization.Factorization`.

    Beside the pinned keys: per texture ``exr_type`` (``float32`` or ``half``), for cube textures the
    six face files ``faces`` and ``cube_file`` (one EXR with ``envmap = cube``), with ``png`` the 8-bit
    file ``png`` (and ``png_faces``); always ``png_decode``, the decode rule of the 8-bit RGBA textures
    (colour, power-of-two scale, prescale factors, alpha use; thesis §4.3) that the ``quantized``
    metrics were measured with.
    """
    from ..param import parametrizations as pz

    _check_options(png, exr)
    p = pz.get(fac.parametrization)
    enc = encoded if encoded is not None else fac.encoded()
    textures = []
    for k, name in enumerate(p.textures):
        t = {
            "name": name,
            "file": f"{name}.exr",
            "mapper": fac.mapper,
            "size": fac.texture_size,
            "shape": list(np.asarray(fac.textures[k]).shape[:2]),
            "factors": list(p.uses(k)),
            "exr_type": exr,
        }
        if fac.mapper == "cube":
            t["faces"] = [f"{name}_{f}.exr" for f in FACE_NAMES]
            t["cube_file"] = f"{name}_cube.exr"
        if png:
            t["png"] = f"{name}.png"
            if fac.mapper == "cube":
                t["png_faces"] = [f"{name}_{f}.png" for f in FACE_NAMES]
        textures.append(t)
    decode = {**enc.decode_rule(), "written": bool(png)}
    return _jsonable(
        {
            "format": FORMAT,
            "schema_version": SCHEMA_VERSION,
            "homofac_version": __version__,
            "kind": fac.kind,
            "target": {"kind": fac.kind, "quantity": fac.quantity, **fac.target_info},
            "parametrization": fac.parametrization,
            "mapper": fac.mapper,
            "texture_size": fac.texture_size,
            "textures": textures,
            "factors": [{"projection": f.projection, "texture": p.textures[f.texture]} for f in p.factors],
            "correction": fac.correction,
            "png_decode": decode,
            "context": fac.context,
            "metrics": fac.metrics,
            "solver": fac.solver,
            "timings": fac.timings,
            "counts": fac.counts,
            "warnings": list(fac.warnings),
            "config": fac.config,
            **({"selection": fac.selection} if fac.selection is not None else {}),
        }
    )


def save(fac, out_dir, *, samples=None, extra_files: dict | None = None, png: bool = False,
         exr: str = "float32") -> Path:
    """Write the output directory atomically; returns its path.

    Args:
        fac: the factorization.
        out_dir: target directory (created; a previous homofac result there is replaced whole).
        samples: optional :class:`~homofac.fit.pipeline.Samples` written as samples.npz.
        extra_files: ``{file name: callable(path)}`` writers of further files (e.g. a preview).
        png: also write ``<name>.png``, the 8-bit RGBA textures with the alpha trick (thesis §4.3.2).
        exr: ``"float32"`` (bit-exact) or ``"half"`` pixels in the EXR textures.

    Cube-mapper textures are additionally written as six face files ``<name>_px.exr`` ... ``_nz.exr``
    (pinned face order and orientation) and as ``<name>_cube.exr``, the faces stacked vertically
    ``(6S, S)`` with the header attribute ``envmap = cube`` (OpenEXR's cube-map layout).
    """
    import OpenEXR

    from .exr import write_exr
    from .png import write_png

    _check_options(png, exr)
    out = check_output_dir(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        enc = fac.encoded()
        doc = document(fac, png=png, exr=exr, encoded=enc)
        half = exr == "half"
        for k, t in enumerate(doc["textures"]):
            tex = np.asarray(fac.textures[k], np.float32)
            write_exr(tmp / t["file"], tex, half=half)
            if "faces" in t:
                for f, face in zip(t["faces"], cube_faces(tex)):
                    write_exr(tmp / f, face, half=half)
                write_exr(tmp / t["cube_file"], cube_vertical(tex), half=half, header={"envmap": OpenEXR.ENVMAP_CUBE})
            if png:
                info = {"homofac": f"texture {t['name']} of {fac.parametrization}; linear RGBA8, "
                                   f"decode rule in {JSON_NAME} (png_decode)"}
                write_png(tmp / t["png"], enc.rgba[k], text=info)
                for f, face in zip(t.get("png_faces", ()), cube_faces(enc.rgba[k])):
                    write_png(tmp / f, np.ascontiguousarray(face))
        if samples is not None:
            np.savez(
                tmp / "samples.npz",
                **{k: np.asarray(v, np.float32) for k, v in samples._asdict().items()},
            )
        for name, writer in (extra_files or {}).items():
            writer(tmp / name)
        (tmp / JSON_NAME).write_text(json.dumps(doc, indent=2, allow_nan=True))
        _swap_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _swap_into_place(tmp: Path, out: Path) -> None:
    if out.exists():
        old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
        os.replace(out, old)
        try:
            os.replace(tmp, out)
        except BaseException:
            os.replace(old, out)
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, out)


def _encoded_from_doc(d: Path, doc: dict, read: bool):
    """The Encoded8 that ``png_decode`` describes; with ``read`` the RGBA arrays from the PNG files."""
    from ..fit.precision import Encoded8
    from .png import read_png

    rule = doc.get("png_decode")
    if not isinstance(rule, dict):
        raise HomofacError(f"{d / JSON_NAME}: no png_decode rule for the 8-bit textures")
    try:
        colour = np.asarray(rule["colour"], np.float64).reshape(3)
        scale = float(rule["scale"])
        pre = np.asarray(rule["prescale"], np.float64).reshape(len(doc["textures"]) + 1)
        alpha = bool(rule["alpha"])
    except (KeyError, TypeError, ValueError) as e:
        raise HomofacError(f"{d / JSON_NAME}: malformed png_decode rule ({_one_line(e)})") from None
    rgba = ()
    if read:
        arrs = []
        for t in doc["textures"]:
            if "png" not in t:
                raise HomofacError(f"{d / JSON_NAME}: texture {t.get('name')} has no PNG file (write with output.png: true)")
            a = read_png(d / t["png"])
            if list(a.shape[:2]) != list(t.get("shape", a.shape[:2])):
                raise HomofacError(f"{d / t['png']}: shape {list(a.shape[:2])} does not match {JSON_NAME} ({t['shape']})")
            arrs.append(a)
        rgba = tuple(arrs)
    return Encoded8(rgba, colour, scale, pre, alpha, tuple(rule.get("clamped", ())))


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


def load(out_dir, textures: str = "exr"):
    """Read an output directory back into a :class:`~homofac.fit.factorization.Factorization`.

    ``textures="exr"`` (default): the float textures from the EXR files; when PNG files were written
    they are read too and ``evaluate(a, b, quantized=True)`` decodes exactly those (else the 8-bit
    encoding is recomputed from the EXR textures with the stored ``png_decode`` settings).
    ``textures="png"``: only the 8-bit PNG textures and their decode rule; ``evaluate(a, b)`` then
    decodes them (thesis eq. 50) and ``textures``/``correction`` hold their per-texel float values.
    A missing, truncated or mismatched file raises a one-line HomofacError naming it.
    """
    import jax.numpy as jnp

    from ..fit.factorization import Factorization
    from ..fit.precision import texel_values
    from .exr import read_exr

    if textures not in ("exr", "png"):
        raise HomofacError(f"load: textures must be 'exr' or 'png', got {textures!r}")
    d = Path(out_dir)
    try:
        doc = json.loads((d / JSON_NAME).read_text())
    except OSError as e:
        raise HomofacError(f"{d}: cannot read {JSON_NAME} ({e.strerror or e})") from None
    except ValueError as e:
        raise HomofacError(f"{d / JSON_NAME}: not valid JSON ({e})") from None
    if doc.get("format") != FORMAT:
        raise HomofacError(f"{d / JSON_NAME}: not a homofac factorization")
    has_png = all("png" in t for t in doc["textures"])
    enc = None
    if textures == "png" or (has_png and "png_decode" in doc):
        enc = _encoded_from_doc(d, doc, read=True)
    if textures == "png":
        tex = tuple(jnp.asarray(t) for t in texel_values(enc))
        correction = jnp.asarray(enc.colour * enc.scale * enc.prescale[0], jnp.float32)
    else:
        arrs = []
        for t in doc["textures"]:
            a = read_exr(d / t["file"])
            if list(a.shape[:2]) != list(t.get("shape", a.shape[:2])):
                raise HomofacError(f"{d / t['file']}: shape {list(a.shape[:2])} does not match {JSON_NAME} ({t['shape']})")
            arrs.append(jnp.asarray(a))
        tex = tuple(arrs)
        correction = jnp.asarray(doc["correction"], jnp.float32)
    encoding = {}
    if "png_decode" in doc:
        rule = _encoded_from_doc(d, doc, read=False)
        encoding = {"weights": [float(x) for x in rule.prescale], "alpha": rule.alpha}
    ctx = {k: jnp.asarray(v, jnp.float32) for k, v in (doc.get("context") or {}).items()}
    return Factorization(
        kind=doc["kind"], parametrization=doc["parametrization"], mapper=doc["mapper"],
        texture_size=int(doc["texture_size"]), textures=tex, correction=correction,
        context=ctx, quantity=doc["target"].get("quantity", "brdf"), metrics=doc.get("metrics", {}),
        solver=doc.get("solver", {}), timings=doc.get("timings", {}), counts=doc.get("counts", {}),
        config=doc.get("config", {}), target_info={k: v for k, v in doc["target"].items() if k not in ("kind", "quantity")},
        warnings=tuple(doc.get("warnings", ())), encoding=encoding, rgba8=enc,
        source="png" if textures == "png" else "float",
    )
