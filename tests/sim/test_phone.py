"""The simulated phone (sim.phone): its optics, its confidence levels, and a session written in the
Stray Scanner layout that reads back as the packets the simulator produced."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rgbd_envmap.colour import decode_nv21
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.sources.stray import read_stray_capture
from rgbd_envmap.types import ColourPacket, DepthPacket
from sim.phone import LEVEL_THRESHOLDS, confidence_levels, depth_image, phone_device, write_phone_session
from sim.scene import load_scene
from sim.session import Simulator
from sim.trajectory import load_trajectory


def test_the_phone_depth_is_registered_to_its_colour_camera():
    d = phone_device()
    cal = d.calibration()
    assert (cal.colour.width, cal.colour.height) == (960, 720) and (cal.depth.width, cal.depth.height) == (256, 192)
    assert cal.colour.distortion.is_zero and cal.depth.distortion.is_zero
    np.testing.assert_array_equal(cal.T_colour_from_depth.matrix, np.eye(4))
    assert cal.depth == cal.colour.scaled(256, 192)
    assert cal.colour.fov_deg[0] == pytest.approx(65.0, abs=0.1)
    assert cal.depth.fov_deg == pytest.approx(cal.colour.fov_deg, abs=1e-9)  # the same field of view
    wide = phone_device(960, 540).calibration().depth
    assert (wide.width, wide.height) == (256, 144) and wide.fx == pytest.approx(wide.fy)
    with pytest.raises(InvalidInputError, match="divides"):
        phone_device(depth_rate_hz=7.0)


def test_confidence_levels_split_at_the_documented_thresholds():
    lo, hi = LEVEL_THRESHOLDS
    c = np.array([0.0, lo - 1e-6, lo, hi - 1e-6, hi, 1.0], np.float32)
    np.testing.assert_array_equal(confidence_levels(c), [0, 0, 1, 1, 2, 2])


@pytest.fixture(scope="module")
def phone_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("phone") / "capture"
    sim = Simulator(load_scene("office_unlit"), load_trajectory("orbit"), phone_device(320, 240), seed=3)
    seen = []
    info = write_phone_session(sim, 0.5, root, envmap_size=(200, 100), on_packet=seen.append)
    return root, sim, seen, info


def test_a_simulated_session_reads_back_as_its_packets(phone_session):
    root, sim, seen, info = phone_session
    assert (info.colour_frames, info.depth_frames) == (15, 3)
    cap = read_stray_capture(root)
    assert cap.depth_frames == [0, 6, 12] and cap.calibration.depth_rate_hz == pytest.approx(5.0)
    np.testing.assert_allclose(cap.calibration.colour.K, sim.calibration.colour.K, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cap.calibration.depth.K, sim.calibration.depth.K, rtol=0, atol=1e-12)
    colour = [sp for sp in seen if isinstance(sp.packet, ColourPacket)]
    depth = [sp for sp in seen if isinstance(sp.packet, DepthPacket)]
    read = list(cap.packets())
    assert [p.kind for p, _ in read] == [k for i in range(15) for k in (("depth", "colour") if i % 6 == 0 else ("colour",))]
    read_colour = [p for p, _ in read if p.kind == "colour"]
    read_depth = [p for p, _ in read if p.kind == "depth"]
    assert len(read_colour) == 15 and len(read_depth) == 3
    for sp, p in zip(colour, read_colour):
        assert p.timestamp_ns == sp.packet.timestamp_ns
        np.testing.assert_allclose(p.T_world_from_colour.matrix, sp.packet.T_world_from_colour.matrix, atol=1e-14)
        a = decode_nv21(p.nv21, 240, 320).astype(int)
        b = decode_nv21(sp.packet.nv21, 240, 320).astype(int)
        assert np.abs(a - b).mean() < 1.5  # lossless video; two YUV ↔ RGB roundings and a 4:2:0 round trip
    rays = sim.calibration.depth
    for sp, p in zip(depth, read_depth):
        assert p.timestamp_ns == sp.packet.timestamp_ns
        # the same pixels, each point within the millimetre rounding along its ray
        d, k, lv = depth_image(sp.packet, sp.groundtruth["pixel_index"], rays.shape)
        assert len(p.points_m) == int(k.sum())
        order = np.argsort(sp.groundtruth["pixel_index"])
        np.testing.assert_allclose(p.points_m, sp.packet.points_m[order], atol=1e-3)
        # the mobile path keeps exactly the points the Tango path would (default threshold 0.7)
        np.testing.assert_array_equal(p.confidence >= 0.7, sp.packet.confidence[order] >= 0.7)


def test_ground_truth_is_written_beside_the_capture(phone_session):
    root, sim, seen, info = phone_session
    with np.load(root / "groundtruth" / "envmap.npz") as z:
        assert z["radiance"].shape == (100, 200, 3) and set(z.files) >= {"distance_m", "valid", "origin", "t_s"}
        np.testing.assert_array_equal(z["origin"], sim.scene.virtual_object_position)
    with np.load(root / "groundtruth" / "frames" / "000006.npz") as z:
        assert set(z.files) == {"gains", "true_depth_m", "true_valid"} and z["true_depth_m"].shape == (192, 256)
    with np.load(root / "groundtruth" / "frames" / "000007.npz") as z:
        assert set(z.files) == {"gains"}
    meta = json.loads((root / "groundtruth" / "simulation.json").read_text())
    assert meta["scene"] == "office_unlit" and meta["colour_frames"] == 15


def test_a_tango_device_cannot_be_written_in_the_phone_layout(tmp_path):
    from sim.device import TangoDeviceConfig

    sim = Simulator(load_scene("office_unlit"), load_trajectory("orbit"), TangoDeviceConfig(), seed=0)
    with pytest.raises(InvalidInputError, match="distortion"):
        write_phone_session(sim, 0.2, tmp_path / "c")
