import numpy as np
import pytest

from rgbd_envmap.errors import InvalidInputError, NonFiniteError
from sim.trajectory import Jitter, OrbitTrajectory, WaypointTrajectory, load_trajectory, trajectory_from_dict

ANGLE_TOL = 1e-9


def _forward(T):
    return T.rotation[:, 2]


def test_outward_orbit_circles_and_looks_away():
    orbit = OrbitTrajectory(centre=(1.0, 2.0, 0.5), radius_m=0.4, height_m=0.2, period_s=8.0, pitch_amplitude_deg=0.0)
    for t in np.linspace(0, 8, 9):
        T = orbit.pose(t)
        rel = T.translation - [1.0, 2.0, 0.5]
        assert np.hypot(rel[0], rel[1]) == pytest.approx(0.4)
        assert rel[2] == pytest.approx(0.2)
        np.testing.assert_allclose(_forward(T), np.append(rel[:2] / 0.4, 0.0), atol=ANGLE_TOL)
        assert T.rotation[2, 1] < 0  # image-down axis points down in the world


def test_inward_orbit_looks_at_the_centre():
    orbit = OrbitTrajectory(centre=(0.0, 0.0, 1.0), radius_m=1.0, height_m=0.5, facing="inward", pitch_amplitude_deg=0.0)
    for t in (0.0, 3.3, 7.1):
        T = orbit.pose(t)
        to_c = np.array([0.0, 0.0, 1.0]) - T.translation
        np.testing.assert_allclose(_forward(T), to_c / np.linalg.norm(to_c), atol=ANGLE_TOL)


def test_pitch_sweep_reaches_its_amplitude():
    orbit = OrbitTrajectory(pitch_amplitude_deg=55.0, pitch_period_s=4.0)
    pitch = np.degrees(np.arcsin(_forward(orbit.pose(1.0))[2]))  # quarter period: the top of the sweep
    assert pitch == pytest.approx(55.0)


def test_waypoints_interpolate_and_hold():
    wp = WaypointTrajectory((0.0, 2.0), ((0, 0, 1), (2, 0, 1)), ((0, 5, 1), (2, 5, 1)))
    np.testing.assert_allclose(wp.pose(1.0).translation, [1, 0, 1])
    np.testing.assert_allclose(wp.pose(-3.0).translation, [0, 0, 1])
    np.testing.assert_allclose(wp.pose(9.0).translation, [2, 0, 1])
    np.testing.assert_allclose(_forward(wp.pose(1.0)), [0, 1, 0], atol=ANGLE_TOL)


def test_jitter_is_smooth_bounded_and_seeded():
    jit = Jitter(amplitude_m=0.01, amplitude_deg=1.0, seed=4)
    ts = np.linspace(0, 10, 1001)
    offsets = np.array([jit.offsets(t)[0] for t in ts])
    peak = 0.01 * 3 / np.sqrt(1.5)  # three unit sinusoids, normalised by sqrt(3/2)
    assert np.abs(offsets).max() <= peak + 1e-12
    # Smooth: a 10 ms step moves at most peak/3 · Σ 2π f_max · dt (frequencies ≤ 2 Hz).
    assert np.abs(np.diff(offsets, axis=0)).max() <= peak / 3 * 3 * 2 * np.pi * 2.0 * 0.01
    np.testing.assert_array_equal(Jitter(0.01, 1.0, 4).offsets(3.3)[1], jit.offsets(3.3)[1])
    assert not np.array_equal(Jitter(0.01, 1.0, 5).offsets(3.3)[0], jit.offsets(3.3)[0])


def test_shipped_trajectories_load():
    for name in ("orbit", "orbit_inward", "sweep", "orbit_then_removal_pass"):
        T = load_trajectory(name).pose(1.0)
        assert np.isfinite(T.matrix).all()


@pytest.mark.parametrize(
    "spec",
    [
        {"kind": "spiral"},
        {"kind": "orbit", "facing": "sideways"},
        {"kind": "orbit", "pitch_amplitude_deg": 95.0},
        {"kind": "orbit", "period_s": 0.0},
        {"kind": "waypoints", "times_s": [1.0, 0.5], "positions": [[0, 0, 0], [1, 0, 0]], "targets": [[0, 1, 0], [1, 1, 0]]},
    ],
)
def test_bad_trajectories_raise(spec):
    with pytest.raises(InvalidInputError):
        trajectory_from_dict(spec)


def test_nan_pose_is_a_clear_error():
    with pytest.raises(NonFiniteError, match="eye"):
        OrbitTrajectory(centre=(np.nan, 0.0, 0.0)).pose(0.0)


def test_sequence_switches_parts_at_the_given_times():
    seq = trajectory_from_dict({"kind": "sequence", "parts": [
        {"kind": "waypoints", "until_s": 2.0, "times_s": [0.0], "positions": [[0, 0, 1]], "targets": [[1, 0, 1]]},
        {"kind": "waypoints", "times_s": [0.0], "positions": [[5, 0, 1]], "targets": [[6, 0, 1]]},
    ]})
    np.testing.assert_allclose(seq.pose(1.99).translation, [0, 0, 1])
    np.testing.assert_allclose(seq.pose(2.0).translation, [5, 0, 1])
    assert np.isfinite(load_trajectory("orbit_then_removal_pass").pose(9.5).matrix).all()
    with pytest.raises(InvalidInputError):
        trajectory_from_dict({"kind": "sequence", "parts": []})
