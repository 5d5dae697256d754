"""Does a depth frame, placed by its reported pose, agree with the environment map? (ours)

A relocalisation error that persists for a while (the tracker snaps to a pose a few centimetres and
degrees off, and stays there) passes every check that looks at one pose or one frame alone: the
pose moves smoothly after the snap, and the colour pairs still find the map's depth within 1 cm on
the walls parallel to the offset. The map can tell, though. Seen from the map's origin, a frame
placed by a correct pose lands on the surfaces the map holds (up to depth noise, occlusion and
change in the scene); a frame placed by a pose off by 8 cm lands in front of or behind them in
most directions.

:func:`map_residuals` gives, for a subsample of a depth packet's points, each point's distance from
the map's origin and the map's stored distance in the point's direction (where the map is valid);
:func:`map_consistency` counts the points within ``tol_m + tol_rel × distance`` of the map and
those in front of it. One such count does not tell a right pose from a wrong one: on fault-free
sessions the agreeing fraction ranges from 0.13 to 1 (an incomplete map, surfaces the origin does
not see). The pipeline therefore compares the *same* packet placed by two poses, as reported and
with a detected jump undone (:func:`extrapolated_pose`, the motion before the jump continued):
see :class:`~rgbd_envmap.pipeline.config.PoseCheckConfig` and docs/design/faults.md. The probe
reads only the map's public arrays (``depth_m``, ``valid``, ``origin``); 2,000 points take about
a millisecond.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rgbd_envmap.checks import check_array, check_instance, check_number, check_positive_int
from rgbd_envmap.envmap.map import EnvironmentMap, check_map
from rgbd_envmap.types import RigidTransform, check_transform

__all__ = ["MapConsistency", "map_residuals", "map_consistency", "extrapolated_pose"]


@dataclass(frozen=True)
class MapConsistency:
    """How a frame agrees with the map.

    Attributes:
        sampled: points probed.
        compared: of those, points whose direction from the origin has a valid map pixel.
        consistent: of those, points within the tolerance of the map's distance.
        in_front: points nearer the origin than the map's surface by more than the tolerance: in
            space the map says is empty. (The rest lie behind it: surfaces the origin does not see,
            which tell nothing.)
        judged: ``consistent + in_front``.
        fraction: ``consistent / judged`` (NaN when nothing was judged).
    """

    sampled: int
    compared: int
    consistent: int
    in_front: int

    @property
    def judged(self) -> int:
        return self.consistent + self.in_front

    @property
    def fraction(self) -> float:
        return self.consistent / self.judged if self.judged else math.nan


def map_residuals(em: EnvironmentMap, points_m: np.ndarray, T_world_from_cam: RigidTransform, *,
                  step: int = 1) -> tuple[int, np.ndarray, np.ndarray]:
    """Every ``step``-th of a camera's (N, 3) points, placed in the world by ``T_world_from_cam``,
    against the map.

    Returns ``(sampled, point_m, map_m)``: how many finite points were probed, and for those whose
    direction from ``em.origin`` falls on a valid map pixel, (n,) float64 their distance from the
    origin and (n,) float64 the map's stored distance there. Non-finite points are not probed.
    """
    check_map(em)
    check_positive_int(step, "step")
    pts = check_array(points_m, "points_m", shape=("N", 3), dtype="float")
    check_instance(T_world_from_cam, RigidTransform, "T_world_from_cam")
    check_transform(T_world_from_cam, "T_world_from_cam", "world")
    pts = pts[::step]
    pts = pts[np.isfinite(pts).all(axis=1)]
    rel = pts.astype(np.float64) @ T_world_from_cam.rotation.T + (T_world_from_cam.translation - em.origin)
    dist = np.sqrt(np.einsum("ij,ij->i", rel, rel))
    h, w = em.height, em.width
    # The map's pixel of each direction, as geometry.equirect_pixel_index finds it (conventions:
    # column from the azimuth, row from the polar angle), without its per-call checks.
    theta = np.arctan2(np.hypot(rel[:, 0], rel[:, 1]), rel[:, 2])
    phi = np.arctan2(rel[:, 1], rel[:, 0])
    cols = np.floor((phi + np.pi) * (w / (2.0 * np.pi))).astype(np.int64) % w
    rows = np.clip(np.floor(theta * (h / np.pi)).astype(np.int64), 0, h - 1)
    valid = em.valid[rows, cols] & (dist > 0)
    return len(rel), dist[valid], em.depth_m[rows[valid], cols[valid]].astype(np.float64)


def map_consistency(em: EnvironmentMap, points_m: np.ndarray, T_world_from_cam: RigidTransform, *, step: int = 1,
                    tol_m: float = 0.02, tol_rel: float = 0.02) -> MapConsistency:
    """How many of the probed points (:func:`map_residuals`) lie within ``tol_m + tol_rel ×
    distance`` of the map's stored distance in their direction."""
    tol_m = check_number(tol_m, "tol_m", low=0.0)
    tol_rel = check_number(tol_rel, "tol_rel", low=0.0)
    sampled, d, m = map_residuals(em, points_m, T_world_from_cam, step=step)
    tol = tol_m + tol_rel * d
    consistent = int(np.count_nonzero(np.abs(d - m) <= tol))
    in_front = int(np.count_nonzero(d < m - tol))
    return MapConsistency(sampled, len(d), consistent, in_front)


def _rotation_power(R: np.ndarray, s: float) -> np.ndarray:
    """R^s for a rotation matrix (axis-angle scaled by s; Rodrigues' formula)."""
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # 2 sin(angle) × axis
    norm = float(np.linalg.norm(axis))
    angle = math.atan2(0.5 * norm, 0.5 * (np.trace(R) - 1.0))  # accurate near 0 and near a half turn
    if angle < 1e-15:
        return np.eye(3)
    if norm < 1e-9 and angle > 1.0:  # a half turn: the axis from the symmetric part
        k = int(np.argmax(np.diag(R)))
        axis = (R[:, k] + np.eye(3)[k]) / math.sqrt(2.0 * (1.0 + R[k, k]))
    else:
        axis = axis / norm
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    a = s * angle
    return np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * (K @ K)


def extrapolated_pose(earlier: np.ndarray, later: np.ndarray, s: float) -> np.ndarray:
    """(4, 4) the pose ``s`` steps of the motion from ``earlier`` to ``later`` (4×4 world-from-device
    matrices) beyond ``later``, at constant velocity: the position moves on by s × the step and the
    orientation turns on by the step's rotation to the power s (both in the world frame)."""
    a = check_array(earlier, "earlier", shape=(4, 4), dtype="float", finite=True)
    b = check_array(later, "later", shape=(4, 4), dtype="float", finite=True)
    s = check_number(s, "s")
    out = np.eye(4)
    out[:3, :3] = _rotation_power(b[:3, :3] @ a[:3, :3].T, s) @ b[:3, :3]
    out[:3, 3] = b[:3, 3] + s * (b[:3, 3] - a[:3, 3])
    return out
