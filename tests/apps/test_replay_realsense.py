"""RealSense bags through Open3D's ``t.io.RSBagReader``.

No bag can be written offline (Open3D records only from a connected camera, and librealsense's
software-device recorder is not a dependency), so the reader is replaced at its documented interface
(``open``, ``metadata``, ``next_frame``, ``is_eof``, ``get_timestamp``, ``close``) by one serving
frames of the hand-built room, as Open3D's own objects (``t.geometry.RGBDImage``,
``t.io.RGBDVideoMetadata``, ``camera.PinholeCameraIntrinsic``). The real reader is used for what it
can do without a bag: refusing a file that is none.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import rgbd_envmap
import rgbd_envmap.sources.realsense as realsense
from apps.cli import main
from rgbd_envmap.config import load_yaml
from rgbd_envmap.errors import LogFormatError
from rgbd_envmap.pipeline import PipelineConfig
from rgbd_envmap.sources.frames import detect_source_layout, open_source
from sim.raycast import SceneRaycaster
from tests.apps.dataset_writers import ORIGIN, log_block, pose_at, render, room_scene
from tests.apps.test_replay_datasets import map_errors

o3d = pytest.importorskip("open3d")

W, H = 320, 240
K = np.array([[260.0, 0.0, 161.0], [0.0, 259.0, 118.5], [0.0, 0.0, 1.0]])
N = 10
SMALL = ["--em-size", "500x250", "--no-render", "--no-video", "--quiet", "--set", "kinect_em_every=2"]


@pytest.fixture(scope="module")
def frames():
    """(rgb, depth in mm, R, t) of N frames 1/30 s apart."""
    rc = SceneRaycaster(room_scene())
    out = []
    for k in range(N):
        R, t = pose_at(k / 10.0)
        rgb, z = render(rc, K, None, R, t, W, H)
        out.append((rgb, np.where((z > 0.3) & (z < 8), np.round(z * 1000), 0).astype(np.uint16), R, t))
    return out, rc


class FakeBagReader:
    """Open3D's RSBagReader as documented, serving ``frames`` (colour stored as ``color_format``)."""

    opened: list[str] = []

    def __init__(self, frames, color_format="RGB8", depth_scale=1000.0):
        self.frames, self.color_format, self.depth_scale = frames, color_format, depth_scale
        self.i = 0
        self.is_open = False

    def open(self, filename):
        FakeBagReader.opened.append(filename)
        self.is_open, self.i = True, 0
        return True

    @property
    def metadata(self):
        m = o3d.t.io.RGBDVideoMetadata()
        m.intrinsics = o3d.camera.PinholeCameraIntrinsic(W, H, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        m.depth_scale, m.fps, m.width, m.height = self.depth_scale, 30.0, W, H
        m.color_format, m.depth_format = self.color_format, "Z16"
        m.stream_length_usec, m.device_name, m.serial_number = int(N / 30 * 1e6), "Intel RealSense D435", "0001"
        return m

    def is_eof(self):
        return self.i >= len(self.frames)

    def next_frame(self):
        if self.i >= len(self.frames):
            return o3d.t.geometry.RGBDImage()
        rgb, depth, _, _ = self.frames[self.i]
        colour = rgb[:, :, ::-1] if self.color_format.startswith("BGR") else rgb
        self.i += 1
        return o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(np.ascontiguousarray(colour)), o3d.t.geometry.Image(depth))

    def get_timestamp(self):
        return round((self.i - 1) * 1e6 / 30) if self.i else 0

    def close(self):
        self.is_open = False


@pytest.fixture
def bag(frames, tmp_path, monkeypatch):
    served, rc = frames
    path = tmp_path / "room.bag"
    path.write_bytes(b"not read: the reader is replaced")
    monkeypatch.setattr(realsense, "_default_reader", lambda: FakeBagReader(served))
    traj = tmp_path / "room.log"
    traj.write_text("".join(log_block(k, R, t) for k, (_, _, R, t) in enumerate(served)))
    return path, traj, rc


def test_a_bag_replays_with_its_camera_and_the_poses_given(bag, tmp_path):
    path, traj, rc = bag
    assert detect_source_layout(path).name == "RealSense" and detect_source_layout(path.parent).name == "RealSense"
    out = tmp_path / "run"
    assert main(["replay", str(path), "--out", str(out), "--origin", *map(str, ORIGIN), "--poses", str(traj), *SMALL]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["layout"] == "RealSense" and info["depth_frames_processed"] == N // 2 and info["skipped"] == {}
    assert info["intrinsics"]["source"] == "bag" and (info["intrinsics"]["fx"], info["intrinsics"]["cy"]) == (260.0, 118.5)
    assert info["depth_scale_units_per_m"] == 1000.0 and info["realsense"]["device_name"] == "Intel RealSense D435"
    e = map_errors(out, rc, ORIGIN)
    assert e["coverage"] > 0.1 and e["median_m"] < 0.012 and e["psnr_db"] > 20.0
    result = rgbd_envmap.replay(path, poses=traj, origin=ORIGIN, config=load_yaml(PipelineConfig, out / "config.yaml"))
    with np.load(out / "envmap.npz") as z:
        np.testing.assert_array_equal(result.envmap.valid, z["valid"])
        np.testing.assert_array_equal(result.envmap.radiance, z["radiance"])


def test_a_bag_without_poses_names_the_option(bag, tmp_path, capsys):
    path, _, _ = bag
    assert main(["replay", str(path), "--out", str(tmp_path / "run"), *SMALL]) == 1
    err = capsys.readouterr().err
    assert "holds no camera poses" in err and "--poses FILE" in err
    with pytest.raises(LogFormatError, match="poses"):
        rgbd_envmap.replay(path)


def test_bgr_colour_is_reordered_frames_without_pose_counted_and_a_tum_trajectory_works(frames, tmp_path):
    served, _ = frames
    path = tmp_path / "x.bag"
    path.write_bytes(b"")
    traj = tmp_path / "half.log"
    traj.write_text("".join(log_block(k, R, t) for k, (_, _, R, t) in enumerate(served) if k % 2 == 0))
    b = realsense.read_realsense_bag(path, trajectory=traj, reader_factory=lambda: FakeBagReader(served, "BGR8", 0.0))
    got = list(b)
    assert len(got) == N // 2 and b.skipped["no_pose"] == N // 2
    np.testing.assert_array_equal(got[1].rgb, served[2][0])  # BGR8 stored, RGB read
    assert got[1].timestamp_ns == round(round(2 * 1e6 / 30) * 1000)
    np.testing.assert_allclose(got[1].depth_m[served[2][1] > 0], served[2][1][served[2][1] > 0] / 1000.0, rtol=1e-6)
    assert not got[1].known[served[2][1] == 0].any()
    assert b.depth_scale == 1000.0 and "holds none" in b.depth_scale_source  # 0 in the metadata: D400's mm assumed
    # TUM format: looked up by the time in the recording
    from tests.apps.dataset_writers import quaternion_xyzw

    tum = tmp_path / "poses.txt"
    tum.write_text("".join(f"{k / 30:.6f} " + " ".join(f"{x:.9f}" for x in (*t, *quaternion_xyzw(R))) + "\n"
                           for k, (_, _, R, t) in enumerate(served)))
    b = realsense.read_realsense_bag(path, trajectory=tum, reader_factory=lambda: FakeBagReader(served))
    got = list(b)
    assert len(got) == N
    np.testing.assert_allclose(got[3].T_world_from_cam.rotation, served[3][2], atol=1e-8)


def test_the_real_reader_refuses_a_file_that_is_no_bag(tmp_path):
    path = tmp_path / "broken.bag"
    path.write_bytes(b"garbage" * 100)
    traj = tmp_path / "t.log"
    traj.write_text(log_block(0, np.eye(3), np.zeros(3)))
    with pytest.raises(LogFormatError, match="could not open the bag"):
        open_source(path, poses=traj)
