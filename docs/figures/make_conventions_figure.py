"""Draw docs/figures/conventions.png, the figure of docs/reference/conventions.md.

Run from anywhere:  python docs/figures/make_conventions_figure.py

Every labelled position is computed by the library itself (``look_at`` for the camera in panel a,
``directions_to_equirect`` / ``equirect_pixel_index`` for the directions in panel b), so the figure
cannot drift from the code.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO))

from rgbd_envmap.geometry import directions_to_equirect, equirect_pixel_index, look_at  # noqa: E402

OUT = HERE / "conventions.png"
RED, GREEN, BLUE, GREY = "#d62728", "#2ca02c", "#1f77b4", "#555555"


# --------------------------------------------------------------------------------------------- (a)
def _arrow3d(ax, origin, vec, colour, label, lw=2.5, offset=1.15, fontsize=13):
    ax.quiver(*origin, *vec, color=colour, linewidth=lw, arrow_length_ratio=0.12)
    tip = np.asarray(origin) + offset * np.asarray(vec)
    ax.text(*tip, label, color=colour, fontsize=fontsize, fontweight="bold", ha="center", va="center")


def panel_world(ax) -> None:
    # World frame at the origin.
    o = np.zeros(3)
    _arrow3d(ax, o, [1.3, 0, 0], RED, "$x_w$")
    _arrow3d(ax, o, [0, 1.3, 0], GREEN, "$y_w$")
    _arrow3d(ax, o, [0, 0, 1.3], BLUE, "$z_w$ (up)", offset=1.1)
    ax.text(0.0, 0.0, -0.22, "world origin", fontsize=10.5, color=GREY, ha="center")

    # A camera placed with the library's look_at: OpenCV axes, world up towards image top.
    eye = np.array([-1.2, -1.5, 1.2])
    target = np.array([-0.9, 0.8, 0.7])
    T = look_at(eye, target)
    R, t = T.rotation, T.translation
    _arrow3d(ax, t, 1.0 * R[:, 0], RED, "$x_c$ right", lw=2.4, offset=1.3, fontsize=12)
    _arrow3d(ax, t, 0.8 * R[:, 1], GREEN, "$y_c$ down", lw=2.4, offset=1.25, fontsize=12)
    _arrow3d(ax, t, 0.9 * R[:, 2], BLUE, "$z_c$ forward", lw=2.4, offset=1.4, fontsize=12)
    ax.text(*(t + [0.0, 0.0, 0.12]), "camera", fontsize=10.5, color=GREY, ha="right", va="bottom")

    # Frustum: image corners at z = 0.5 in the camera frame (OpenCV), mapped to the world.
    w, h, z = 0.3, 0.22, 0.45
    corners = T.apply(np.array([[-w, -h, z], [w, -h, z], [w, h, z], [-w, h, z]]))
    for c in corners:
        ax.plot(*np.stack([t, c]).T, color="#aaaaaa", lw=0.9)
    ax.plot(*np.vstack([corners, corners[:1]]).T, color="#777777", lw=1.1)
    # The image's top edge (v = 0, camera −y): world up ends up there.
    ax.plot(*corners[:2].T, color="k", lw=3.5)
    ax.text(*(corners[:2].mean(axis=0) + [0, 0, 0.13]), "image top (v = 0)", fontsize=10.5, ha="center")

    ax.set_xlim(-1.5, 1.3)
    ax.set_ylim(-1.9, 1.3)
    ax.set_zlim(-0.3, 1.5)
    ax.set_box_aspect((2.6, 3.0, 1.8), zoom=1.2)
    ax.view_init(elev=20, azim=-40)
    ax.set_xticks([]), ax.set_yticks([]), ax.set_zticks([])
    for a in (ax.xaxis, ax.yaxis, ax.zaxis):
        a.pane.fill = False
        a.pane.set_edgecolor("#dddddd")
        a.line.set_color((1, 1, 1, 0))
    ax.grid(False)
    ax.set_title("(a) World: right-handed, z up.   Camera: OpenCV (x right, y down, z forward)",
                 fontsize=13.5, y=1.0)
    ax.text2D(0.54, -0.01,
              "pose: T_world_from_cam (4×4 float64)\n"
              "p_world = T_world_from_cam @ p_cam\n"
              "camera drawn by geometry.look_at(eye, target)\n"
              "opengl_from_opencv(T): flips camera y and z",
              transform=ax.transAxes, fontsize=10.5, family="monospace", va="bottom",
              bbox=dict(boxstyle="round", fc="#f4f4f4", ec="#bbbbbb"))


# --------------------------------------------------------------------------------------------- (b)
def panel_equirect(ax, H: int = 8, W: int = 16) -> None:
    # Pixel grid: pixel (v, u) covers [u − .5, u + .5] × [v − .5, v + .5]; dots at the centres.
    for u in np.arange(W + 1) - 0.5:
        ax.plot([u, u], [-0.5, H - 0.5], color="#cccccc", lw=0.8, zorder=1)
    for v in np.arange(H + 1) - 0.5:
        ax.plot([-0.5, W - 0.5], [v, v], color="#cccccc", lw=0.8, zorder=1)
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    ax.scatter(uu.ravel(), vv.ravel(), s=10, color="k", zorder=3)

    # Labelled directions, placed by the library.
    named = [
        ("−y", "φ = −π/2", [0.0, -1.0, 0.0], "#8c564b"),
        ("+x", "φ = 0", [1.0, 0.0, 0.0], RED),
        ("+y", "φ = π/2", [0.0, 1.0, 0.0], GREEN),
        ("−x", "φ = ±π", [-1.0, 0.0, 0.0], "#9467bd"),
    ]
    dirs = np.array([d for _, _, d, _ in named])
    uv = directions_to_equirect(dirs, H, W)
    _, cols, _ = equirect_pixel_index(dirs, H, W)
    label_v = H + 0.45
    for (name, phi, _, colour), (u, _), col in zip(named, uv, cols):
        seam = u < 0
        us = [u, u + W] if seam else [u]  # the seam lies on both outer edges
        for ui in us:
            ax.plot([ui, ui], [-0.5, H - 0.5], color=colour, lw=2.6, zorder=2, ls="--" if seam else "-")
            ax.plot([ui, ui], [H - 0.5, label_v], color=colour, lw=1.2)
            ax.plot([ui, ui], [-0.5, -1.0], color=colour, lw=1.2)
            ax.text(ui, -1.05, f"{name}: {phi}", ha="center", va="bottom", fontsize=11.5, color=colour,
                    fontweight="bold")
        if seam:
            texts = [(u, f"u = {u:g}\n→ col {col}"), (u + W, f"u = W − 0.5 ≡ {u:g}\n→ col {col}")]
        else:
            texts = [(u, f"u = {u:g}\n→ col {col}")]
        for ui, text in texts:
            ax.text(ui, label_v, text, fontsize=10.5, color=colour, fontweight="bold", ha="center", va="top",
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec=colour))
    ax.text(W + 2.6, label_v - 0.05, "dashed: the seam at φ = ±π (−x); u wraps mod W.",
            fontsize=10.5, color="#9467bd", va="top")
    ax.text(W + 2.6, label_v + 0.4, "The axes lie on pixel edges; ties go to the higher index.",
            fontsize=10.5, color=GREY, va="top")

    # Poles and horizon, placed by the library.
    pv = directions_to_equirect(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), H, W)[:, 1]
    zen_v, nad_v, hor_v = pv
    rows, _, _ = equirect_pixel_index(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]), H, W)
    for v in (zen_v, nad_v):
        ax.plot([-0.5, W - 0.5], [v, v], color=BLUE, lw=3.2, zorder=2)
    ax.plot([-0.5, W - 0.5], [hor_v, hor_v], color=GREY, lw=1.6, ls=":", zorder=2)
    x_txt = W + 0.1
    ax.text(x_txt, zen_v, f"zenith +z (θ = 0): v = {zen_v:g} → row {rows[0]}", va="center", fontsize=11,
            color=BLUE, fontweight="bold")
    ax.text(x_txt, nad_v, f"nadir −z (θ = π): v = {nad_v:g} → row {rows[1]} (clamped)", va="center", fontsize=11,
            color=BLUE, fontweight="bold")
    ax.text(x_txt, hor_v, f"horizon (θ = π/2): v = {hor_v:g}", va="center", fontsize=11, color=GREY)
    ax.add_patch(Rectangle((-0.5, -0.5), W, 1, fc=BLUE, alpha=0.08, zorder=0))
    ax.add_patch(Rectangle((-0.5, H - 1.5), W, 1, fc=BLUE, alpha=0.08, zorder=0))

    box = dict(fontsize=11, family="monospace", va="top", bbox=dict(boxstyle="round", fc="#f4f4f4", ec="#bbbbbb"))
    ax.text(x_txt, 0.4,
            "θ = π (v + 0.5) / H      polar, from +z\n"
            "φ = 2π (u + 0.5) / W − π from +x towards +y\n"
            "d = (sin θ cos φ, sin θ sin φ, cos θ)", **box)
    ax.text(x_txt, 4.3,
            "u ∈ [−0.5, W − 0.5),  v ∈ [−0.5, H − 0.5]\n"
            "col = floor(u + 0.5) mod W\n"
            "row = clamp(floor(v + 0.5), 0, H − 1)\n"
            "Ω_pixel = (2π/W)(cos θ_top − cos θ_bottom)\n"
            "Σ Ω_pixel = 4π", **box)

    ax.set_xlim(-1.0, W + 14.5)
    ax.set_ylim(H + 1.75, -1.9)
    ax.set_aspect("equal")
    ax.set_yticks(range(H))
    ax.set_xticks([])
    ax.tick_params(labelsize=10, length=0)
    for u in range(W):
        ax.text(u, -0.62, str(u), ha="center", va="bottom", fontsize=8.5, color=GREY)
    ax.text(-0.75, -0.62, "u", fontsize=10, color=GREY, ha="right", va="bottom")
    ax.set_ylabel("row v  (0 = zenith)", fontsize=11)
    for s in ax.spines.values():
        s.set_visible(False)
    ax.set_title(f"(b) Equirectangular map (H×W = {H}×{W}, W = 2H): dots = pixel centres at integer (u, v); "
                 "row 0 = zenith", fontsize=13.5, loc="left", pad=0)


# --------------------------------------------------------------------------------------------- (c)
def panel_image(ax, H: int = 4, W: int = 6) -> None:
    for u in np.arange(W + 1) - 0.5:
        ax.plot([u, u], [-0.5, H - 0.5], color="#999999", lw=1)
    for v in np.arange(H + 1) - 0.5:
        ax.plot([-0.5, W - 0.5], [v, v], color="#999999", lw=1)
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    ax.scatter(uu.ravel(), vv.ravel(), s=24, color="k", zorder=3)
    for u in range(W):
        ax.text(u, -0.6, str(u), ha="center", va="bottom", fontsize=10, color=GREY)
    for v in range(H):
        ax.text(-0.6, v, str(v), ha="right", va="center", fontsize=10, color=GREY)

    # One highlighted pixel.
    pu, pv = 4, 2
    ax.add_patch(Rectangle((pu - 0.5, pv - 0.5), 1, 1, fc="#ffdd77", ec="#c08000", lw=2, zorder=0))
    ax.annotate(f"pixel (u = {pu}, v = {pv}) = img[{pv}, {pu}]\n"
                f"covers [{pu - 0.5}, {pu + 0.5}] × [{pv - 0.5}, {pv + 0.5}]",
                xy=(pu + 0.3, pv), xytext=(W + 0.1, 1.0), fontsize=11, ha="left", va="center",
                arrowprops=dict(arrowstyle="->", color="#c08000", lw=1.5))
    # Axes from the origin (the centre of pixel (0, 0)).
    ax.annotate("", xy=(1.8, 0), xytext=(0, 0), arrowprops=dict(arrowstyle="-|>", color=RED, lw=2.8), zorder=4)
    ax.annotate("", xy=(0, 1.8), xytext=(0, 0), arrowprops=dict(arrowstyle="-|>", color=GREEN, lw=2.8), zorder=4)
    ax.text((W - 1) / 2, -1.0, "u (column, x) right →", color=RED, fontsize=12, fontweight="bold",
            ha="center", va="bottom")
    ax.text(-0.5, H - 0.3, "↓ v (row, y) down", color=GREEN, fontsize=12, fontweight="bold",
            ha="left", va="top")
    ax.text(W + 0.1, 0.0 - 0.25, "(u, v) = (0, 0): centre of the top-left pixel", fontsize=11, va="center")
    ax.text(W + 0.1, 2.4,
            "image spans [−0.5, W − 0.5] × [−0.5, H − 0.5]\n"
            "pixel index = floor(u + 0.5), floor(v + 0.5)\n"
            "u = fx·x'/z + cx,  v = fy·y'/z + cy\n"
            "(x', y' after Brown distortion)\n"
            "arrays channels-last: img[v, u, c]",
            fontsize=11, va="top", family="monospace",
            bbox=dict(boxstyle="round", fc="#f4f4f4", ec="#bbbbbb"))
    ax.set_xlim(-1.1, W + 8.7)
    ax.set_ylim(H + 0.5, -1.5)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("(c) Camera image (OpenCV): pixel centres at integer (u, v)", fontsize=13.5, loc="left")


def main() -> None:
    fig = plt.figure(figsize=(16, 10), dpi=100, facecolor="white")
    ax_a = fig.add_axes([0.0, 0.545, 0.48, 0.44], projection="3d")
    ax_c = fig.add_axes([0.49, 0.56, 0.51, 0.40])
    ax_b = fig.add_axes([0.02, 0.0, 0.97, 0.5])
    panel_world(ax_a)
    panel_image(ax_c)
    panel_equirect(ax_b)
    fig.savefig(OUT, dpi=100, facecolor="white")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
