"""Public RGB-D datasets written by hand, file by file, as their documentation describes them, from
views of a simple room ray-cast by the simulator (not with the project's own writer).

- **TUM RGB-D** ("File Formats" page of the benchmark): ``rgb.txt`` / ``depth.txt`` with three ``#``
  header lines, then ``timestamp filename`` (seconds, 6 decimals); ``groundtruth.txt``
  ``timestamp tx ty tz qx qy qz qw`` (4 decimals, 100 Hz, the colour camera's optical centre in the
  world); 640×480 8-bit RGB PNGs; 640×480 16-bit depth PNGs, 5000 units per metre, 0 = no data;
  depth, colour and poses at their own, unsynchronised times. No calibration.json.
- **ICL-NUIM**, TUM-compatible: ``rgb/N.png``, ``depth/N.png`` (5000 per metre), ``associations.txt``
  with ``t_depth depth/N.png t_rgb rgb/N.png`` (frame numbers as timestamps) and one
  ``<name>.gt.freiburg`` trajectory; camera fx = 481.20, fy = −480.00, cx = 319.5, cy = 239.5: the
  pixel (u, v) sees the camera-frame ray ((u − cx) / fx, (v − cy) / fy, 1), so with fy < 0 the
  image's rows run against the frame's +y.

Rays are built here from the intrinsics directly (OpenCV's ``undistortPoints``, iterated to convergence, for the TUM
cameras' distortion), the z-depth is the hit distance divided by the ray's length at z = 1, and the
linear radiance is encoded to sRGB with the IEC 61966-2-1 formula.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from sim.raycast import SceneRaycaster
from sim.scene import scene_from_dict

W, H = 640, 480
#: the map origin the room is built around (world metres, z up)
ORIGIN = np.array([0.0, 0.0, 1.0])


def room_scene():
    """A 5 m × 4 m × 2.7 m room with walls of different colours, two checkered walls, a box and a
    pillar, so that the colour fit has pairs and the depth has edges."""
    hx, hy, hz = 2.5, 2.0, 2.7
    walls = [
        ("floor", [-hx, -hy, 0], [2 * hx, 0, 0], [0, 2 * hy, 0], {"texture": "checker", "colours": [[0.35, 0.3, 0.25], [0.2, 0.18, 0.15]], "cells": [10, 8]}),
        ("ceiling", [-hx, -hy, hz], [2 * hx, 0, 0], [0, 2 * hy, 0], [0.7, 0.7, 0.68]),
        ("north", [-hx, hy, 0], [2 * hx, 0, 0], [0, 0, hz], {"texture": "checker", "colours": [[0.6, 0.2, 0.15], [0.15, 0.2, 0.6]], "cells": [8, 4]}),
        ("south", [-hx, -hy, 0], [2 * hx, 0, 0], [0, 0, hz], [0.2, 0.5, 0.25]),
        ("east", [hx, -hy, 0], [0, 2 * hy, 0], [0, 0, hz], {"texture": "checker", "colours": [[0.55, 0.5, 0.1], [0.1, 0.4, 0.45]], "cells": [6, 4]}),
        ("west", [-hx, -hy, 0], [0, 2 * hy, 0], [0, 0, hz], [0.45, 0.3, 0.5]),
    ]
    objects = [{"name": n, "shape": "quad", "corner": c, "u": u, "v": v, "radiance": r} for n, c, u, v, r in walls]
    objects += [
        {"name": "crate", "shape": "box", "centre": [1.2, 0.8, 0.4], "size": [0.8, 0.6, 0.8], "radiance": [0.8, 0.55, 0.3]},
        {"name": "pillar", "shape": "box", "centre": [-1.3, -1.0, 1.35], "size": [0.3, 0.3, 2.7], "radiance": [0.9, 0.9, 0.9]},
    ]
    return scene_from_dict({"name": "hand_room", "virtual_object_position": ORIGIN.tolist(), "objects": objects})


def pose_at(t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of T_world_from_cam (OpenCV axes: x right, y down, z forward) of a camera 30 cm behind
    the origin turning about the vertical at 1 rad/s, tilted 10° down."""
    yaw = 0.3 + 1.0 * t_s
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    r = Rotation.from_rotvec(np.cross(forward, [0, 0, 1]) * np.radians(-10)).as_matrix()
    forward = r @ forward
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward], axis=1)
    t = ORIGIN + np.array([0.0, 0.0, 0.2]) - 0.3 * forward
    return R, t


_RAYS: dict = {}


def camera_rays(K: np.ndarray, dist: np.ndarray | None, width: int = W, height: int = H) -> np.ndarray:
    """(H·W, 3) camera-frame rays (x, y, 1) through the pixel centres, row by row (cached)."""
    key = (np.asarray(K, np.float64).tobytes(), None if dist is None else np.asarray(dist, np.float64).tobytes(), width, height)
    if key not in _RAYS:
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        if dist is not None and np.any(dist):
            pts = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
            xy = cv2.undistortPoints(pts, K, np.asarray(dist, np.float64), criteria=crit).reshape(-1, 2)
        else:
            xy = np.stack([(u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1]], axis=-1)
        _RAYS[key] = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    return _RAYS[key]


def render(rc: SceneRaycaster, K: np.ndarray, dist: np.ndarray | None, R: np.ndarray, t: np.ndarray,
           width: int = W, height: int = H) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) uint8 sRGB colour and (H, W) float64 z-depth (0: no surface) of the camera (R, t)."""
    rays = camera_rays(K, dist, width, height)
    length = np.linalg.norm(rays, axis=1)
    dirs = (rays / length[:, None]) @ R.T
    hits = rc.cast(t, dirs, 0.0, normals=False)
    z = np.where(hits.hit, hits.distance_m / length, 0.0).reshape(height, width)
    lin = np.clip(hits.radiance.reshape(height, width, 3).astype(np.float64), 0.0, 1.0)
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    return np.round(srgb * 255).astype(np.uint8), z


def depth_png(z: np.ndarray, rng: np.random.Generator, units_per_m: float = 5000.0, dropout: float = 0.02) -> np.ndarray:
    """16-bit depth: round(z · units), 0 where no surface, out of [0.4, 8] m, or dropped at random."""
    ok = (z >= 0.4) & (z <= 8.0) & (rng.random(z.shape) >= dropout)
    return np.where(ok, np.round(z * units_per_m), 0).astype(np.uint16)


def write_png(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", img)
    assert ok
    path.write_bytes(buf.tobytes())


def quaternion_xyzw(R: np.ndarray) -> np.ndarray:
    q = Rotation.from_matrix(R).as_quat()
    return -q if q[3] < 0 else q


def write_tum_published(root: Path, K: np.ndarray, dist: np.ndarray | None, n_frames: int = 24, seed: int = 0) -> dict:
    """A sequence in the benchmark's published layout (module docstring); returns what was written."""
    rng = np.random.default_rng(seed)
    rc = SceneRaycaster(room_scene())
    root.mkdir(parents=True)
    t0 = 1305031102.0
    bag = f"# file: '{root.name}.bag'"
    rgb_lines = ["# color images", bag, "# timestamp filename"]
    depth_lines = ["# depth maps", bag, "# timestamp filename"]
    for k in range(n_frames):
        # 30 Hz with jitter; colour 9-14 ms after depth, as the Kinect's streams drift
        td = round(k / 30.0 + 0.005 + rng.uniform(-0.002, 0.002), 6)
        tc = round(td + rng.uniform(0.009, 0.014), 6)
        R, t = pose_at(td)
        _, z = render(rc, K, dist, R, t)
        R, t = pose_at(tc)
        rgb, _ = render(rc, K, dist, R, t)
        d_name, c_name = f"{t0 + td:.6f}", f"{t0 + tc:.6f}"
        write_png(root / "depth" / f"{d_name}.png", depth_png(z, rng))
        write_png(root / "rgb" / f"{c_name}.png", rgb)
        depth_lines.append(f"{d_name} depth/{d_name}.png")
        rgb_lines.append(f"{c_name} rgb/{c_name}.png")
    gt_lines = ["# ground truth trajectory", bag, "# timestamp tx ty tz qx qy qz qw"]
    for j in range(int(n_frames / 30.0 * 100) + 3):  # 100 Hz motion capture, 4 decimals
        ts = j / 100.0
        R, t = pose_at(ts)
        gt_lines.append(f"{t0 + ts:.4f} " + " ".join(f"{x:.4f}" for x in (*t, *quaternion_xyzw(R))))
    for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines), ("groundtruth.txt", gt_lines)):
        (root / name).write_text("\n".join(lines) + "\n")
    return {"root": root, "raycaster": rc, "gt_lines": gt_lines}


ICL_K = np.array([[481.20, 0.0, 319.5], [0.0, -480.00, 239.5], [0.0, 0.0, 1.0]])


def write_icl_nuim(root: Path, n_frames: int = 12, seed: int = 0, *, flip: bool = False) -> dict:
    """An ICL-NUIM sequence in its TUM-compatible layout (module docstring). ``flip``: the same frames
    with the images upside down, for the camera fy = +480, cy = 479 − 239.5 (the same poses: the
    pixel (u, H − 1 − v) of the flipped image sees what pixel (u, v) of the original sees)."""
    rng = np.random.default_rng(seed)
    rc = SceneRaycaster(room_scene())
    root.mkdir(parents=True)
    assoc, gt = [], []
    for k in range(n_frames):
        R, t = pose_at(k / 10.0)  # ICL's frames are 1/30 s apart; a faster turn keeps the test short
        rgb, z = render(rc, ICL_K, None, R, t)
        depth = depth_png(z, rng, dropout=0.0)
        if flip:
            rgb, depth = rgb[::-1].copy(), depth[::-1].copy()
        write_png(root / "depth" / f"{k}.png", depth)
        write_png(root / "rgb" / f"{k}.png", rgb)
        assoc.append(f"{k} depth/{k}.png {k} rgb/{k}.png")
        gt.append(f"{k} " + " ".join(f"{x:.17g}" for x in (*t, *quaternion_xyzw(R))))
    (root / "associations.txt").write_text("\n".join(assoc) + "\n")
    (root / "livingRoom0.gt.freiburg").write_text("\n".join(gt) + "\n")
    return {"root": root, "raycaster": rc}


# --- Redwood (Open3D's layout: colors/ JPEG, depth/ 16-bit PNG in mm, camera_intrinsic.json, .log) ------


def log_block(frame: int, R: np.ndarray, t: np.ndarray) -> str:
    """One frame of a ``.log`` trajectory as the Redwood data writes it: "frame frame frame+1" and the
    4×4 camera-to-world matrix, one row a line."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R, t
    return f"{frame} {frame} {frame + 1}\n" + "\n".join(" ".join(f"{x:.8f}" for x in row) for row in m) + "\n"


def write_redwood(root: Path, n_frames: int = 12, seed: int = 0, *, K: np.ndarray | None = None, intrinsic_json: bool = True,
                  trajectory: str | None = "room-traj.txt", jpeg_quality: int = 95) -> dict:
    """A Redwood / Augmented ICL-NUIM folder written by hand: ``colors/NNNNN.jpg`` (8-bit JPEG),
    ``depth/NNNNN.png`` (16-bit, millimetres), Open3D's ``camera_intrinsic.json`` (width, height,
    ``intrinsic_matrix`` column-major) unless ``intrinsic_json`` is False (then the PrimeSense default
    applies and ``K`` must be it), and the ``.log`` trajectory (``trajectory``: its file name; None:
    no trajectory). Frames are 1/30 s apart on :func:`pose_at`'s turn."""
    rng = np.random.default_rng(seed)
    rc = SceneRaycaster(room_scene())
    K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]]) if K is None else K
    root.mkdir(parents=True)
    blocks = []
    for k in range(n_frames):
        R, t = pose_at(k / 30.0 * 3.0)  # three times the turn of the TUM writer: more of the room in few frames
        rgb, z = render(rc, K, None, R, t)
        write_png(root / "depth" / f"{k:05d}.png", depth_png(z, rng, units_per_m=1000.0, dropout=0.0))
        (root / "colors").mkdir(exist_ok=True)
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        assert ok
        (root / "colors" / f"{k:05d}.jpg").write_bytes(buf.tobytes())
        blocks.append(log_block(k, R, t))
    if intrinsic_json:
        m = [K[0, 0], 0.0, 0.0, 0.0, K[1, 1], 0.0, K[0, 2], K[1, 2], 1.0]  # column-major, as Open3D writes it
        (root / "camera_intrinsic.json").write_text(
            '{\n\t"height" : %d,\n\t"intrinsic_matrix" : [ %s ],\n\t"width" : %d\n}\n' % (H, ", ".join(f"{x:g}" for x in m), W))
    if trajectory is not None:
        (root / trajectory).write_text("".join(blocks))
    return {"root": root, "raycaster": rc, "blocks": blocks, "K": K}
