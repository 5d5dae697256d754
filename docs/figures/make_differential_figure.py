"""The differential-rendering figure (docs/design/differential.md): one reference frame of a run, as the
path-traced reference, the paper-003 composite and the differential composite, with the reference's
own shadow (its luminance with / without the object) and each composite's relative error.

Takes two run folders of the same session, one per composite mode (each holds ``reference/<ts>.npz``
with the reference pair, the run's composite in the same linear space, and the compared regions):

    OUT=runs/diff bash scripts/main.sh
    OUT=runs/p3 bash scripts/main.sh --set render.composite=paper003
    python docs/figures/make_differential_figure.py runs/diff runs/p3 [--frame TS] [--out PNG]

The frame defaults to the reference frame with the most object pixels. Panels are cropped to the
object's box grown by its size on every side and shown as the camera would have seen them
(radiance × the frame's true gains, clipped, sRGB).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

Y = np.array([0.2126, 0.7152, 0.0722])


def _srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _load(run: Path, frame: str | None) -> tuple[str, dict]:
    paths = sorted((run / "reference").glob("*.npz"))
    if not paths:
        raise SystemExit(f"{run}: no reference/*.npz (run the main job with reference frames)")
    if frame is None:
        frame = max(paths, key=lambda p: int(np.load(p)["object_mask"].sum())).stem
    z = np.load(run / "reference" / f"{frame}.npz")
    return frame, {k: z[k] for k in z.files}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("differential", type=Path, help="run folder of the differential composite")
    ap.add_argument("paper003", type=Path, help="run folder of the paper-003 composite, same session")
    ap.add_argument("--frame", default=None, help="reference timestamp (ns); default: most object pixels")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "differential_composite.png")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frame, d = _load(args.differential, args.frame)
    _, p = _load(args.paper003, frame)
    ref, without = d["with_object"].astype(np.float64), d["without_object"].astype(np.float64)
    if not np.allclose(ref, p["with_object"].astype(np.float64)):
        raise SystemExit("the two runs' reference frames differ: run both on the same session")
    region = (d["object_mask"] | d["shadow_mask"]) & d["valid"]
    rows, cols = np.nonzero(d["object_mask"])  # the object's box, grown by its size on every side
    h, w = rows.max() - rows.min() + 1, cols.max() - cols.min() + 1
    r0, r1 = max(rows.min() - h, 0), min(rows.max() + h, region.shape[0])
    c0, c1 = max(cols.min() - int(1.5 * w), 0), min(cols.max() + int(1.5 * w), region.shape[1])
    crop = (slice(r0, r1), slice(c0, c1))
    gains = d["gains"]

    def view(x):
        return _srgb(x[crop] * gains)

    def rel_error(ours):
        e = np.linalg.norm(ours - ref, axis=-1) / np.maximum(np.linalg.norm(ref, axis=-1), 1e-6)
        return np.where(region, e, np.nan)[crop]

    def region_rmse(ours, m):
        m = m & d["valid"]
        return float(np.sqrt(np.sum((ours[m] - ref[m]) ** 2) / np.sum(ref[m] ** 2)))

    ours_d, ours_p = d["ours"].astype(np.float64), p["ours"].astype(np.float64)
    ratio = np.where(d["shadow_mask"], (ref @ Y) / np.maximum(without @ Y, 1e-6), np.nan)[crop]
    fig, ax = plt.subplots(2, 3, figsize=(12, 6.4))
    titles = ["path-traced reference", "paper-003 composite", "differential composite (default)"]
    for a, img, t in zip(ax[0], (ref, ours_p, ours_d), titles):
        a.imshow(view(img))
        a.set_title(t, fontsize=10)
    im = ax[1, 0].imshow(ratio, cmap="gray", vmin=0.7, vmax=1.1)
    ax[1, 0].set_title("reference: luminance with / without the object\n(shadow region)", fontsize=9)
    fig.colorbar(im, ax=ax[1, 0], fraction=0.04)
    for a, ours, name in ((ax[1, 1], ours_p, "paper 003"), (ax[1, 2], ours_d, "differential")):
        im = a.imshow(rel_error(ours), cmap="inferno", vmin=0, vmax=0.5)
        a.set_title(f"{name}: |ours − ref| / |ref|\nrel. RMSE object {region_rmse(ours, d['object_mask']):.3f}, "
                    f"shadow {region_rmse(ours, d['shadow_mask']):.3f}", fontsize=9)
        fig.colorbar(im, ax=a, fraction=0.04)
    for a in ax.ravel():
        a.set_xticks([])
        a.set_yticks([])
    fig.suptitle(f"reference frame at {float(d['t_s']):.1f} s", fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(args.out)


if __name__ == "__main__":
    main()
