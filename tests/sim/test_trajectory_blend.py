"""Sequences joined by a blend: a hand-held device moves continuously (no jump where two parts meet)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.types import RigidTransform
from sim.trajectory import OrbitTrajectory, SequenceTrajectory, blend_poses, load_trajectory, trajectory_from_dict

FPS = 30.0


def _steps(traj, t0: float, t1: float, dt: float = 1 / FPS):
    ts = np.arange(t0, t1, dt)
    poses = [traj.pose(t) for t in ts]
    move = np.array([np.linalg.norm(b.translation - a.translation) for a, b in zip(poses, poses[1:])])
    turn = np.array([np.degrees(np.linalg.norm(Rotation.from_matrix(a.rotation.T @ b.rotation).as_rotvec()))
                     for a, b in zip(poses, poses[1:])])
    return ts, move, turn


@pytest.mark.parametrize("name", ["orbit", "orbit_then_removal_pass", "orbit_inward", "sweep"])
def test_shipped_trajectories_never_jump_between_two_colour_frames(name):
    _, move, turn = _steps(load_trajectory(name), 0.0, 30.0)
    # Below 1.5 m/s and 360°/s: a brisk hand. The default orbit used to jump 1.11 m at 10 s.
    assert move.max() < 1.5 / FPS
    assert turn.max() < 360.0 / FPS


def test_default_orbit_is_unchanged_outside_its_blend():
    traj = load_trajectory("orbit")
    first, second = traj.parts
    for t in (0.0, 4.3, 8.99):
        assert traj.pose(t) == first.pose(t)
    for t in (11.0, 15.5, 19.9, 40.0):
        assert traj.pose(t) == second.pose(t)
    assert traj.blend_s == (2.0,)


def test_blend_is_continuous_in_position_and_velocity_at_its_edges():
    a = OrbitTrajectory(radius_m=0.25, height_m=0.25, period_s=10.0, pitch_amplitude_deg=30.0)
    b = OrbitTrajectory(radius_m=0.8, height_m=0.6, period_s=10.0, start_deg=180.0, facing="inward", pitch_amplitude_deg=15.0)
    seq = SequenceTrajectory((a, b), (10.0,), (2.0,))
    h = 1e-4
    for edge, part in ((9.0, a), (11.0, b)):
        for t in (edge - h, edge + h):
            np.testing.assert_allclose(seq.pose(t).translation, part.pose(t).translation, atol=1e-7)
        v_seq = (seq.pose(edge + h).translation - seq.pose(edge - h).translation) / (2 * h)
        v_part = (part.pose(edge + h).translation - part.pose(edge - h).translation) / (2 * h)
        np.testing.assert_allclose(v_seq, v_part, atol=1e-3)
    # Without the blend the same sequence jumps by the distance between the parts at 10 s.
    cut = SequenceTrajectory((a, b), (10.0,))
    gap = np.linalg.norm(a.pose(10.0).translation - b.pose(10.0).translation)
    assert gap > 1.0
    assert np.linalg.norm(cut.pose(10.0).translation - cut.pose(10.0 - 1e-6).translation) == pytest.approx(gap, rel=1e-3)
    assert np.linalg.norm(seq.pose(10.0).translation - seq.pose(10.0 - 1e-6).translation) < 1e-5


def test_blend_poses_closed_forms():
    a = RigidTransform.from_rt(np.eye(3), np.array([0.0, 0.0, 1.0]), "world", "colour")
    rz = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    b = RigidTransform.from_rt(rz, np.array([2.0, 0.0, 1.0]), "world", "colour")
    assert blend_poses(a, b, 0.0) == a and blend_poses(a, b, 1.0) == b
    m = blend_poses(a, b, 0.5)
    np.testing.assert_allclose(m.translation, [1.0, 0.0, 1.0])
    np.testing.assert_allclose(m.rotation, Rotation.from_euler("z", 45, degrees=True).as_matrix(), atol=1e-12)
    assert (m.dst, m.src) == ("world", "colour")


@pytest.mark.parametrize("until, blend, error", [
    ((5.0, 6.0), (2.0, 1.0), InvalidInputError),  # [4, 6] and [5.5, 6.5] overlap
    ((5.0,), (-1.0,), RangeError),
    ((5.0,), (1.0, 1.0), InvalidInputError),
    ((5.0,), (float("nan"),), RangeError),
])
def test_bad_blends_are_refused(until, blend, error):
    parts = tuple(OrbitTrajectory() for _ in range(len(until) + 1))
    with pytest.raises(error):
        SequenceTrajectory(parts, until, blend)


def test_blend_reads_from_yaml():
    spec = {"kind": "sequence", "parts": [{"kind": "orbit", "until_s": 3.0, "blend_s": 1.0}, {"kind": "orbit", "radius_m": 0.5}]}
    traj = trajectory_from_dict(spec)
    assert traj.blend_s == (1.0,)
    assert trajectory_from_dict({**spec, "parts": [{"kind": "orbit", "until_s": 3.0}, {"kind": "orbit"}]}).blend_s == (0.0,)
