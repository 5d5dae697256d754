"""The captured ceiling lamp's radiance against the truth, and the map's accuracy figures, per run folder.

    python benchmarks/eval_hdr_lamp.py RUN [RUN ...]

For each run folder of ``simulate`` (the default office): the map pixels whose ray from the map's
origin meets the lamp quad of the scene (one pixel in from its outline, so no pixel mixes lamp and
ceiling), how many of them the final map holds, the median of their radiance per channel, the same
of the true map at the session's end (``session/groundtruth/envmap.npz``) and the scene's emission
times its timeline scale at that time; then ``irradiance_rel_error_vs_true`` and ``em_ws_psnr_db``
from ``accuracy.json``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from scipy.ndimage import binary_erosion

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from rgbd_envmap.geometry import equirect_directions  # noqa: E402
from sim.scene import load_scene  # noqa: E402


def lamp_mask(origin: np.ndarray, h: int, w: int, corner, u, v) -> np.ndarray:
    """(H, W) bool: pixels whose ray from ``origin`` meets the quad corner + a·u + b·v, 0 ≤ a, b ≤ 1
    (a quad in a plane of constant z), eroded by one pixel."""
    corner, u, v = (np.asarray(x, np.float64) for x in (corner, u, v))
    d = equirect_directions(h, w).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (corner[2] - origin[2]) / d[..., 2]
    p = origin + t[..., None] * d - corner
    a, b = p @ u / (u @ u), p @ v / (v @ v)
    hit = (t > 0) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    return binary_erosion(hit)


def main(runs: list[str]) -> None:
    scene = load_scene("office")
    lamp = next(s for s in scene.objects if s.name == "ceiling_lamp")
    corner, u, v = lamp.quad_frame
    print(f"{'run':28s} {'lamp px':>8s} {'held':>6s} {'map median RGB':>22s} {'true map':>20s} {'emission':>20s} "
          f"{'map/true':>8s} {'irr err':>8s} {'WS-PSNR':>8s}")
    for run in runs:
        run = Path(run)
        em = np.load(run / "envmap.npz")
        gt = np.load(run / "session/groundtruth/envmap.npz")
        h, w = em["valid"].shape
        mask = lamp_mask(em["origin"], h, w, corner, u, v)
        held = mask & em["valid"]
        got = np.median(em["radiance"][held], axis=0) if held.any() else np.full(3, np.nan)
        true = np.median(gt["radiance"][mask], axis=0)
        emission = lamp.emission * lamp.scale_at(float(gt["t_s"]))
        acc = json.loads((run / "accuracy.json").read_text())
        lum = np.array([0.2126, 0.7152, 0.0722])
        print(f"{run.name:28s} {int(mask.sum()):8d} {int(held.sum()):6d} {np.array2string(got, precision=2):>22s} "
              f"{np.array2string(true, precision=2):>20s} {np.array2string(emission, precision=2):>20s} "
              f"{(got @ lum) / (true @ lum):8.3f} {acc.get('irradiance_rel_error_vs_true', np.nan):8.4f} "
              f"{acc.get('em_ws_psnr_db', np.nan):8.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
