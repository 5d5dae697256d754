"""A phone capture in the Stray Scanner layout written by hand, from the format's description alone
(no code of the project's writer): a camera inside a cube room whose six walls have six colours, with
depth and colour ray-cast in closed form in ARKit's y-up world.

The layout, as the Stray Scanner docs describe it: ``rgb.mp4`` (H.264 or HEVC), ``depth/NNNNNN.png``
(uint16 millimetres, 256×192, the colour image's field of view), ``confidence/NNNNNN.png`` (uint8
0 / 1 / 2), ``camera_matrix.csv`` (3×3, comma-separated, at the video's resolution) and
``odometry.csv`` (``timestamp, frame, x, y, z, qx, qy, qz, qw``: ``T_arkit_from_cam`` with OpenCV camera
axes, ARKit's world +y up).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
from scipy.spatial.transform import Rotation

HALF = 2.0  # the room is the cube [−HALF, HALF]³ (the same cube in either world)
#: sRGB colour of each wall, by the ARKit axis its plane is normal to and the side.
WALLS = {
    ("x", +1): (200, 50, 50), ("x", -1): (50, 200, 50),
    ("y", +1): (220, 200, 60),  # ARKit +y: the ceiling
    ("y", -1): (50, 50, 200),  # the floor
    ("z", +1): (200, 60, 200), ("z", -1): (60, 200, 200),  # ARKit −z: ahead at the session start
}
#: the camera's position in ARKit's world (ours: (x, −z, y) = (0.1, −0.3, 0.2)).
POSITION_ARKIT = np.array([0.1, 0.2, 0.3])
#: forward direction of each frame's camera, in ARKit's world.
LOOKS = [(0, 0, -1), (-1, 0, 0), (0, 0, 1), (1, 0, 0), (0, 1, 0), (0, -1, 0)]
COLOUR_SIZE = (320, 240)
DEPTH_SIZE = (256, 192)
K = np.array([[260.0, 0.0, 161.25], [0.0, 260.0, 118.75], [0.0, 0.0, 1.0]])
#: odometry timestamps as ARKit prints them (seconds, more than 9 decimals).
TIMESTAMPS = [f"{1000.5 + i / 30:.12f}" for i in range(len(LOOKS))]


def rotation_arkit(forward) -> np.ndarray:
    """R of ``T_arkit_from_cam`` for an OpenCV camera (x right, y down, z forward) looking along ``forward``."""
    f = np.asarray(forward, float)
    f = f / np.linalg.norm(f)
    up = np.array([0.0, 1.0, 0.0]) if abs(f[1]) < 0.9 else np.array([0.0, 0.0, -1.0])
    x = np.cross(f, up)
    x /= np.linalg.norm(x)
    y = np.cross(f, x)
    return np.stack([x, y, f], axis=1)


def depth_intrinsics() -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of the depth image: the camera matrix scaled to 256×192 over the same field of
    view (pixel centres at integers: the image edges at −0.5 and W − 0.5 map onto each other)."""
    sx, sy = DEPTH_SIZE[0] / COLOUR_SIZE[0], DEPTH_SIZE[1] / COLOUR_SIZE[1]
    return K[0, 0] * sx, K[1, 1] * sy, (K[0, 2] + 0.5) * sx - 0.5, (K[1, 2] + 0.5) * sy - 0.5


def cast(R: np.ndarray, p: np.ndarray, fx, fy, cx, cy, w, h) -> tuple[np.ndarray, np.ndarray]:
    """(z-depth (h, w), colour (h, w, 3) uint8) of the cube room seen by the camera (R, p)."""
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=-1)  # z = 1
    d = rays @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d != 0, (HALF * np.sign(d) - p) / d, np.inf)
    axis = np.argmin(t, axis=-1)
    z = np.take_along_axis(t, axis[..., None], axis=-1)[..., 0]
    sign = np.sign(np.take_along_axis(d, axis[..., None], axis=-1)[..., 0]).astype(int)
    colour = np.zeros((h, w, 3), np.uint8)
    for (name, s), rgb in WALLS.items():
        colour[(axis == "xyz".index(name)) & (sign == s)] = rgb
    return z, colour


#: how ``rgb.mp4`` is encoded: ``"h264"`` (lossless, ffmpeg's default RGB → YUV, untagged) or ``"hevc"``
#: (lossless HEVC in BT.709 limited range, tagged, as an iPhone records).
VIDEO_PARAMS = {
    "h264": {"codec": "libx264", "output_params": ["-crf", "0"]},
    "hevc": {"codec": "libx265", "output_params": ["-x265-params", "lossless=1:log-level=error", "-vf",
                                                   "scale=out_color_matrix=bt709:out_range=tv", "-colorspace", "bt709",
                                                   "-color_primaries", "bt709", "-color_trc", "bt709", "-color_range", "tv",
                                                   "-tag:v", "hvc1"]},
}


def write_capture(root: Path, *, confidence: bool = True, video: str = "h264") -> dict:
    """Write the capture to ``root``; returns what a reader should find."""
    root = Path(root)
    (root / "depth").mkdir(parents=True)
    if confidence:
        (root / "confidence").mkdir()
    (root / "camera_matrix.csv").write_text("\n".join(", ".join(f"{v:.6f}" for v in row) for row in K) + "\n")
    fd = depth_intrinsics()
    poses, depths, levels_all = [], [], []
    lines = ["timestamp, frame, x, y, z, qx, qy, qz, qw"]
    writer = imageio_ffmpeg.write_frames(str(root / "rgb.mp4"), COLOUR_SIZE, fps=30, quality=None, ffmpeg_log_level="error",
                                         **VIDEO_PARAMS[video])
    writer.send(None)
    for i, look in enumerate(LOOKS):
        R = rotation_arkit(look)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, POSITION_ARKIT
        poses.append(T)
        qx, qy, qz, qw = Rotation.from_matrix(R).as_quat()
        x, y, z = POSITION_ARKIT
        lines.append(f"{TIMESTAMPS[i]}, {i:06d}, {x}, {y}, {z}, {qx}, {qy}, {qz}, {qw}")
        _, rgb = cast(R, POSITION_ARKIT, K[0, 0], K[1, 1], K[0, 2], K[1, 2], *COLOUR_SIZE)
        writer.send(np.ascontiguousarray(rgb))
        zd, _ = cast(R, POSITION_ARKIT, *fd, *DEPTH_SIZE)
        mm = np.round(zd * 1000).astype(np.uint16)
        mm[100:104, 50:54] = 0  # no return
        lv = np.full(mm.shape, 2, np.uint8)
        lv[:20] = 1  # medium confidence along the top
        lv[:, :10] = 0  # low on the left
        depths.append(mm)
        levels_all.append(lv)
        assert cv2.imwrite(str(root / "depth" / f"{i:06d}.png"), mm)
        if confidence:
            assert cv2.imwrite(str(root / "confidence" / f"{i:06d}.png"), lv)
    writer.close()
    (root / "odometry.csv").write_text("\n".join(lines) + "\n")
    return {"poses_arkit": poses, "depth_mm": depths, "levels": levels_all}
