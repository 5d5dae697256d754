"""Draw docs/figures/export_conventions.png, the figure of docs/reference/export.md.

Run from anywhere:  python docs/figures/make_export_conventions_figure.py

Each panel is an equirect image in one tool's orientation, coloured by the world direction (ours: z
up) that its pixels hold: RGB = (1 + d) / 2, so +x is reddish, +y greenish, +z bluish. The images and
the axis labels come from the library itself: ``equirect_directions`` gives our map's directions and
``rgbd_envmap.envmap_io.to_convention`` turns that map into Blender's and Mitsuba's orientation; each
label sits at the pixel whose direction lies closest to the axis. So the figure cannot drift from the
code.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO))

from rgbd_envmap.envmap_io import to_convention  # noqa: E402
from rgbd_envmap.geometry import equirect_directions  # noqa: E402

OUT = HERE / "export_conventions.png"
H, W = 90, 180
AXES = {"+x": (1, 0, 0), "−x": (-1, 0, 0), "+y": (0, 1, 0), "−y": (0, -1, 0), "+z": (0, 0, 1), "−z": (0, 0, -1)}
PANELS = [
    ("ours", "ours (rgbd-envmap):  u = ½ + φ/2π,  v = θ/π   (φ = atan2(y, x) from +x towards +y, θ from +z)"),
    ("blender", "blender (World → Environment Texture, Cycles):  u = ½ − φ/2π,  rows as ours"),
    ("mitsuba", "mitsuba (envmap emitter, to_world = identity, +y up; our (x, y, z) → (x, z, −y)):  "
                "u = ¼ − φ/2π  (mod 1)"),
]


def main() -> None:
    dirs = equirect_directions(H, W).astype(np.float64)
    fig, axes = plt.subplots(len(PANELS), 1, figsize=(9.0, 13.2))
    for ax, (convention, title) in zip(axes, PANELS):
        d = to_convention(dirs, convention)  # what world direction each pixel of this image holds
        ax.imshow(0.5 + 0.5 * d / np.linalg.norm(d, axis=-1, keepdims=True), extent=(0, 1, 1, 0),
                  interpolation="nearest", aspect="auto")
        for name, axis in AXES.items():
            r, c = np.unravel_index(np.argmax(d @ np.asarray(axis, float)), (H, W))
            x, y = (c + 0.5) / W, (r + 0.5) / H
            if name in ("+z", "−z"):  # a whole row holds the pole: label it in the middle
                x, y = 0.5, (0.04 if name == "+z" else 0.96)
            elif c in (0, W - 1):  # the seam: both edges
                for xx in (0.012, 0.988):
                    ax.annotate(name, (xx, 0.5), ha="center", va="center", fontsize=11, fontweight="bold",
                                bbox=dict(boxstyle="round,pad=0.2", fc="white", alpha=0.85))
                continue
            else:  # the axis lies on the edge between two columns
                x = round(x * 4) / 4
            ax.annotate(name, (x, y), ha="center", va="center", fontsize=11, fontweight="bold",
                        bbox=dict(boxstyle="round,pad=0.2", fc="white", alpha=0.85))
        ax.set_xticks([0, 0.25, 0.5, 0.75, 1.0], ["0", "W/4", "W/2", "3W/4", "W"])
        ax.set_yticks([0, 0.5, 1.0], ["0 (top)", "H/2", "H"])
        ax.set_xlabel("column (the seam at 0 = W)")
        ax.set_title(title, fontsize=9.5, loc="left")
        ax.axhline(0.5, color="white", lw=0.6, alpha=0.6)
        for xv in (0.25, 0.5, 0.75):
            ax.axvline(xv, color="white", lw=0.6, alpha=0.6)
    fig.suptitle("Where the world's axes sit in each tool's equirect image (world z up; colour = (1 + d)/2)",
                 fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(OUT, dpi=110)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
