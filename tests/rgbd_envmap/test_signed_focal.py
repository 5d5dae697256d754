"""Negative focal lengths through every stage that looks at pixels (issue 21, ICL-NUIM's fy = −480).

The check is a mirror: a camera with fy < 0 sees in pixel (u, v) what the camera with +|fy| and the
principal point mirrored (cy′ = H − 1 − cy) sees in pixel (u, H − 1 − v), in the same camera frame
and pose. So every stage fed the upside-down images with the positive camera must give the same
result upside down (and the same for fx < 0, left to right). Where a stage's result depends on which
way it walks the grid (the warp splits each pixel quad along one diagonal, and a vertical flip turns
that diagonal into the other), the two agree to a fraction of a millimetre; a single frame through
the whole pipeline agrees bit for bit.

Frames: views of a simple room ray-cast by the simulator (``tests/apps/dataset_writers.py``).
"""

from __future__ import annotations

import numpy as np
import pytest

from rgbd_envmap.config import apply_overrides
from rgbd_envmap.depth import fill_holes, mark_reliable
from rgbd_envmap.depth.denoise import denoise_depth
from rgbd_envmap.ingest.kinect import KinectMerger, normals_from_depth
from rgbd_envmap.ingest.tango import rgbd_frame_from_packets
from rgbd_envmap.pipeline import Pipeline, PipelineConfig
from rgbd_envmap.types import Calibration, DepthPacket, Intrinsics, RigidTransform
from tests.apps.dataset_writers import pose_at, render, room_scene
from sim.raycast import SceneRaycaster

W, H = 160, 120
FX, FY, CX, CY = 120.3, 120.0, 79.5, 59.5  # ICL-NUIM's camera at a quarter of its size


def cameras(axis: str) -> tuple[Intrinsics, Intrinsics]:
    """(the signed camera, the positive camera of the flipped images)."""
    if axis == "v":
        return Intrinsics(W, H, FX, -FY, CX, CY), Intrinsics(W, H, FX, FY, CX, H - 1 - CY)
    return Intrinsics(W, H, -FX, FY, CX, CY), Intrinsics(W, H, FX, FY, W - 1 - CX, CY)


def flip(a: np.ndarray, axis: str) -> np.ndarray:
    return np.ascontiguousarray(a[::-1] if axis == "v" else a[:, ::-1])


@pytest.fixture(scope="module")
def views():
    """(rgb uint8, z-depth float32, known, pose) of four views a little apart, rendered with the
    signed camera of each axis."""
    rc = SceneRaycaster(room_scene())
    out = {}
    for axis in ("v", "u"):
        signed, _ = cameras(axis)
        frames = []
        for k in range(4):
            R, t = pose_at(0.04 * k)
            rgb, z = render(rc, signed.K, None, R, t, W, H)
            z = np.round(z * 5000) / 5000  # the PNG's quantisation
            frames.append((rgb, z.astype(np.float32), z > 0.4, RigidTransform.from_rt(R, t, "world", "colour")))
        out[axis] = frames
    return out


@pytest.mark.parametrize("axis", ["v", "u"])
def test_denoise_reliability_and_hole_filling_mirror(views, axis):
    signed, positive = cameras(axis)
    rgb8, z, known, _ = views[axis][1]
    known = known.copy()
    known[40:52, 60:75] = False  # a hole to fill
    rgb = rgb8.astype(np.float32) / 255
    a = denoise_depth(z, known, signed)
    b = denoise_depth(flip(z, axis), flip(known, axis), positive)
    np.testing.assert_allclose(flip(a, axis), b, rtol=2e-6, atol=0)  # float rounding of the sums' order
    assert np.abs(a - z)[known].max() > 0  # the denoiser did something
    np.testing.assert_array_equal(flip(mark_reliable(rgb, z, known), axis),
                                  mark_reliable(flip(rgb, axis), flip(z, axis), flip(known, axis)))
    da, ka = fill_holes(z, known)
    db, kb = fill_holes(flip(z, axis), flip(known, axis))
    np.testing.assert_array_equal(flip(ka, axis), kb)
    np.testing.assert_array_equal(flip(da, axis), db)


def second_difference(z: np.ndarray) -> np.ndarray:
    """max(|z(v+1) + z(v−1) − 2z|, |z(u+1) + z(u−1) − 2z|): where the surface bends (0 on a plane seen
    fronto-parallel; at a wall corner or an edge, centimetres)."""
    z = z.astype(np.float64)
    out = np.zeros_like(z)
    out[1:-1, 1:-1] = np.maximum(np.abs(z[2:, 1:-1] + z[:-2, 1:-1] - 2 * z[1:-1, 1:-1]),
                                 np.abs(z[1:-1, 2:] + z[1:-1, :-2] - 2 * z[1:-1, 1:-1]))
    return out


@pytest.mark.parametrize("axis", ["v", "u"])
def test_kinect_merge_and_normals_mirror(views, axis):
    """Warp + merge: standing still, the mirror bit for bit; over four moving frames the same merged
    depth to tens of micrometres, except where the surface bends inside a pixel quad (a wall corner,
    an edge): there the warp's choice of diagonal, which flips with the image, interpolates differently.
    Normals: the same camera-frame vectors."""
    signed, positive = cameras(axis)
    still_a, still_b = KinectMerger(signed), KinectMerger(positive)
    ma, mb = KinectMerger(signed), KinectMerger(positive)
    for rgb, z, known, T in views[axis]:
        sa = still_a.step(z, known, views[axis][0][3])
        sb = still_b.step(flip(z, axis), flip(known, axis), views[axis][0][3])
        ra = ma.step(z, known, T)
        rb = mb.step(flip(z, axis), flip(known, axis), T)
    np.testing.assert_array_equal(flip(sa.depth_m, axis), sb.depth_m)
    np.testing.assert_array_equal(flip(sa.weight, axis), sb.weight)
    assert ra.n_warped > 0.5 * W * H and ra.n_averaged > 0.3 * W * H  # the history was used
    ka, kb = flip(ra.known, axis), rb.known
    assert (ka ^ kb).sum() <= 0.002 * W * H
    both = ka & kb
    d = np.abs(flip(ra.depth_m, axis) - rb.depth_m)
    assert np.median(d[both]) < 1e-5 and np.percentile(d[both], 95) < 1e-4  # metres (measured 2.6 µm, 28 µm)
    far = both & (d > 1e-3)
    assert far.sum() < 0.02 * W * H  # measured 1.1 %
    assert (second_difference(rb.depth_m)[far] > 2e-3).mean() > 0.9  # measured 96 %: bends, not planes
    na, va = normals_from_depth(z, known, signed)
    nb, vb = normals_from_depth(flip(z, axis), flip(known, axis), positive)
    np.testing.assert_array_equal(flip(va, axis), vb)
    np.testing.assert_allclose(flip(na, axis)[vb], nb[vb], atol=1e-5)  # one camera frame: the same vectors
    assert (np.sum(na[va] * np.array([0, 0, 1.0]), axis=-1) < 0).all()  # facing the camera


@pytest.mark.parametrize("axis", ["v", "u"])
def test_one_frame_through_the_pipeline_is_the_mirror_bit_for_bit(views, axis):
    """Kinect path, one frame: merge (no history), reliability, colour pairs, the map update with its
    footprints (0.5 (|fx| + |fy|)) and carving: the same map."""
    signed, positive = cameras(axis)
    rgb, z, known, T = views[axis][0]
    cfg = apply_overrides(PipelineConfig(), ["render.enabled=false", "capture.width=400", "capture.height=200",
                                             "kinect_em_stride=1"])
    origin = T.translation + T.rotation[:, 2]
    maps = []
    for intr, images in ((signed, (rgb, z, known)), (positive, tuple(flip(a, axis) for a in (rgb, z, known)))):
        cal = Calibration("kinect", intr, intr, RigidTransform.identity("colour", "depth"), 30.0, 30.0)
        with Pipeline(cfg, cal, origin) as pipe:
            pipe.feed_rgbd(1, *images, T)
            maps.append(pipe.capture.em)
    a, b = maps
    assert a.valid.sum() > 0.05 * a.valid.size
    np.testing.assert_array_equal(a.valid, b.valid)
    np.testing.assert_array_equal(a.depth_m, b.depth_m)
    np.testing.assert_array_equal(a.radiance, b.radiance)


def test_stride_two_keeps_the_signed_focal_length():
    """The Kinect path subsamples the merged frame by 2: pixel j of the subsampled grid is pixel 2j,
    so fy / 2 and cy / 2 whatever the sign; every subsampled ray is the full grid's."""
    from rgbd_envmap.geometry import pixel_rays

    intr = Intrinsics(W, H, FX, -FY, CX, CY)
    half = Intrinsics(W // 2, H // 2, FX / 2, -FY / 2, CX / 2, CY / 2)
    np.testing.assert_allclose(pixel_rays(half), pixel_rays(intr)[::2, ::2], rtol=0, atol=1e-15)


def test_tango_point_cloud_lands_mirrored():
    """A point cloud projected into a depth camera with fy < 0 (and coloured from a colour camera
    with fy < 0) gives the positive cameras' frame upside down."""
    rng = np.random.default_rng(7)
    n = 4000
    pts = np.stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.45, 0.45, n), np.ones(n)], -1) * rng.uniform(0.5, 4, (n, 1))
    packet = DepthPacket(5, pts, np.ones(n), RigidTransform.identity("world", "depth"))
    img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    frames = []
    for intr, colour in ((Intrinsics(W, H, FX, -FY, CX, CY), img), (Intrinsics(W, H, FX, FY, CX, H - 1 - CY), img[::-1].copy())):
        cal = Calibration("tango", intr, intr, RigidTransform.identity("colour", "depth"))
        frames.append(rgbd_frame_from_packets(packet, colour, RigidTransform.identity("world", "colour"), cal)[0])
    a, b = frames
    assert a.known.sum() > 1000
    np.testing.assert_array_equal(a.known[::-1], b.known)
    np.testing.assert_array_equal(a.depth_m[::-1], b.depth_m)
    np.testing.assert_allclose(a.rgb[::-1][b.known], b.rgb[b.known], atol=1e-6)
