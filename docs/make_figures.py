"""Make the figures of docs/conventions.md from homofac's own functions: ``python docs/make_figures.py``.

Writes docs/img/*.png (committed; run this again after a mapper or convention changes):

* ``mapper_<name>.png`` for every registered mapper: the texture of size S as a file stores it (row 0
  at the top, column 0 at the left), each texel coloured by the direction of its centre
  (``texel_directions``), texels whose centre lies outside the mapped domain but that hold data
  (``valid_mask`` minus ``inside_mask``) hatched, texels that hold no data grey with a cross;
* ``latlong.png``: the pinned lat-long layout;
* ``bilinear.png``: two bilinear footprints of ``mappers.bilinear``: clamped to a face, and an
  out-of-domain direction whose invalid corners get weight 0;
* ``tangent.png``: the length of x - (x.n) n over the sphere, zero at n = +-x where t(n) is singular.

Needs matplotlib (the dev extra). The pictures are computed, not drawn: they show what the code does.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.patches as patches  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from homofac import sphere  # noqa: E402
from homofac.param import mappers  # noqa: E402

OUT = Path(__file__).resolve().parent / "img"
#: Texture size of the figures (12 shows the invalid corners of the disk-shaped faces).
S = 12
#: Per mapper, when it differs.
SIZES = {"cube": 6, "octahedral": 8, "line": 16}
#: No software/date metadata in the PNGs, so that regenerating unchanged figures changes no byte.
META = {"Software": None}

FACE_LABELS = {
    "dual_paraboloid": ["face 0: z >= 0", "face 1: z < 0"],
    "cube": ["+X", "-X", "+Y", "-Y", "+Z", "-Z"],
}


def colours(d: np.ndarray) -> np.ndarray:
    """RGB = (d + 1) / 2 for directions; a grey ramp for the scalars of the line mapper."""
    if d.ndim == 2:  # line: (1, S) scalars
        return np.repeat(d[..., None], 3, axis=-1)
    return np.clip((d + 1.0) / 2.0, 0.0, 1.0)


def mapper_figure(name: str) -> Path:
    m = mappers.get(name)
    S = SIZES.get(name, globals()["S"])
    H, W = mappers.texture_shape(m, S)
    d = np.asarray(mappers.texel_directions(m, S), np.float64)
    valid = np.asarray(mappers.valid_mask(m, S))
    inside = np.asarray(mappers.inside_mask(m, S))
    rgb = colours(d)
    rgb[~valid] = 0.55
    scale = 0.36 if W <= 24 else 0.3
    fig, ax = plt.subplots(figsize=(max(3.2, W * scale) + 0.8, H * scale + 1.5 if H > 1 else 2.0), dpi=110)
    ax.imshow(rgb, interpolation="nearest", extent=(0, W, H, 0))
    for r in range(H):
        for c in range(W):
            if not valid[r, c]:
                ax.plot([c + 0.2, c + 0.8], [r + 0.2, r + 0.8], color="0.3", lw=0.8)
                ax.plot([c + 0.2, c + 0.8], [r + 0.8, r + 0.2], color="0.3", lw=0.8)
            elif not inside[r, c]:
                ax.add_patch(patches.Rectangle((c, r), 1, 1, fill=False, hatch="////", edgecolor="white", lw=0))
    for x in range(W + 1):
        ax.axvline(x, color="white", lw=0.4)
    for y in range(H + 1):
        ax.axhline(y, color="white", lw=0.4)
    for f in range(1, m.faces):
        ax.axvline(f * S, color="black", lw=2.0)
    if not m.covers_sphere and not m.scalar or name in ("dual_paraboloid", "spherical"):
        for f in range(m.faces):  # the unit disk of each face: the mapped domain
            ax.add_patch(patches.Circle((f * S + S / 2, S / 2), S / 2, fill=False, color="black", lw=1.2))
    for f, label in enumerate(FACE_LABELS.get(name, [])):
        ax.text(f * S + S / 2, -0.25, label, ha="center", va="bottom", fontsize=8)
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)
    step = 1 if W <= 24 else 2
    ax.set_xticks(np.arange(0, W, step) + 0.5, [str(c) for c in range(0, W, step)], fontsize=6)
    ax.set_yticks(np.arange(H) + 0.5, [str(r) for r in range(H)], fontsize=6)
    ax.set_xlabel("column (u increases to the right)", fontsize=8)
    ax.set_ylabel("row (v increases downwards)" if H > 1 else "row", fontsize=8)
    what = "grey = x" if m.scalar else "RGB = (d + 1) / 2"
    ax.set_title(f"{name}, S = {S}: texture {H} x {W}; {what}", fontsize=9, pad=20 if name in FACE_LABELS else 6)
    fig.tight_layout()
    path = OUT / f"mapper_{name}.png"
    fig.savefig(path, metadata=META)
    plt.close(fig)
    return path


def latlong_figure() -> Path:
    from homofac.light.latlong import latlong_directions  # noqa: PLC0415 - the light layer, only for this figure

    h, w = 8, 16
    d = latlong_directions(h, w)
    fig, ax = plt.subplots(figsize=(7.4, 4.2), dpi=110)
    ax.imshow(colours(d), interpolation="nearest", extent=(0, w, h, 0))
    for x in range(w + 1):
        ax.axvline(x, color="white", lw=0.4)
    for y in range(h + 1):
        ax.axhline(y, color="white", lw=0.4)
    for frac, label in ((0.0, "+x"), (0.25, "+y"), (0.5, "-x"), (0.75, "-y"), (1.0, "+x")):
        ax.annotate(label, (frac * w, h), (frac * w, h + 0.9), ha="center", fontsize=9,
                    arrowprops={"arrowstyle": "-", "lw": 0.6})
    ax.text(w + 0.3, 0.0, "theta = 0: +z (row 0 is up)", va="center", fontsize=8)
    ax.text(w + 0.3, h / 2, "theta = pi/2: horizon", va="center", fontsize=8)
    ax.text(w + 0.3, h, "theta = pi: -z", va="center", fontsize=8)
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_xticks(np.arange(w) + 0.5, [str(c) for c in range(w)], fontsize=6)
    ax.set_yticks(np.arange(h) + 0.5, [str(r) for r in range(h)], fontsize=6)
    ax.set_xlabel("column c: phi = 2 pi (c + 0.5) / W, from +x towards +y", fontsize=8, labelpad=18)
    ax.set_ylabel("row r: theta = pi (r + 0.5) / H", fontsize=8)
    ax.set_title(f"lat-long map {w} x {h} (W = 2H); RGB = (d + 1) / 2", fontsize=9)
    fig.tight_layout()
    path = OUT / "latlong.png"
    fig.savefig(path, metadata=META)
    plt.close(fig)
    return path


def _footprint(ax, name: str, direction, title: str, S: int = 12) -> None:
    """A mapper's texture with the bilinear footprint of one direction and its weights (mappers.bilinear)."""
    m = mappers.get(name)
    H, W = mappers.texture_shape(m, S)
    valid = np.asarray(mappers.valid_mask(m, S))
    inside = np.asarray(mappers.inside_mask(m, S))
    shade = np.where(valid, np.where(inside, 0.93, 0.8), 0.55)
    ax.imshow(shade, cmap="gray", vmin=0, vmax=1, interpolation="nearest", extent=(0, W, H, 0))
    for x in range(W + 1):
        ax.axvline(x, color="white", lw=0.4)
    for y in range(H + 1):
        ax.axhline(y, color="white", lw=0.4)
    for f in range(1, m.faces):
        ax.axvline(f * S, color="black", lw=2.0)
    for f in range(m.faces):
        ax.add_patch(patches.Circle((f * S + S / 2, S / 2), S / 2, fill=False, color="black", lw=1.0))
    d = sphere.normalize(np.asarray(direction, np.float64))[None]
    face, _, _ = mappers.face_uv(m, d)
    row, col = (float(x[0]) for x in mappers.continuous_coords(m, d, S))
    _, w = mappers.bilinear(m, d, S)
    # the pinned footprint: clamp to the face, corners (U, V), (U+1, V), (U, V+1), (U+1, V+1)
    f0 = int(face[0]) * S
    cu, cv = min(max(col - f0, 0.0), S - 1.0), min(max(row, 0.0), H - 1.0)
    j0, i0 = min(int(np.floor(cu)), S - 2), min(int(np.floor(cv)), H - 2)
    corners = [(i0, j0), (i0, j0 + 1), (i0 + 1, j0), (i0 + 1, j0 + 1)]
    ax.plot(col + 0.5, row + 0.5, "o", color="crimson", ms=6, zorder=5, clip_on=False)
    ax.plot(f0 + cu + 0.5, cv + 0.5, "+", color="crimson", ms=10, mew=1.5, zorder=5)
    for k, (i, j) in enumerate(corners):
        ax.add_patch(patches.Rectangle((f0 + j, i), 1, 1, fill=False, edgecolor="crimson", lw=1.6, zorder=4))
        label = f"{w[0, k]:.2f}" + ("" if valid[i, f0 + j] else "\nno data")
        ax.text(f0 + j + 0.5, i + 0.5, label, ha="center", va="center", fontsize=6.5, color="crimson", zorder=6)
    ax.set_xlim(0, W)
    ax.set_ylim(H, 0)
    ax.set_xticks(np.arange(W) + 0.5, [str(c) for c in range(W)], fontsize=6)
    ax.set_yticks(np.arange(H) + 0.5, [str(r) for r in range(H)], fontsize=6)
    ax.set_title(title, fontsize=8)


def bilinear_figure() -> Path:
    fig, axes = plt.subplots(1, 2, figsize=(11.5, 4.6), dpi=110, gridspec_kw={"width_ratios": [2, 1]})
    _footprint(axes[0], "dual_paraboloid", [0.995, 0.05, 0.02],
               "dual_paraboloid, near the rim of face 0: the footprint is clamped to face 0")
    _footprint(axes[1], "parabolic", [0.695, 0.695, -0.182],
               "parabolic, below the horizon: the no-data corner gets 0")
    fig.text(0.01, 0.01, "dot: continuous coordinate (c = u S - 0.5); +: clamped to the face; "
             "light grey: texel centre in the domain, mid grey: texel holds data (valid), dark grey: no data",
             fontsize=7)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    path = OUT / "bilinear.png"
    fig.savefig(path, metadata=META)
    plt.close(fig)
    return path


def tangent_figure() -> Path:
    h, w = 90, 180
    th = np.pi * (np.arange(h) + 0.5) / h
    ph = 2 * np.pi * (np.arange(w) + 0.5) / w
    n = sphere.from_spherical(th[:, None] + 0 * ph[None], ph[None] + 0 * th[:, None])
    length = np.linalg.norm(np.array([1.0, 0, 0]) - n[..., 0:1] * n, axis=-1)
    fig, ax = plt.subplots(figsize=(7.4, 3.6), dpi=110)
    im = ax.imshow(length, cmap="viridis", extent=(0, 360, 180, 0), aspect="auto")
    ax.contour(np.degrees(ph), np.degrees(th), length, levels=[0.05, 0.2, 0.5], colors="white", linewidths=0.6)
    for phi, label in ((0, "n = +x"), (180, "n = -x"), (360, "n = +x")):
        ax.plot(phi, 90, "x", color="crimson", ms=9, mew=2, clip_on=False)
        ax.text(min(max(phi, 14), 346), 48, label, color="white", fontsize=8, ha="center")
    ax.set_xlabel("phi of n (degrees, from +x towards +y)", fontsize=8)
    ax.set_ylabel("theta of n (degrees from +z)", fontsize=8)
    ax.set_title("|x - (x.n) n|: t(n) = (x - (x.n) n) / |x - (x.n) n| is singular where it vanishes", fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.03)
    fig.tight_layout()
    path = OUT / "tangent.png"
    fig.savefig(path, metadata=META)
    plt.close(fig)
    return path


def figures() -> list[Path]:
    """Every figure the docs use, written into docs/img (paths returned)."""
    OUT.mkdir(exist_ok=True)
    out = [mapper_figure(name) for name in mappers.MAPPERS]
    out += [latlong_figure(), bilinear_figure(), tangent_figure()]
    return out


if __name__ == "__main__":
    for p in figures():
        print(p.relative_to(OUT.parent.parent))
