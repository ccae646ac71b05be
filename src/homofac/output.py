"""The pinned output directory: factorization.json (schema 2), ``<name>.exr`` textures, optional files.

Layout (docs/format.md): ``factorization.json``; per texture ``<name>.exr`` (float32 or half RGB,
linear) and, with ``png``, ``<name>.png`` (8-bit RGBA with the decode rule in the JSON), with ``ktx2``,
``<name>.ktx2`` (KTX 2.0, RGBA half float, a cube map for the ``cube`` mapper; :func:`ktx2_layout`); cube-mapper
textures also as six face files and one EXR with ``envmap = cube``; ``samples.npz``, ``preview.png``
and the shaders (``shader.glsl`` ...) when asked. A one-term factorization also writes schema 1's
top-level keys (``parametrization``, ``mapper``, ``texture_size``, ``factors``, ``correction``,
``png_decode``), so schema-1 readers keep working; schema-1 directories still load.

What is on disk is not trusted when it is read back (:func:`load`): the document is validated
(:class:`Document`: types, ranges, every declared size against its mapper), file names must be plain
names of files inside the directory (no ``..``, no absolute paths, no symlinks leaving it), images are
read with a memory cap and must have the declared shape, and every problem is one line naming the
file. Writing is atomic and exclusive: everything goes into a temporary sibling directory that is
renamed into place only after every file was written, under a lock file beside the directory
(:class:`OutputLock`, ``.<name>.lock``) that a second run refuses to share; leftovers of a killed run
(``.<name>.tmp-*``, ``.<name>.old-*``) are cleaned, and a result stranded between the two renames of
the final swap is put back. A directory homofac did not write is never replaced. Files and folders
get the modes the umask allows (as any program's output), not the 0600/0700 of temporary files.
"""

from __future__ import annotations

import errno
import fcntl
import json
import math
import os
import shutil
import stat
import uuid
from pathlib import Path
from typing import Any, Literal, Optional

import numpy as np
import OpenEXR
from pydantic import Field, field_validator, model_validator

from ._version import __version__
from .errors import HomofacError
from .factorization import (Factor, Factorization, Quantized, Term, Texture, check_identifier, check_label, check_rgba,
                            check_texture_name, decode_texels)
from .bake import Bake, BakePlan
from .bake import register_writer as register_bake_writer
from .bake import shader as bake_shader
from .bake.atlas import Atlas, assemble, blocks_of, check_layout, pack, split, up
from .bake.gauge import face_gauge
from .bake.sources import MAX_SOURCES
from .bake.sources import Source
from .fit.result import Result, register_writer
from .io.exr import read_exr, write_exr
from .io.files import one_line, read_bounded
from .io.ktx2 import write_ktx2
from .light.sh import SH9
from .io.png import read_png, write_png
from .options import Options, validate
from .param import mappers
from .param import projections as pj
from .shader import languages

FORMAT = "homofac.factorization"
SCHEMA_VERSION = 2
JSON_NAME = "factorization.json"
#: factorization.json files larger than this are refused before they are parsed.
MAX_JSON_BYTES = 64 << 20
#: Cube face file suffixes, in the pinned face order +X, -X, +Y, -Y, +Z, -Z (as homofac.light reads them).
FACE_NAMES = ("px", "nx", "py", "ny", "pz", "nz")
#: EXR pixel types of the float textures.
EXR_TYPES = ("float32", "half")
#: Largest texture size a loaded document may declare.
MAX_SIZE = 4096
#: A material library (docs/refit.md): one output directory per material and this index beside them.
LIBRARY_FORMAT = "homofac.library"
LIBRARY_VERSION = 1
INDEX_NAME = "index.json"
BAKE_FORMAT = "homofac.bake"
BAKE_SCHEMA = 8
BAKE_JSON = "bake.json"
#: The shader files of a bake directory (homofac_ibl, homofac_ibl_terms).
BAKE_SHADERS = {"glsl": "shader.glsl", "glsl_es": "shader_es.glsl", "hlsl": "shader.hlsl", "msl": "shader.metal",
                "wgsl": "shader.wgsl"}

#: The environment's SH9 irradiance beside every bake: pinned ``sh9.json``, and Filament's ``sh.txt`` form.
SH9_JSON = "sh9.json"
SH9_FILAMENT = "sh.txt"


class OutputOptions(Options):
    """``output``: where and what to write.

    ``png`` writes the 8-bit RGBA textures; ``exr`` is the EXR pixel type (``float32`` or ``half``);
    ``alpha`` turns the thesis' alpha precision trick (§4.3.2) of the 8-bit textures on or off;
    ``prescale`` gives the T + 1 weights ``w_0 .. w_T`` of thesis §4.3.1 (correction, then textures);
    ``preview`` writes preview.png; ``shaders`` the shader files of the listed languages; ``ktx2`` also writes
    each texture as ``<name>.ktx2`` (KTX 2.0, half float) for engines that load KTX2.
    """

    dir: str = "out"
    png: bool = False
    ktx2: bool = False
    samples: bool = True
    exr: Literal["float32", "half"] = "float32"
    alpha: bool = True
    prescale: Optional[list[float]] = Field(None, min_length=2, max_length=64)
    preview: bool = True
    shaders: list[Literal[tuple(languages.LANGUAGES)]] = Field(default_factory=list)  # type: ignore[valid-type]


# --------------------------------------------------------------------------------------------------
# Writing


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _jsonable(v: Any, bad: list) -> Any:
    """JSON-friendly values; non-finite floats become null and are counted in ``bad`` (strict JSON)."""
    if isinstance(v, dict):
        return {str(k): _jsonable(x, bad) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x, bad) for x in v]
    if isinstance(v, Path):
        return str(v)
    if hasattr(v, "shape") and hasattr(v, "dtype"):
        a = np.asarray(v)
        return _jsonable(a.item() if a.ndim == 0 else a.tolist(), bad)
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if not math.isfinite(f):
            bad.append(f)
            return None
        return f
    return v


def _format_of(path: Path, name: str):
    """The ``format`` field of the JSON file ``path / name`` (None when absent, too big or unreadable)."""
    f = Path(path) / name
    try:
        return json.loads(read_bounded(f, "a JSON", MAX_JSON_BYTES)).get("format")
    except (OSError, ValueError, AttributeError, UnicodeDecodeError, RecursionError, HomofacError):
        return None


def is_homofac_dir(path: Path) -> bool:
    """True when ``path`` holds a factorization.json written by homofac."""
    return _format_of(path, JSON_NAME) == FORMAT


def is_library_dir(path: Path) -> bool:
    """True when ``path`` holds a material library's index.json written by homofac (:func:`save_library`)."""
    return _format_of(path, INDEX_NAME) == LIBRARY_FORMAT


def is_bake_dir(path: Path) -> bool:
    """True when ``path`` holds a bake's bake.json written by homofac (:func:`save_bake`)."""
    return _format_of(path, BAKE_JSON) == BAKE_FORMAT


def check_output_dir(out_dir) -> Path:
    """Refuse output paths that are files, foreign non-empty directories, or not writable (before any work).
    A directory homofac wrote (a factorization or a material library) may be replaced."""
    out = Path(out_dir)
    parent = out.parent
    if parent.exists() and not parent.is_dir():
        raise HomofacError(f"output path {out}: parent {parent} is not a directory")
    if out.exists() and not out.is_dir():
        raise HomofacError(f"output path {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not (is_homofac_dir(out) or is_library_dir(out) or is_bake_dir(out)):
        raise HomofacError(f"output directory {out} is not empty and was not written by homofac; refusing to overwrite it")
    return out


def _make_parent(out: Path) -> None:
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise HomofacError(f"output path {out}: cannot create {out.parent}: {one_line(e)}") from None
    if not os.access(out.parent, os.W_OK | os.X_OK):
        raise HomofacError(f"output path {out}: directory {out.parent} is not writable")


class OutputLock:
    """Exclusive right to write one output directory: ``flock`` on ``.<name>.lock`` beside it.

    The concurrency rule (docs/format.md): one run writes a directory at a time; a second run that
    finds the lock held is refused at once (one line, before any work), never blocked and never
    silently overwriting the first. The lock file is removed when the lock is released; one left by a
    killed run (its flock died with it) is taken over by the next run and removed when it is done, and a
    run whose opened file was removed meanwhile by its holder opens the new one (same inode checked). Taking the lock also cleans what a killed run left behind (its
    temporary and old directories) and restores a previous result stranded by a kill between the two
    renames of the final swap. Reentrant within a process (``save`` inside ``run``).
    """

    _held: dict[str, int] = {}

    def __init__(self, out_dir):
        self.out = Path(out_dir)
        self.key = str(self.out.resolve(strict=False))
        self.fd: int | None = None

    def __enter__(self) -> "OutputLock":
        if self.key in OutputLock._held:
            OutputLock._held[self.key] += 1
            return self
        _make_parent(self.out)
        path = self.out.parent / f".{self.out.name}.lock"
        for _ in range(100):  # a lock file removed by its holder between our open and flock: open the new one
            fd = self._take(path)
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(path))
            except OSError:
                same = False
            if same:
                break
            os.close(fd)
        else:
            raise HomofacError(f"output path {self.out}: the lock file {path} keeps changing; is another run looping?")
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self.fd = fd
        OutputLock._held[self.key] = 1
        recover(self.out)
        return self

    def _take(self, path: Path) -> int:
        """Open and flock ``path`` (created when missing). A file left by a killed run has a free flock: it
        is taken over (and removed on release)."""
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666 & ~_umask())
        except OSError as e:
            raise HomofacError(f"output path {self.out}: cannot create the lock file {path}: {one_line(e)}") from None
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise HomofacError(f"output path {self.out}: the lock file {path} is not a regular file")
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise HomofacError(f"output directory {self.out} is being written by another homofac run "
                                   f"(lock {path}); wait for it or choose another --out") from None
            raise HomofacError(f"output path {self.out}: cannot lock {path}: {one_line(e)}") from None
        except BaseException:
            os.close(fd)
            raise
        return fd

    def __exit__(self, *exc) -> None:
        n = OutputLock._held.get(self.key, 0) - 1
        if n > 0:
            OutputLock._held[self.key] = n
            return
        OutputLock._held.pop(self.key, None)
        if self.fd is not None:
            # unlink while still holding the lock: a run that opened the old file is refused by it, a
            # later one creates a new file; nothing is left beside the output directory
            (self.out.parent / f".{self.out.name}.lock").unlink(missing_ok=True)
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def recover(out: Path) -> list[str]:
    """Clean the leftovers of killed runs beside ``out`` (call with its lock held); returns what was done.

    A kill between the two renames of the swap leaves ``out`` missing and the previous result in
    ``.<name>.old-*``: it is renamed back. Temporary ``.<name>.tmp-*`` directories and remaining old
    directories are removed.
    """
    done = []
    parent = out.parent
    if not parent.is_dir():
        return done
    olds = sorted(parent.glob(f".{out.name}.old-*"), key=lambda p: p.stat().st_mtime, reverse=True)
    if not out.exists() and olds and (is_homofac_dir(olds[0]) or is_library_dir(olds[0]) or is_bake_dir(olds[0])):
        os.replace(olds[0], out)
        done.append(f"restored {out} from {olds[0].name}")
        olds = olds[1:]
    for p in olds + list(parent.glob(f".{out.name}.tmp-*")):
        shutil.rmtree(p, ignore_errors=True)
        done.append(f"removed {p.name}")
    return done


def cube_faces(texture: np.ndarray) -> list[np.ndarray]:
    """The six ``(S, S, C)`` faces of a pinned ``(S, 6S, C)`` cube texture (+X, -X, +Y, -Y, +Z, -Z)."""
    t = np.asarray(texture)
    S = t.shape[0]
    return [t[:, i * S : (i + 1) * S] for i in range(6)]


def cube_vertical(texture: np.ndarray) -> np.ndarray:
    """The OpenEXR cube-map layout ``(6S, S, C)``: the pinned faces stacked top to bottom."""
    return np.concatenate(cube_faces(texture), axis=0)


def shader_files(languages_: list[str], png: bool) -> dict[str, tuple[str, bool]]:
    """File name -> (language, quantized) of the shaders written for ``languages_`` (8-bit variants with ``png``)."""
    out = {}
    for name in languages_:
        lang = languages.get(name)
        out[lang.file] = (name, False)
        if png:
            stem, ext = lang.file.rsplit(".", 1)
            out[f"{stem}_8bit.{ext}"] = (name, True)
    return out


#: Largest magnitude of a half float: a texture beyond it is written to KTX2 as float32 instead.
HALF_MAX = 65504.0


def ktx2_layout(name: str, mapper: str, size: int, uses: list, fmt: str) -> dict:
    """The ``homofac`` key of a texture's KTX2 file: what the texels mean, and how the file is laid out.

    ``cube`` textures are KTX2 cube maps (faces +X, -X, +Y, -Y, +Z, -Z of homofac's +z-up frame, the
    OpenGL face table of docs/format.md: a y-up engine looks them up at ``(x, -z, y)`` of its direction
    as ``HOMOFAC_Y_UP`` does); every other mapper is one 2D image with the EXR's layout (the mapper's
    ``(H, W)`` table, two halves side by side for ``dual_paraboloid``, one row for ``line``). One mip
    level: the factorization is read with bilinear filtering. RGB in R, G, B; alpha 1.
    """
    layout = ("cube map, faces +X -X +Y -Y +Z -Z of the +z-up frame" if mapper == "cube"
              else f"2D image laid out as the {mapper} mapper's table (docs/format.md)")
    return {"format": "homofac.texture", "texture": name, "mapper": mapper, "size": size, "uses": uses,
            "layout": layout, "layers": "none (one image per face)" if mapper == "cube" else "none",
            "levels": "1 (bilinear lookups)", "frame": "+z up", "values": "linear RGB, alpha 1", "ktx2_format": fmt}


def _ktx2_format(tex: np.ndarray) -> str:
    """``half`` unless a texel exceeds the half-float range (then ``float``)."""
    return "half" if np.abs(tex).max(initial=0.0) <= HALF_MAX else "float"


def document(fac: Result, *, png: bool = False, exr: str = "float32", encoded: Quantized | None = None,
             shaders: dict | None = None, ktx2: bool = False) -> tuple[dict, list]:
    """The factorization.json document of a result, and the non-finite values it replaced by null."""
    if exr not in EXR_TYPES:
        raise HomofacError(f"output.exr must be one of {', '.join(EXR_TYPES)}, got {exr!r}")
    model = fac.model
    enc = encoded if encoded is not None else fac.encoded()
    textures = []
    for k, t in enumerate(model.textures):
        entry = {"name": t.name, "file": f"{t.name}.exr", "mapper": t.mapper, "size": t.size,
                 "shape": list(t.shape), "uses": model.uses(t.name), "exr_type": exr,
                 "png_decode": {"offset": enc.offset[k], "scale": enc.scale[k], "alpha": bool(enc.alpha[k])}}
        if t.mapper == "cube":
            entry["faces"] = [f"{t.name}_{f}.exr" for f in FACE_NAMES]
            entry["cube_file"] = f"{t.name}_cube.exr"
        if png:
            entry["png"] = f"{t.name}.png"
            if t.mapper == "cube":
                entry["png_faces"] = [f"{t.name}_{f}.png" for f in FACE_NAMES]
        if ktx2:
            entry["ktx2"] = f"{t.name}.ktx2"
            entry["ktx2_format"] = _ktx2_format(np.asarray(t.data, np.float32))
        textures.append(entry)
    terms = [{"kind": term.kind, "correction": term.correction, "png_correction": enc.corrections[i],
              "factors": [{"projection": f.projection, "texture": f.texture} for f in term.factors]}
             for i, term in enumerate(model.terms)]
    doc = {
        "format": FORMAT,
        "schema_version": SCHEMA_VERSION,
        "homofac_version": __version__,
        "kind": model.kind,
        "name": model.name,
        "target": {"kind": model.kind, "quantity": model.quantity, **fac.target_info},
        "textures": textures,
        "terms": terms,
        "png_written": bool(png),
        "lookups": model.lookups,
        "context": model.context,
        "metrics": fac.metrics,
        "solver": fac.solver,
        "timings": fac.timings,
        "counts": fac.counts,
        "warnings": list(fac.warnings),
        "config": fac.config,
        "shaders": sorted(shaders or {}),
    }
    if fac.selection is not None:
        doc["selection"] = fac.selection
    if fac.analysis is not None:
        doc["analysis"] = fac.analysis
    if len(model.terms) == 1:  # schema 1's keys, for readers of schema 1
        main = fac._main()
        doc.update({
            "parametrization": model.name, "mapper": main.mapper, "texture_size": main.size,
            "factors": terms[0]["factors"], "correction": model.terms[0].correction,
        })
        if enc.rule.get("encoding") == "rgba8":  # the thesis' rule; affine (signed) textures have no schema-1 form
            doc["png_decode"] = {**enc.rule, "written": bool(png)}
    bad: list = []
    return _jsonable(doc, bad), bad


def _write_json(path: Path, doc: dict) -> None:
    path.write_text(json.dumps(doc, indent=2, allow_nan=False))


def save(fac: Result, out_dir, *, samples=None, extra_files: dict | None = None, png: bool = False,
         exr: str = "float32", shaders=(), ktx2: bool = False) -> Path:
    """Write the output directory atomically (see the module docstring); returns its path.

    Args:
        fac: the result (:class:`~homofac.fit.result.Result`).
        out_dir: target directory (created; a previous homofac result there is replaced whole).
        samples: optional :class:`~homofac.fit.samples.Samples` written as samples.npz.
        extra_files: ``{file name: callable(path)}`` writers of further files (e.g. a preview).
        png: also write ``<name>.png``, the 8-bit RGBA textures with their decode rule.
        exr: ``"float32"`` (bit-exact) or ``"half"`` pixels in the EXR textures.
        shaders: languages whose shader files to write (``glsl``, ``glsl_es``, ``hlsl``, ``msl``, ``wgsl``).
        ktx2: also write ``<name>.ktx2`` (KTX 2.0, RGBA half float; :func:`ktx2_layout`).

    Non-finite metrics are written as null with a warning in the document (strict JSON).
    """
    shaders = shader_files(list(shaders), png)
    return _write_dir_atomically(out_dir, "the output directory",
                                 lambda tmp: _write_all(fac, tmp, samples, extra_files, png, exr, shaders, ktx2))


def _write_dir_atomically(out_dir, what: str, write) -> Path:
    """``write(tmp)`` into a temporary sibling of ``out_dir``, then swapped into place under the output
    lock: a killed or failed write leaves the previous directory (or nothing), never a half-written one."""
    out = check_output_dir(out_dir)
    with OutputLock(out):
        out = check_output_dir(out_dir)
        tmp = out.parent / f".{out.name}.tmp-{uuid.uuid4().hex[:8]}"
        try:
            tmp.mkdir(mode=0o777 & ~_umask())
            write(tmp)
            _swap_into_place(tmp, out)
        except OSError as e:
            shutil.rmtree(tmp, ignore_errors=True)
            where = f" ({e.filename})" if getattr(e, "filename", None) else ""
            raise HomofacError(f"cannot write {what} {out}{where}: {e.strerror or one_line(e)}") from None
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    return out


def save_library(out_dir, write_members) -> Path:
    """Write a material library atomically: ``write_members(tmp)`` writes the members' output
    directories into a temporary sibling directory (e.g. with :func:`save` into ``tmp / name``) and
    returns the index, which is written (given ``format`` and ``version``) as index.json; then the directory is swapped
    into place under the output lock, as :func:`save` does: a killed or failed write leaves the
    previous library (or nothing), never a half-written one. Returns the path."""

    def write(tmp: Path) -> None:
        index = write_members(tmp)
        bad: list = []
        doc = _jsonable({"format": LIBRARY_FORMAT, "version": LIBRARY_VERSION, "homofac": __version__, **index}, bad)
        _write_json(tmp / INDEX_NAME, doc)

    return _write_dir_atomically(out_dir, "the library", write)


def _write_all(fac: Result, tmp: Path, samples, extra_files, png: bool, exr: str, shaders: dict,
               ktx2: bool = False) -> None:
    enc = fac.encoded()
    doc, bad = document(fac, png=png, exr=exr, encoded=enc, shaders=shaders, ktx2=ktx2)
    if bad:
        doc["warnings"].append(f"{len(bad)} non-finite metric values were written as null")
    half = exr == "half"
    for k, t in enumerate(doc["textures"]):
        tex = mappers.dilate(t["mapper"], t["size"], np.asarray(fac.model.textures[k].data, np.float32))
        write_exr(tmp / t["file"], tex, half=half)
        if "faces" in t:
            for f, face in zip(t["faces"], cube_faces(tex)):
                write_exr(tmp / f, face, half=half)
            write_exr(tmp / t["cube_file"], cube_vertical(tex), half=half, header={"envmap": OpenEXR.ENVMAP_CUBE})
        if ktx2:
            layout = json.dumps(ktx2_layout(t["name"], t["mapper"], t["size"], t["uses"], t["ktx2_format"]))
            if t["mapper"] == "cube":
                write_ktx2(tmp / t["ktx2"], np.stack(cube_faces(tex)), "cube", t["ktx2_format"], {"homofac": layout})
            else:
                write_ktx2(tmp / t["ktx2"], tex, "2d", t["ktx2_format"], {"homofac": layout})
        if png:
            info = {"homofac": f"texture {t['name']} of {fac.parametrization}; linear RGBA8, "
                               f"decode rule in {JSON_NAME} (textures[].png_decode)"}
            write_png(tmp / t["png"], enc.rgba[k], text=info)
            for f, face in zip(t.get("png_faces", ()), cube_faces(enc.rgba[k])):
                write_png(tmp / f, np.ascontiguousarray(face))
    for name, (lang, quant) in shaders.items():
        (tmp / name).write_text(fac.shader(lang, quantized=quant))
    if samples is not None:
        np.savez(tmp / "samples.npz", **{k: np.asarray(v, np.float32) for k, v in samples._asdict().items()})
    for name, writer in (extra_files or {}).items():
        writer(tmp / name)
    _write_json(tmp / JSON_NAME, doc)


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


# --------------------------------------------------------------------------------------------------
# Reading: the document's schema, and confined, size-checked files


#: Largest magnitude of a number that feeds the evaluation (float32's largest finite value).
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _finite32(v):
    """``v`` (a list of numbers, or None) when every value is a finite float32; else a ValueError (one line)."""
    if v is not None and not all(math.isfinite(x) and abs(x) <= FLOAT32_MAX for x in v):
        raise ValueError(f"must be finite float32 numbers (|x| <= {FLOAT32_MAX:.4g}), got {v}")
    return v


def _checked(check):
    """A pydantic validator from a ``check_*`` of :mod:`homofac.factorization` (HomofacError -> ValueError)."""
    def validator(cls, v):
        if v is None:
            return v
        try:
            return check(v, "")
        except HomofacError as e:
            raise ValueError(str(e).strip()) from None
    return classmethod(validator)


def _plain_name(v: str) -> str:
    if not isinstance(v, str) or not v or v in (".", "..") or "/" in v or "\\" in v or "\x00" in v:
        raise ValueError(f"must be a plain file name inside the directory, got {v!r}")
    return v


class PngDecode(Options):
    offset: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3)
    scale: list[float] = Field(default_factory=lambda: [1.0, 1.0, 1.0], min_length=3, max_length=3)
    alpha: bool = True

    _finite = field_validator("offset", "scale")(classmethod(lambda cls, v: _finite32(v)))


class TextureEntry(Options):
    """One entry of ``textures``."""

    model_config = Options.model_config | {"extra": "ignore"}
    name: str  # factorization.check_texture_name (docs/format.md, "Names")
    file: str
    mapper: Optional[str] = None  # schema 1: the top-level mapper
    size: Optional[int] = Field(None, ge=2, le=MAX_SIZE)
    shape: Optional[list[int]] = Field(None, min_length=2, max_length=2)
    png: Optional[str] = None
    png_decode: Optional[PngDecode] = None

    _name_file = field_validator("file", "png")(classmethod(lambda cls, v: v if v is None else _plain_name(v)))
    _name = field_validator("name", mode="before")(_checked(check_texture_name))


class FactorEntry(Options):
    model_config = Options.model_config | {"extra": "ignore"}
    projection: str
    texture: str


class TermEntry(Options):
    model_config = Options.model_config | {"extra": "ignore"}
    kind: str = "fitted"
    correction: list[float] = Field(min_length=3, max_length=3)
    png_correction: Optional[list[float]] = Field(None, min_length=3, max_length=3)
    factors: list[FactorEntry] = Field(min_length=1, max_length=64)

    _kind = field_validator("kind", mode="before")(_checked(check_identifier))
    _finite = field_validator("correction", "png_correction")(classmethod(lambda cls, v: _finite32(v)))


class Document(Options):
    """The parts of factorization.json that :func:`load` reads, validated (schema 1 or 2)."""

    model_config = Options.model_config | {"extra": "ignore"}
    format: Literal["homofac.factorization"]
    schema_version: int = Field(1, ge=1, le=SCHEMA_VERSION)
    kind: Literal["brdf", "lighting"]
    name: Optional[str] = None
    parametrization: Optional[str] = None
    mapper: Optional[str] = None
    texture_size: Optional[int] = Field(None, ge=2, le=MAX_SIZE)
    textures: list[TextureEntry] = Field(min_length=1, max_length=64)
    terms: Optional[list[TermEntry]] = Field(None, min_length=1, max_length=64)
    factors: Optional[list[FactorEntry]] = Field(None, min_length=1, max_length=64)
    correction: Optional[list[float]] = Field(None, min_length=3, max_length=3)
    png_decode: Optional[dict] = None
    target: dict = Field(default_factory=dict)
    context: dict = Field(default_factory=dict)
    metrics: dict = Field(default_factory=dict)
    solver: dict = Field(default_factory=dict)
    timings: dict = Field(default_factory=dict)
    counts: dict = Field(default_factory=dict)
    warnings: list = Field(default_factory=list)
    config: dict = Field(default_factory=dict)
    selection: Optional[dict] = None
    analysis: Optional[dict] = None

    _names = field_validator("name", "parametrization", mode="before")(_checked(check_label))
    _finite = field_validator("correction")(classmethod(lambda cls, v: _finite32(v)))

    @model_validator(mode="after")
    def _consistent(self):
        for t in self.textures:
            mapper = t.mapper or self.mapper
            size = t.size or self.texture_size
            if mapper is None or size is None:
                raise ValueError(f"texture {t.name}: no mapper and size (neither per texture nor at the top level)")
            if mapper not in mappers.MAPPERS:
                raise ValueError(f"texture {t.name}: unknown mapper {mapper!r}")
            shape = list(mappers.texture_shape(mapper, size))
            if t.shape is not None and list(t.shape) != shape:
                raise ValueError(f"texture {t.name}: shape {t.shape} does not match mapper {mapper} at size {size} ({shape})")
        names = [t.name for t in self.textures]
        if len(set(names)) != len(names):
            raise ValueError(f"texture names repeat: {names}")
        terms = self.terms if self.schema_version >= 2 and self.terms else None
        if terms is None and (self.factors is None or self.correction is None):
            raise ValueError("neither terms (schema 2) nor factors and correction (schema 1)")
        for f in [f for term in (terms or []) for f in term.factors] + list(self.factors or []):
            if f.texture not in names:
                raise ValueError(f"factor texture {f.texture!r} is not one of {names}")
            if f.projection not in pj.PROJECTIONS:
                raise ValueError(f"unknown projection {f.projection!r}")
        return self


def _confined(d: Path, name: str, what: str) -> Path:
    """``d / name`` after checking it is a regular file inside ``d`` (symlinks may not leave it)."""
    p = d / _plain_name_or_fail(d, name)
    try:
        real, root = p.resolve(strict=True), d.resolve(strict=True)
    except (OSError, RuntimeError):
        raise HomofacError(f"{p}: {what} file is missing") from None
    if root not in real.parents:
        raise HomofacError(f"{p}: {what} file leads outside the output directory; refusing to read it")
    if not real.is_file():
        raise HomofacError(f"{p}: {what} file is not a regular file")
    return p


def _plain_name_or_fail(d: Path, name: str) -> str:
    try:
        return _plain_name(name)
    except ValueError as e:
        raise HomofacError(f"{d / JSON_NAME}: {e}") from None


def read_document(d: Path, name: str = JSON_NAME, fmt: str = FORMAT, what: str = "a homofac factorization") -> dict:
    """The raw ``name`` JSON of ``d`` (a regular file, strict JSON, size-capped) whose ``format`` is ``fmt``, as a dict."""
    f = d / name
    try:
        size = f.stat().st_size
    except OSError as e:
        raise HomofacError(f"{d}: cannot read {name} ({e.strerror or e})") from None
    if size > MAX_JSON_BYTES:
        raise HomofacError(f"{f}: {size} bytes; a {name} is far smaller (at most {MAX_JSON_BYTES})")
    raw = read_bounded(f, "a JSON", MAX_JSON_BYTES)

    def no_constants(c):
        raise ValueError(f"non-standard JSON constant {c}")

    try:
        doc = json.loads(raw.decode("utf-8"), parse_constant=no_constants)
    except UnicodeDecodeError:
        raise HomofacError(f"{f}: not UTF-8 text") from None
    except RecursionError:
        raise HomofacError(f"{f}: nested too deeply") from None
    except ValueError as e:
        raise HomofacError(f"{f}: not valid JSON ({one_line(e)})") from None
    if not isinstance(doc, dict):
        raise HomofacError(f"{f}: the top level must be a JSON object, got {type(doc).__name__}")
    if doc.get("format") != fmt:
        raise HomofacError(f"{f}: not {what}")
    return doc


#: Default cap on the texture memory of :func:`load`, all textures together: 1 GiB.
MAX_LOAD_BYTES = 1 << 30


def _texture_bytes(specs, png: bool, exr: bool) -> int:
    """Bytes of reading the declared textures: float32 RGB and the reader's temporaries (28 per texel),
    the RGBA8 copy and its temporaries when PNG files are read (20)."""
    texels = sum(int(np.prod(mappers.texture_shape(mapper, size))) for _, mapper, size in specs)
    return texels * ((28 if exr else 12) + (20 if png else 0))


def load(out_dir, textures: str = "exr", *, max_bytes: int = 1 << 28, max_total_bytes: int | None = MAX_LOAD_BYTES) -> Result:
    """Read an output directory back into a :class:`~homofac.fit.result.Result` (schema 1 or 2), or a bake
    directory (it holds bake.json, no factorization.json) into a :class:`~homofac.bake.Bake` (:func:`load_bake`).

    ``textures="exr"`` (default): the float textures from the EXR files; when PNG files were written
    they are read too and ``evaluate(a, b, quantized=True)`` decodes exactly those (else the 8-bit
    encoding is recomputed from the EXR textures with the stored settings). ``textures="png"``: only
    the 8-bit PNG textures and their decode rule; ``evaluate(a, b)`` then decodes them and the model's
    texels are their decoded float values. ``max_bytes`` caps each texture read, ``max_total_bytes``
    (default :data:`MAX_LOAD_BYTES`, None: no cap) the memory of all of them together, counted from the
    declared sizes before any texture is read (many entries may name one file). A missing, truncated,
    mismatched or misplaced file raises a one-line HomofacError naming it; running out of memory while
    reading says so (not "corrupt").
    """
    if textures not in ("exr", "png"):
        raise HomofacError(f"load: textures must be 'exr' or 'png', got {textures!r}")
    d = Path(out_dir)
    if not d.is_dir():
        raise HomofacError(f"{d}: no such directory" if not d.exists() else f"{d}: not a directory")
    if (d / BAKE_JSON).is_file() and not (d / JSON_NAME).exists():
        return load_bake(d, max_bytes=max_bytes)
    raw = read_document(d)
    doc = validate(Document, raw, str(d / JSON_NAME))
    specs = [(t, t.mapper or doc.mapper, int(t.size or doc.texture_size)) for t in doc.textures]
    if doc.schema_version >= 2 and doc.terms:
        terms_doc = doc.terms
    else:
        terms_doc = [TermEntry(kind="fitted", correction=doc.correction, factors=doc.factors)]
    quantity = doc.target.get("quantity", "lighting" if doc.kind == "lighting" else "brdf")
    context = {}
    for k, v in (doc.context or {}).items():
        try:
            context[k] = pj.check_context(k, v)
        except HomofacError as e:
            raise HomofacError(f"{d / JSON_NAME}: {e}") from None
    has_png = all(t.png for t, _, _ in specs)
    need = _texture_bytes(specs, textures == "png" or has_png, textures == "exr")
    if max_total_bytes is not None and need > max_total_bytes:
        raise HomofacError(f"{d / JSON_NAME}: its {len(specs)} textures need {need / (1 << 30):.2f} GiB to load, over "
                           f"the memory budget of {max_total_bytes / (1 << 30):.2f} GiB")
    try:
        return _load(d, doc, raw, specs, terms_doc, quantity, context, textures, has_png, max_bytes)
    except MemoryError:
        raise HomofacError(f"{d}: out of memory loading {len(specs)} textures ({need / (1 << 30):.2f} GiB declared): "
                           "over the memory this process may use (ulimit -v, cgroup)") from None


def _load(d, doc, raw, specs, terms_doc, quantity, context, textures, has_png, max_bytes) -> Result:
    """The textures and the Result of :func:`load` (after its checks)."""
    quant = None
    if textures == "png" or has_png:
        quant = _read_png(d, doc, raw, specs, terms_doc)
    if textures == "png":
        data = decode_texels(quant)
        terms_doc = [TermEntry(kind=term.kind, correction=list(map(float, c)), factors=term.factors)
                     for term, c in zip(terms_doc, quant.corrections)]
    else:
        data = []
        for t, mapper, size in specs:
            a = read_exr(_confined(d, t.file, "texture"), max_bytes=max_bytes)
            want = tuple(mappers.texture_shape(mapper, size))
            if a.shape[:2] != want:
                raise HomofacError(f"{d / t.file}: shape {list(a.shape[:2])} does not match {JSON_NAME} "
                                   f"({mapper} at size {size}: {list(want)})")
            data.append(a)
    try:
        model = Factorization(
            doc.kind, quantity,
            tuple(Texture(t.name, mapper, size, np.asarray(a, np.float32)) for (t, mapper, size), a in zip(specs, data)),
            tuple(Term(tuple(Factor(f.projection, f.texture) for f in term.factors),
                       np.asarray(term.correction, np.float32), term.kind) for term in terms_doc),
            context, doc.name or doc.parametrization or "",
        )
    except HomofacError as e:
        raise HomofacError(f"{d / JSON_NAME}: {e}") from None
    if quant is not None:
        check_rgba(quant, model)
    encoding = {}
    rule = raw.get("png_decode") if isinstance(raw.get("png_decode"), dict) else None
    if rule and isinstance(rule.get("prescale"), list) and len(model.terms) == 1:
        encoding = {"alpha": bool(rule.get("alpha", True))}
        if any(abs(float(x) - 1.0) > 1e-12 for x in rule["prescale"] if isinstance(x, (int, float))):
            encoding["weights"] = [float(x) for x in rule["prescale"]]
    return Result(
        model, metrics=doc.metrics, solver=doc.solver, timings=doc.timings, counts=doc.counts, config=doc.config,
        target_info={k: v for k, v in doc.target.items() if k not in ("kind", "quantity")},
        warnings=tuple(str(w) for w in doc.warnings), encoding=encoding, quantized=quant, selection=doc.selection,
        analysis=doc.analysis,
        source="png" if textures == "png" else "float",
    )


def _read_png(d: Path, doc: Document, raw: dict, specs, terms_doc) -> Quantized:
    """The 8-bit textures and decode rule a document describes (schema 2 per texture, or schema 1's rule)."""
    rgba, offs, scales, alphas = [], [], [], []
    for t, mapper, size in specs:
        if not t.png:
            raise HomofacError(f"{d / JSON_NAME}: texture {t.name} has no PNG file (write with output.png: true)")
        a = read_png(_confined(d, t.png, "PNG texture"))
        want = tuple(mappers.texture_shape(mapper, size))
        if a.shape[:2] != want:
            raise HomofacError(f"{d / t.png}: shape {list(a.shape[:2])} does not match {JSON_NAME} ({list(want)})")
        rgba.append(a)
        rule = t.png_decode or PngDecode()
        offs.append(np.asarray(rule.offset, np.float64))
        scales.append(np.asarray(rule.scale, np.float64))
        alphas.append(bool(rule.alpha))
    if doc.schema_version >= 2 and doc.terms and all(term.png_correction is not None for term in doc.terms):
        corrections = tuple(np.asarray(term.png_correction, np.float64) for term in doc.terms)
    else:  # schema 1: colour * scale of the thesis' rule (the prescale is folded into the texels)
        rule = raw.get("png_decode")
        try:
            colour = np.asarray(rule["colour"], np.float64).reshape(3)
            z = float(rule["scale"])
            alpha = bool(rule["alpha"])
        except (KeyError, TypeError, ValueError) as e:
            raise HomofacError(f"{d / JSON_NAME}: malformed png_decode rule ({one_line(e)})") from None
        if not (np.all(np.isfinite(colour)) and math.isfinite(z) and np.all(np.abs(colour * z) <= FLOAT32_MAX)):
            raise HomofacError(f"{d / JSON_NAME}: png_decode has values that are not finite float32 numbers")
        corrections = (colour * z,)
        alphas = [alpha for _ in alphas]
        if len(terms_doc) != 1:
            raise HomofacError(f"{d / JSON_NAME}: schema-1 png_decode describes one term, the document has {len(terms_doc)}")
    rule = raw.get("png_decode") if isinstance(raw.get("png_decode"), dict) else {"encoding": "rgba8-affine"}
    return Quantized(tuple(rgba), tuple(offs), tuple(scales), tuple(alphas), corrections,
                     {k: v for k, v in rule.items() if k != "written"})


register_writer(save)

__all__ = ["Document", "EXR_TYPES", "FACE_NAMES", "FORMAT", "INDEX_NAME", "JSON_NAME", "LIBRARY_FORMAT", "LIBRARY_VERSION",
           "MAX_LOAD_BYTES", "read_document",
           "OutputLock", "OutputOptions", "SCHEMA_VERSION", "check_output_dir", "cube_faces", "cube_vertical", "document",
           "is_homofac_dir", "is_library_dir", "load", "recover", "save", "save_library", "shader_files"]


# --------------------------------------------------------------------------------------------------
# The bake directory (docs/format.md "The bake directory")


class BakeBlockEntry(Options):
    """One layer's block in a specular map's atlas (schema 5): first texel (x, y), face size (an (S, 6 S) block)."""

    x: int = Field(ge=0, le=MAX_SIZE * 6)
    y: int = Field(ge=0, le=MAX_SIZE * 6)
    size: int = Field(ge=1, le=MAX_SIZE)


class BakeTextureEntry(Options):
    name: str = Field(pattern=r"^[PEW][0-9]{1,2}$", description="P<k>, E<d> or W<t>: the shader reads hf_<name>")
    file: str = Field(pattern=r"^[PEW][0-9]{1,2}\.exr$")
    ktx2: Optional[str] = Field(None, pattern=r"^[PEW][0-9]{1,2}\.ktx2$")
    kind: Literal["prefiltered", "diffuse", "weights"]
    width: int = Field(ge=1, le=MAX_SIZE * 6)
    height: int = Field(ge=1, le=MAX_SIZE * 6)
    channels: list[str]
    #: schema 5, a prefiltered map: each layer's block in this map's atlas (width x height)
    blocks: Optional[list[BakeBlockEntry]] = Field(None, max_length=32)


class BakeLayerEntry(Options):
    roughness: float = Field(gt=0, le=1)
    shift: float = Field(ge=0, le=1)
    size: int = Field(ge=2, le=MAX_SIZE)
    #: schemas 1-4: the layer's block in every map's atlas (schema 5: each map's ``blocks``)
    x: Optional[int] = Field(None, ge=0)
    y: Optional[int] = Field(None, ge=0)


class BakePlanEntry(Options):
    """bake.json's ``plan`` (:class:`homofac.bake.BakePlan`), every field bounded: it reaches generated code."""

    preset: Literal["fast", "balanced", "best"]
    terms: int = Field(ge=1, le=8)
    diffuse: int = Field(ge=0, le=8)
    layers: int = Field(ge=3, le=32)
    nv_size: int = Field(ge=2, le=MAX_SIZE)
    max_size: int = Field(ge=2, le=MAX_SIZE)
    diffuse_size: int = Field(ge=2, le=MAX_SIZE)
    min_roughness: float = Field(gt=0, le=1)
    diffuse_basis: Literal["texture", "sh9"] = "texture"
    #: schema 3: the layers from this roughness up store the second harmonic (0: none; schemas 1-2: none)
    harmonic: float = Field(0.0, ge=0, le=1)
    #: schema 4: the harmonic layers store K - 1 products and the harmonic in the K-th's channels (schemas 1-3: no)
    mixed: bool = False
    #: P_2..P_K's face divisor (schema 5; informative: each map's blocks give the sizes the maps are read at)
    later_face: int = Field(1, ge=1, le=64)
    #: schema 7: the harmonic's one table channel h_A scales I_A and I_B (schemas 1-6: h_A and h_B, or mixed)
    shared_gain: bool = False
    #: schema 8: the sharp layers' shared block's face (0 or absent, schemas 1-7: max_size; informative: the layers'
    #: sizes and each map's blocks give the sizes the maps are read at)
    block_size: int = Field(0, ge=0, le=MAX_SIZE)


class BakeSourceEntry(Options):
    """bake.json's ``sources[i]`` (:class:`homofac.bake.sources.Source`): a point light the shaders add with the
    exact glTF lobes; every number finite and bounded (they reach generated code)."""

    direction: list[float] = Field(min_length=3, max_length=3)
    power: list[float] = Field(min_length=3, max_length=3)
    radius: float = Field(ge=0, le=math.pi)
    #: schema 6: the two principal semi-axes (rad) of the source's core normal to ``direction``; absent: round
    axes: list[list[float]] | None = Field(None, min_length=2, max_length=2)
    #: schema 8: the core's box half-widths (rad) along its ``axes`` (homofac.bake.sources.box_widths); absent: a
    #: Gaussian core
    box: list[float] | None = Field(None, min_length=2, max_length=2)
    #: schema 8: the core's widths in units of ``axes`` (each entry's own, ``homofac.bake.sources.core_factor``,
    #: since the twenty-second session; ``CORE`` before); absent: the factor of the code that wrote the bake
    #: (:func:`legacy_core`)
    core: Optional[float] = Field(None, gt=0, le=10)

    @field_validator("box")
    @classmethod
    def _box(cls, v):
        if v is not None and not all(math.isfinite(c) and 0 <= c <= math.pi for c in v):
            raise ValueError("must be two finite half-widths in [0, pi] (rad)")
        return v

    @field_validator("axes")
    @classmethod
    def _axes(cls, v):
        if v is not None and not all(len(a) == 3 and all(math.isfinite(c) and abs(c) <= math.pi for c in a) for a in v):
            raise ValueError("must be two 3-vectors of finite numbers within pi (rad)")
        return v

    @field_validator("direction")
    @classmethod
    def _unit(cls, v):
        if not all(math.isfinite(c) for c in v) or abs(math.sqrt(sum(c * c for c in v)) - 1.0) > 1e-3:
            raise ValueError("must be a finite unit vector")
        return v

    @field_validator("power")
    @classmethod
    def _power(cls, v):
        if not all(math.isfinite(c) and 0 <= c <= 1e30 for c in v):
            raise ValueError("must be 3 finite non-negative numbers (RGB radiance integral)")
        return v


class BakeDocument(Options):
    """bake.json (schema 8: ``plan.block_size``, the sharp block's face, absent in schema 7 and older: max_size;
    ``sources[i].core``, the core's width factor, absent: :func:`legacy_core`; sources may give their core's ``box``,
    absent: Gaussian cores; schema 7: ``plan.shared_gain``, absent in schema 6 and older: read as false; schema 6:
    sources may give their ``axes``; schema 5 is read with round sources; schema 5: each
    specular map's blocks in its own atlas; schema 4 is read with every map in the
    shelf packer's layout of ``layers``' x, y; schema 3 is read as a bake without ``plan.mixed``, schema 2 as one without the harmonic, schema 1, without ``sources``, as a
    bake without sources either): see docs/format.md."""

    format: Literal["homofac.bake"]
    schema_version: Literal[1, 2, 3, 4, 5, 6, 7, 8]
    brdf: Literal["gltf"]
    plan: BakePlanEntry
    lookups: int
    layer_coordinate: str
    layers: list[BakeLayerEntry] = Field(min_length=3)
    diffuse_size: int = Field(ge=2, le=MAX_SIZE)
    nv_size: int = Field(ge=2, le=MAX_SIZE)
    textures: list[BakeTextureEntry]
    exr: str = "half"
    homofac: str = ""
    texture_bytes_half: int = 0
    shaders: dict[Literal[tuple(BAKE_SHADERS)], Literal[tuple(BAKE_SHADERS.values())]] = {}  # type: ignore[valid-type]
    sh9: Optional[dict[Literal["json", "filament"], Literal[SH9_JSON, SH9_FILAMENT]]] = None
    #: with plan.diffuse_basis sh9: the E_d maps' SH9 coefficients (D x 9 x RGB), finite (they reach generated code)
    diffuse_sh9: Optional[list[list[list[float]]]] = None
    #: the analytic lights taken out of the maps (schema 2; at most 2 MAX_SOURCES = 16: a core and a halo per light)
    sources: list[BakeSourceEntry] = Field(default_factory=list, max_length=2 * MAX_SOURCES)
    info: dict = {}


def bake_document(bake: Bake, exr: str = "half") -> dict:
    """The bake.json of ``bake`` (see docs/format.md)."""
    pl = bake.plan
    atlases = bake.atlases
    chans = ([f"{c}{k}" for k in range(pl.terms) for c in ("a", "b")] + [f"w{d}" for d in range(pl.diffuse)]
             + ((["hA"] if pl.shared_gain else ["hA", "hB"]) if pl.harmonic and not pl.mixed else []))
    if pl.mixed and pl.harmonic:  # a_K, b_K's channels carry h_A, h_B in the harmonic layers
        chans[2 * pl.terms - 2:2 * pl.terms] = [f"a{pl.terms - 1}/hA", f"b{pl.terms - 1}/hB"]
    tex = [{"name": f"P{i}", "file": f"P{i}.exr", "kind": "prefiltered", "width": a.width, "height": a.height,
            "channels": c if pl.harmonic else ["r", "g", "b"],
            "blocks": [{"x": x, "y": y, "size": sz} for (x, y), sz in zip(a.offsets, a.sizes)]}
           for i, (a, c) in enumerate(zip(atlases, bake_shader.specular_channels(bake)))]
    s = pl.diffuse_size
    tex += [{"name": f"E{d}", "file": f"E{d}.exr", "kind": "diffuse", "width": 6 * s, "height": s,
             "channels": ["r", "g", "b"]} for d in range(pl.diffuse if pl.diffuse_basis == "texture" else 0)]
    tex += [{"name": f"W{t}", "file": f"W{t}.exr", "kind": "weights", "width": pl.nv_size, "height": pl.layers,
             "channels": (chans[3 * t:3 * t + 3] + ["-", "-"])[:3]} for t in range(pl.tables)]
    bad: list = []
    return {
        "format": BAKE_FORMAT, "schema_version": BAKE_SCHEMA, "homofac": __version__, "brdf": "gltf",
        "plan": pl._asdict(), "lookups": bake.lookups,
        "layer_coordinate": "u = (layers - 1) log(rho / rho_0) / log(rho_last / rho_0), clamped to [0, layers - 1]",
        "layers": [{"roughness": r, "shift": sh, "size": sz} for r, sh, sz in zip(bake.roughness, bake.shift, atlases[0].sizes)],
        "diffuse_size": s, "nv_size": pl.nv_size, "textures": tex, "exr": exr, "shaders": dict(BAKE_SHADERS),
        "texture_bytes_half": bake.texture_bytes(),
        **({"diffuse_sh9": np.asarray(bake.sh, np.float64).tolist()} if pl.diffuse_basis == "sh9" else {}),
        "sources": [{"direction": list(src.direction), "power": list(src.power), "radius": src.radius,
                     **({"axes": [list(a) for a in src.axes]} if src.axes else {}),
                     **({"box": list(src.box)} if src.box else {}), "core": src.core} for src in bake.sources],
        "info": _jsonable(bake.info, bad),
    }


def bake_ktx2_layout(doc: dict, entry: dict) -> dict:
    """The ``homofac`` key of a bake texture's KTX2 file (docs/format.md "The bake directory"): what the texels
    mean and where each part of the 2D image lies, so that an engine can read the file without bake.json.

    ``P<k>`` is an atlas of cube-layout blocks, one per roughness layer (``layers``: roughness, shift, and this
    map's block: size S and first texel x, y; a block is (S, 6 S), faces +X -X +Y -Y +Z -Z left to right); ``E<d>``
    one cube layout (S, 6 S); ``sources`` the analytic lights the maps exclude (bake.json's); ``W<t>`` a table with one row per layer and one column per n.v (texel centres
    (i + 0.5) / X), its channels named by ``channels``. Rows are in file order (row 0 read at v = 0), the
    frame is homofac's +z up, the values linear; alpha is 1.
    """
    faces = "faces +X -X +Y -Y +Z -Z left to right (docs/conventions.md cube mapper)"
    common = {"format": "homofac.bake.texture", "texture": entry["name"], "kind": entry["kind"],
              "width": entry["width"], "height": entry["height"], "channels": entry["channels"],
              "rows": "file order: row 0 is read at v = 0", "frame": "homofac world, +z up", "values": "linear, alpha 1",
              # the maps exclude these point lights: an engine adds their exact glTF lobes (docs/format.md)
              "sources": doc.get("sources", [])}
    if entry["kind"] == "prefiltered":
        return {**common, "mapper": "cube", "layout": f"atlas: layer j is an (S, 6 S) cube-layout block at texel (x, y), {faces}",
                "layer_coordinate": doc["layer_coordinate"],
                "layers": [{"roughness": layer["roughness"], "shift": layer["shift"], **block}
                           for layer, block in zip(doc["layers"], entry["blocks"])]}
    if entry["kind"] == "diffuse":
        return {**common, "mapper": "cube", "size": doc["diffuse_size"], "layout": f"one (S, 6 S) cube layout, {faces}"}
    return {**common, "mapper": "line x line", "layout": "rows: roughness layers u = 0 .. L - 1 (layer_coordinate); "
            "columns: n.v, texel centres (i + 0.5) / X", "layer_coordinate": doc["layer_coordinate"],
            "layers": len(doc["layers"]), "nv_size": doc["nv_size"]}


def save_bake(bake: Bake, out_dir, *, exr: str | None = None, ktx2: bool | None = None) -> Path:
    """Write a bake directory atomically: bake.json, ``P<k>.exr`` (layer atlases), ``E<d>.exr`` (cube
    layout), ``W<t>.exr`` (weight tables, rows = layers, columns = n.v), the shaders (:data:`BAKE_SHADERS`),
    the environment's SH9 irradiance (``sh9.json``, pinned, and Filament's ``sh.txt``) and, with ``ktx2``, each
    texture also as ``<name>.ktx2`` (RGBA half float, the same 2D layout; listed as ``ktx2`` in bake.json)."""
    exr = exr or str(bake.info.get("options", {}).get("exr", "half"))
    ktx2 = bool(bake.info.get("options", {}).get("ktx2", False)) if ktx2 is None else ktx2
    if exr not in EXR_TYPES:
        raise HomofacError(f"bake.save: exr must be one of {', '.join(EXR_TYPES)}, got {exr!r}")
    half = exr == "half"
    pl = bake.plan

    def write(tmp: Path) -> None:
        doc = bake_document(bake, exr)
        for entry, (_, array) in zip(doc["textures"], bake_shader.texture_arrays(bake)):
            write_exr(tmp / entry["file"], array, half=half, alpha=True)
            if ktx2:
                entry["ktx2"] = f"{entry['name']}.ktx2"
                write_ktx2(tmp / entry["ktx2"], array, kind="2d", format="half" if half else "float",
                           layout=bake_ktx2_layout(doc, entry))
        sh = (bake.info or {}).get("sh9")
        if sh:
            sh9 = SH9(np.asarray(sh["irradiance"], np.float64), dict(sh.get("error") or {}))
            (tmp / SH9_JSON).write_text(json.dumps(sh9.document(), indent=1) + "\n")
            (tmp / SH9_FILAMENT).write_text(sh9.filament_text())
            doc["sh9"] = {"json": SH9_JSON, "filament": SH9_FILAMENT}
        for language, name in BAKE_SHADERS.items():
            (tmp / name).write_text(bake_shader.source(bake, language))
        _write_json(tmp / BAKE_JSON, doc)

    return _write_dir_atomically(out_dir, "the bake directory", write)


def load_bake(d, *, max_bytes: int = 1 << 28) -> Bake:
    """Read a bake directory back (:func:`save_bake`); one-line errors naming the bad file."""
    d = Path(d)
    f = d / BAKE_JSON
    raw = read_document(d, BAKE_JSON, BAKE_FORMAT, "a homofac bake")
    doc = validate(BakeDocument, raw, str(f))
    pl = BakePlan(**doc.plan.model_dump())
    rgba = doc.schema_version < 5 and pl.harmonic > 0  # schemas 3-4: the tensor's 5 channels in RGBA maps
    maps = _rgba_maps(pl) if rgba else pl.maps
    if len(doc.layers) != pl.layers or doc.lookups != pl.lookups + 2 * (maps - pl.maps):
        raise HomofacError(f"{f}: the layers or lookups do not match the plan")
    by_kind = {k: [t for t in doc.textures if t.kind == k] for k in ("prefiltered", "diffuse", "weights")}
    atlases, blocks = _bake_layouts(doc, by_kind["prefiltered"], f)
    sizes = [layer.size for layer in doc.layers]
    sh9 = pl.diffuse_basis == "sh9"
    if (len(by_kind["prefiltered"]), len(by_kind["diffuse"]), len(by_kind["weights"])) != (
            maps, 0 if sh9 else pl.diffuse, pl.tables):
        raise HomofacError(f"{f}: texture count does not match the plan")
    if any(len(t.channels) != (4 if rgba else 3) for t in by_kind["prefiltered"]):
        raise HomofacError(f"{f}: the specular maps' channels do not match the plan "
                           f"({'RGBA: schema 3-4 with the harmonic' if rgba else 'RGB'})")
    sh = None
    if sh9:
        sh = np.asarray(doc.diffuse_sh9 if doc.diffuse_sh9 is not None else [], np.float64)
        if sh.shape != (pl.diffuse, 9, 3) or not np.all(np.isfinite(sh)) or np.abs(sh).max(initial=0) > 1e30:
            raise HomofacError(f"{f}: diffuse_sh9 must hold {pl.diffuse} x 9 x 3 finite coefficients (plan diffuse_basis sh9)")

    def read(t: BakeTextureEntry, shape) -> np.ndarray:
        a = read_exr(_confined(d, t.file, "texture"), max_bytes=max_bytes, alpha=t.kind == "prefiltered" and rgba)
        if a.shape[:2] != tuple(shape):
            raise HomofacError(f"{d / t.file}: shape {list(a.shape[:2])} does not match {BAKE_JSON} ({list(shape)})")
        if not np.all(np.isfinite(a)):
            raise HomofacError(f"{d / t.file}: non-finite texels")
        return np.asarray(a, np.float32)

    # each block back at its layer's face (a smaller block replicated: its box average is the stored block)
    ps = [[up(blk, s // a.sizes[j]) for j, (blk, s) in enumerate(zip(split(a, read(t, (a.height, a.width))), sizes))]
          for a, t in zip(atlases, by_kind["prefiltered"])]
    H: tuple = ()
    harm = set(pl.harmonic_layers())
    if pl.harmonic and not rgba:  # RGB maps: P_k's RGB; the tensor's face gauge in map K (mixed: K - 1, harmonic layers)
        g = pl.terms - 1 if pl.mixed else pl.terms
        P = tuple(np.stack([ps[k][j][..., :3] if k < g or j not in harm or not pl.mixed else np.zeros_like(ps[k][j][..., :3])
                            for k in range(pl.terms)], axis=2) for j in range(pl.layers))
        H = tuple(np.ascontiguousarray(ps[g][j][..., :3]) if j in harm else None for j in range(pl.layers))
    elif pl.harmonic and pl.mixed:  # RGBA maps: K - 1 products' RGB, then P_K's RGB or (harmonic layers) the tensor
        flat = [np.concatenate([p[j][..., :4] for p in ps], axis=-1) for j in range(pl.layers)]
        harm, k1 = set(pl.harmonic_layers()), 3 * pl.terms - 3
        P = tuple(np.concatenate([a[..., :k1], np.zeros_like(a[..., :3]) if j in harm else a[..., k1:k1 + 3]], -1)
                  .reshape(a.shape[:2] + (pl.terms, 3)) for j, a in enumerate(flat))
        H = tuple(np.ascontiguousarray(a[..., k1:k1 + 5]) if j in harm else None for j, a in enumerate(flat))
    elif pl.harmonic:  # RGBA maps: the K products' RGB, then the tensor's 5 channels (docs/format.md)
        flat = [np.concatenate([p[j][..., :4] for p in ps], axis=-1) for j in range(pl.layers)]
        P = tuple(a[..., :3 * pl.terms].reshape(a.shape[:2] + (pl.terms, 3)) for a in flat)
        H = tuple(np.ascontiguousarray(a[..., 3 * pl.terms:3 * pl.terms + 5]) if rho >= pl.harmonic else None
                  for a, rho in zip(flat, (layer.roughness for layer in doc.layers)))
    else:
        P = tuple(np.stack([p[j][..., :3] for p in ps], axis=2) for j in range(pl.layers))
    if rgba:  # schemas 3-4 store (M_xx, M_yy, M_xy, M_xz, M_yz): read in the face gauge, as a bake stores it now
        H = tuple(None if h is None else face_gauge(h, h.shape[0]) for h in H)
    s = doc.diffuse_size
    E = None if sh9 else np.stack([read(t, (s, 6 * s))[..., :3] for t in by_kind["diffuse"]], axis=2)
    W = np.concatenate([read(t, (pl.layers, doc.nv_size))[..., :3] for t in by_kind["weights"]], axis=-1)[:, :, :pl.channels]
    return Bake(pl, tuple(layer.roughness for layer in doc.layers), tuple(layer.shift for layer in doc.layers), P, E, W,
                dict(raw.get("info") or {}), sh=None if sh is None else sh.astype(np.float32), blocks=blocks,
                sources=tuple(Source(tuple(e.direction), tuple(e.power), e.radius,
                                     tuple(tuple(a) for a in e.axes) if e.axes else (),
                                     box=tuple(e.box) if e.box and e.axes else (),
                                     core=e.core if e.core is not None else legacy_core(doc)) for e in doc.sources), H=H,
                layouts=atlases)


#: The core's width factor (``homofac.bake.sources.CORE``) of the code that wrote bake.json schemas 6-7 without
#: ``sources[i].core``: 1.15 (the eighteenth and nineteenth sessions), 1.2 from the twentieth session's core and
#: halo per light, whose bakes record ``info.analytic_source.lights``.
LEGACY_CORE = (1.15, 1.2)


def legacy_core(doc: BakeDocument) -> float:
    """The core width factor a bake.json without ``sources[i].core`` (schema 7 and older) was baked with:
    :data:`LEGACY_CORE`'s second when its ``info.analytic_source`` counts ``lights`` (the twentieth session's
    core-and-halo bakes), else its first."""
    found = (doc.info or {}).get("analytic_source") or {}
    return LEGACY_CORE[1] if isinstance(found, dict) and "lights" in found else LEGACY_CORE[0]


def _rgba_maps(pl: BakePlan) -> int:
    """The specular map count of a bake.json of schema 3-4 with the harmonic: RGBA maps holding the products' RGB
    and the tensor's 5 channels, ceil((3 K + 5) / 4) (mixed: ceil((3 K + 2) / 4))."""
    return math.ceil((3 * pl.terms + (2 if pl.mixed else 5)) / 4)


def _bake_layouts(doc: BakeDocument, maps: list, f: Path) -> tuple[tuple[Atlas, ...], tuple[int, ...]]:
    """Each specular map's layout and the layers' shared blocks (the first map's), checked: schema 5 reads each
    map's ``blocks`` (every block inside its map's width x height, blocks disjoint unless shared, each layer's
    block of the layer's size or a power-of-two fraction of it: that map's layer box-averaged per face; each map
    shares blocks between its own layers, e.g. one block of zeros for every layer without that map's content);
    schemas 1-4 the ``layers``' x, y, which must be the shelf packer's layout (:func:`homofac.bake.atlas.pack`),
    shared by every map."""
    sizes = [layer.size for layer in doc.layers]
    if doc.schema_version < 5:
        offsets = [(layer.x, layer.y) for layer in doc.layers]
        if any(x is None or y is None for x, y in offsets):
            raise HomofacError(f"{f}: layers: schema {doc.schema_version} gives each layer's x and y")
        blocks = blocks_of(offsets, sizes)
        try:
            atlas = pack(sizes, blocks)
        except ValueError as e:
            raise HomofacError(f"{f}: layers: {e}") from None
        if offsets != list(atlas.offsets):
            raise HomofacError(f"{f}: layer offsets do not match the atlas layout")
        return (atlas,) * len(maps), blocks
    atlases, shared = [], []
    for t in maps:
        if t.blocks is None or len(t.blocks) != len(doc.layers):
            raise HomofacError(f"{f}: texture {t.name}: schema 5 gives one block per layer ({len(doc.layers)})")
        a = Atlas(t.width, t.height, tuple((b.x, b.y) for b in t.blocks), tuple(b.size for b in t.blocks))
        if any(s < 1 or size % s or (size // s) & (size // s - 1) for s, size in zip(a.sizes, sizes)):
            raise HomofacError(f"{f}: texture {t.name}: block sizes {list(a.sizes)} are not the layers' sizes {sizes} "
                               "or power-of-two fractions of them")
        try:
            shared.append(check_layout(a))
        except ValueError as e:
            raise HomofacError(f"{f}: texture {t.name}: {e}") from None
        atlases.append(a)
    return tuple(atlases), (shared[0] if shared else tuple(range(len(sizes))))


register_bake_writer(save_bake)
