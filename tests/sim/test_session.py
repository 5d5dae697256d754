import numpy as np

from rgbd_envmap.types import ColourPacket, DepthPacket
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.session import Simulator
from sim.trajectory import load_trajectory

SMALL_COLOUR = ColourCameraConfig(width=96, height=64)


def _sim(office, seed=0, **device):
    return Simulator(office, load_trajectory("orbit"), TangoDeviceConfig(colour=SMALL_COLOUR, **device), seed=seed)


def test_schedule_rates_and_order(office):
    sched = _sim(office).schedule(10.0)
    kinds = [k for _, k, _ in sched]
    assert kinds.count("depth") == 50 and kinds.count("colour") == 300
    ts = [t for t, _, _ in sched]
    assert ts == sorted(ts)
    ties = [i for i in range(len(sched) - 1) if sched[i][0] == sched[i + 1][0]]
    assert ties and all(sched[i][1] == "depth" for i in ties)


def test_stream_is_deterministic_and_seeded(office):
    a = list(_sim(office, seed=5).run(0.5))
    b = list(_sim(office, seed=5).run(0.5))
    c = list(_sim(office, seed=6).run(0.5))
    assert [p.packet for p in a] == [p.packet for p in b]
    assert [p.packet for p in a] != [p.packet for p in c]
    assert isinstance(a[0].packet, DepthPacket) and isinstance(a[1].packet, ColourPacket)


def test_depth_pose_is_colour_pose_times_extrinsics(office):
    sim = _sim(office)
    T_c, T_d = sim.true_pose_colour(1.3), sim.true_pose_depth(1.3)
    np.testing.assert_allclose(T_d.matrix, T_c.matrix @ sim.calibration.T_colour_from_depth.matrix, atol=1e-12)


def test_tracking_noise_perturbs_reported_not_true_poses(office):
    clean = next(iter(_sim(office).run(0.1)))
    noisy = next(iter(_sim(office, tracking_noise_m=0.01, tracking_noise_deg=0.5).run(0.1)))
    np.testing.assert_array_equal(clean.true_pose.matrix, noisy.true_pose.matrix)
    assert clean.packet.T_world_from_depth == clean.true_pose
    offset = np.linalg.norm(noisy.packet.T_world_from_depth.translation - noisy.true_pose.translation)
    assert 0 < offset < 0.1


def test_groundtruth_arrays_describe_the_packet(office):
    sp = next(iter(_sim(office).run(0.1)))
    gt = sp.groundtruth
    assert gt["pixel_index"].shape == (len(sp.packet.points_m),)
    assert gt["true_depth_m"].shape == (172, 224)
    z_true = gt["true_depth_m"].reshape(-1)[gt["pixel_index"]]
    z = sp.packet.points_m[:, 2]
    conf = sp.packet.confidence >= 0.7
    assert np.median(np.abs(z[conf] - z_true[conf]) / z_true[conf]) < 0.01


def test_calibration_matches_the_device(office):
    cal = _sim(office).calibration
    assert cal.sensor == "tango" and (cal.depth.width, cal.depth.height) == (224, 172)
    assert (cal.colour.width, cal.colour.height) == (96, 64)
    hfov, vfov = cal.depth.fov_deg
    assert 55 < hfov < 65 and 40 < vfov < 52
