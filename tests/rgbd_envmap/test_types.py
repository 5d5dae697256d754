"""Tests for rgbd_envmap.types: validation, immutability, equality and serialisation of the value types.

Rotations are checked against scipy's Rotation and an explicit quaternion formula written here.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
)
from rgbd_envmap.types import (
    Calibration,
    ColourPacket,
    DepthPacket,
    Distortion,
    Intrinsics,
    RGBDFrame,
    RigidTransform,
)


@dataclass(frozen=True)
class _Tolerances:
    matrix: float = 1e-12  #: float64 entries of composed / inverted 4×4 transforms
    points_m: float = 1e-12  #: float64 transformed points (metres)
    points_f32: float = 1e-5  #: float32 transformed points of magnitude ~10 m
    quat: float = 1e-12  #: quaternion components
    fov_deg: float = 1e-9  #: field of view in degrees


TOL = _Tolerances()


def _quat_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Hamilton unit quaternion (x, y, z, w) → rotation matrix, written out by hand."""
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _random_transform(seed: int, dst: str = "", src: str = "") -> RigidTransform:
    rng = np.random.default_rng(seed)
    m = np.eye(4)
    m[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    m[:3, 3] = rng.uniform(-5, 5, 3)
    return RigidTransform(m, dst, src)


def _intrinsics(**over) -> Intrinsics:
    kw = dict(width=224, height=172, fx=180.0, fy=181.0, cx=111.5, cy=85.5, distortion=Distortion.radial(0.1, -0.02, 0.003))
    kw.update(over)
    return Intrinsics(**kw)


# --------------------------------------------------------------------------------------------------
# Distortion and Intrinsics
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("field", ["k1", "k2", "p1", "p2", "k3"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_distortion_rejects_non_finite(field, bad):
    with pytest.raises(NonFiniteError) as info:
        Distortion(**{field: bad})
    assert field in str(info.value)


def test_distortion_radial_and_coefficient_order():
    d = Distortion.radial(0.1, -0.2, 0.3)
    assert (d.k1, d.k2, d.p1, d.p2, d.k3) == (0.1, -0.2, 0.0, 0.0, 0.3)
    np.testing.assert_array_equal(Distortion(1, 2, 3, 4, 5).coefficients, [1.0, 2.0, 3.0, 4.0, 5.0])
    assert Distortion().is_zero and not d.is_zero
    assert isinstance(Distortion(k1=1).k1, float)


@pytest.mark.parametrize("field", ["fx", "fy", "cx", "cy"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_intrinsics_non_finite_raises(field, bad):
    with pytest.raises(NonFiniteError):
        _intrinsics(**{field: bad})


@pytest.mark.parametrize("over", [
    {"width": 0}, {"height": 0}, {"width": -3}, {"width": 224.0}, {"height": True},
    {"fx": 0.0}, {"fy": 0.0}, {"fy": -0.0},
], ids=["zero_width", "zero_height", "negative_width", "float_width", "bool_height", "zero_fx", "zero_fy", "minus_zero_fy"])
def test_intrinsics_out_of_range_raises(over):
    with pytest.raises(RangeError) as info:
        _intrinsics(**over)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("fx_sign, fy_sign", [(1, -1), (-1, 1), (-1, -1)])
def test_intrinsics_accept_signed_focal_lengths(fx_sign, fy_sign):
    """ICL-NUIM publishes fy = −480 (POV-Ray's y-up camera frame): a signed focal length is kept as
    given; what is a size in pixels (field of view, mean focal length) uses its magnitude."""
    pos = Intrinsics(640, 480, 481.2, 480.0, 319.5, 239.5)
    neg = Intrinsics(640, 480, fx_sign * 481.2, fy_sign * 480.0, 319.5, 239.5)
    assert (neg.fx, neg.fy) == (fx_sign * 481.2, fy_sign * 480.0)
    np.testing.assert_array_equal(neg.K, [[fx_sign * 481.2, 0, 319.5], [0, fy_sign * 480.0, 239.5], [0, 0, 1]])
    assert neg.fov_deg == pos.fov_deg
    assert neg.focal_px == pos.focal_px == 0.5 * (481.2 + 480.0)
    half = neg.scaled(320, 240)
    assert (half.fx, half.fy) == (fx_sign * 240.6, fy_sign * 240.0) and half.fov_deg == pytest.approx(pos.fov_deg)
    assert Intrinsics.from_dict(json.loads(json.dumps(neg.to_dict()))) == neg


def test_focal_px_is_the_plain_mean_for_positive_focal_lengths():
    """The map update's footprint used 0.5 · (fx + fy): for positive focal lengths focal_px is that
    number bit for bit, so the default session's map does not move."""
    for fx, fy in ((180.0, 181.0), (525.0, 525.0), (517.3, 516.5), (1e-3, 7.1e5)):
        assert Intrinsics(64, 48, fx, fy, 31.5, 23.5).focal_px == 0.5 * (fx + fy)


def test_intrinsics_derived_values():
    intr = Intrinsics(640, 480, 500.0, 400.0, 319.5, 239.5)
    np.testing.assert_array_equal(intr.K, [[500.0, 0.0, 319.5], [0.0, 400.0, 239.5], [0.0, 0.0, 1.0]])
    assert intr.shape == (480, 640)
    # Centred principal point: the image spans ±W/2 pixels from the axis (pixel edges at −0.5, W−0.5).
    h, v = intr.fov_deg
    assert h == pytest.approx(2 * math.degrees(math.atan(320 / 500)), abs=TOL.fov_deg)
    assert v == pytest.approx(2 * math.degrees(math.atan(240 / 400)), abs=TOL.fov_deg)


def test_intrinsics_scaled_keeps_the_pixel_centre_convention():
    intr = Intrinsics(224, 172, 180.0, 181.0, 111.5, 85.5)
    half = intr.scaled(112, 86)
    # The image centre stays the image centre and the field of view is unchanged.
    assert (half.cx, half.cy) == pytest.approx(((112 - 1) / 2, (86 - 1) / 2))
    assert half.fov_deg == pytest.approx(intr.fov_deg)
    # Pixel corner (−0.5, −0.5) of one grid is the same ray as the other grid's corner.
    assert (-0.5 - intr.cx) / intr.fx == pytest.approx((-0.5 - half.cx) / half.fx)


def test_intrinsics_dict_round_trip_through_json():
    intr = _intrinsics(distortion=Distortion(0.1, -0.05, 0.001, -0.002, 0.01))
    d = intr.to_dict()
    again = Intrinsics.from_dict(json.loads(json.dumps(d)))
    assert again == intr
    assert again.distortion == intr.distortion
    # A dict without distortion means no distortion.
    d.pop("distortion")
    assert Intrinsics.from_dict(d).distortion.is_zero


def test_intrinsics_is_frozen_and_hashable():
    intr = _intrinsics()
    with pytest.raises(dataclasses.FrozenInstanceError):
        intr.fx = 1.0  # type: ignore[misc]
    assert hash(intr) == hash(_intrinsics())


# --------------------------------------------------------------------------------------------------
# RigidTransform
# --------------------------------------------------------------------------------------------------


def test_rigid_transform_rejects_non_orthonormal():
    m = np.eye(4)
    m[:3, :3] *= 1.01
    with pytest.raises(InvalidInputError):
        RigidTransform(m)
    shear = np.eye(4)
    shear[0, 1] = 0.05
    with pytest.raises(InvalidInputError):
        RigidTransform(shear)


def test_rigid_transform_rejects_reflection():
    with pytest.raises(InvalidInputError):
        RigidTransform(np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(InvalidInputError):
        RigidTransform(np.diag([-1.0, -1.0, -1.0, 1.0]))


@pytest.mark.parametrize("where", [(0, 0), (1, 3), (2, 2)])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_rigid_transform_rejects_non_finite(where, bad):
    m = np.eye(4)
    m[where] = bad
    with pytest.raises(NonFiniteError):
        RigidTransform(m)


@pytest.mark.parametrize("last", [[0.0, 0.0, 0.0, 2.0], [0.1, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0]])
def test_rigid_transform_rejects_bad_last_row(last):
    m = np.eye(4)
    m[3] = last
    with pytest.raises(InvalidInputError):
        RigidTransform(m)


def test_rigid_transform_rejects_wrong_shape():
    with pytest.raises(ShapeError):
        RigidTransform(np.eye(4)[:3])
    with pytest.raises(ShapeError):
        RigidTransform(np.eye(3))


def test_rigid_transform_accepts_rounding_noise_and_stores_a_read_only_copy():
    m = _random_transform(0).matrix.copy()
    m[:3, :3] += 1e-10
    T = RigidTransform(m)
    assert T.matrix.dtype == np.float64 and not T.matrix.flags.writeable
    m[0, 3] = 99.0
    assert T.matrix[0, 3] != 99.0
    with pytest.raises(ValueError):
        T.matrix[0, 0] = 2.0


@pytest.mark.parametrize("seed", range(5))
def test_inverse_composes_to_identity(seed):
    T = _random_transform(seed, "a", "b")
    inv = T.inverse()
    assert (inv.dst, inv.src) == ("b", "a")
    np.testing.assert_allclose(inv.matrix, np.linalg.inv(T.matrix), rtol=0, atol=TOL.matrix)
    left, right = T @ inv, inv @ T
    np.testing.assert_allclose(left.matrix, np.eye(4), rtol=0, atol=TOL.matrix)
    np.testing.assert_allclose(right.matrix, np.eye(4), rtol=0, atol=TOL.matrix)
    assert (left.dst, left.src) == ("a", "a")
    assert (right.dst, right.src) == ("b", "b")


def test_composition_matches_matrix_product_and_chains_names():
    a_from_b = _random_transform(1, "a", "b")
    b_from_c = _random_transform(2, "b", "c")
    a_from_c = a_from_b @ b_from_c
    assert (a_from_c.dst, a_from_c.src) == ("a", "c")
    np.testing.assert_allclose(a_from_c.matrix, a_from_b.matrix @ b_from_c.matrix, rtol=0, atol=TOL.matrix)
    p = np.array([0.3, -1.0, 2.0])
    np.testing.assert_allclose(a_from_c.apply(p), a_from_b.apply(b_from_c.apply(p)), rtol=0, atol=TOL.points_m)


def test_composition_with_mismatched_frames_raises():
    with pytest.raises(InvalidInputError) as info:
        _random_transform(1, "world", "cam") @ _random_transform(2, "depth", "device")
    assert "cam" in str(info.value) and "depth" in str(info.value)


def test_composition_with_unnamed_frames_is_unchecked():
    T = _random_transform(1, "world", "") @ _random_transform(2, "depth", "device")
    assert (T.dst, T.src) == ("world", "device")
    T = _random_transform(1) @ _random_transform(2)
    assert (T.dst, T.src) == ("", "")


def test_long_chain_stays_valid():
    step = _random_transform(7)
    T = RigidTransform.identity()
    for _ in range(1000):
        T = T @ step
    R = T.rotation
    np.testing.assert_allclose(R.T @ R, np.eye(3), rtol=0, atol=1e-9)


def test_quaternion_order_is_xyzw():
    # 90° about +z maps +x to +y.
    s = math.sqrt(0.5)
    T = RigidTransform.from_quaternion(np.zeros(3), np.array([0.0, 0.0, s, s]))
    np.testing.assert_allclose(T.apply(np.array([1.0, 0.0, 0.0])), [0.0, 1.0, 0.0], rtol=0, atol=TOL.points_m)


@pytest.mark.parametrize("seed", range(10))
def test_quaternion_round_trip_against_scipy(seed):
    q = Rotation.random(random_state=seed).as_quat()  # (x, y, z, w)
    t = np.array([1.0, -2.0, 0.5])
    T = RigidTransform.from_quaternion(t, q, "world", "cam")
    np.testing.assert_allclose(T.rotation, Rotation.from_quat(q).as_matrix(), rtol=0, atol=TOL.matrix)
    np.testing.assert_allclose(T.rotation, _quat_to_matrix(*q), rtol=0, atol=TOL.matrix)
    np.testing.assert_array_equal(T.translation, t)
    assert (T.dst, T.src) == ("world", "cam")
    got = T.quaternion_xyzw()
    assert got[3] >= 0
    np.testing.assert_allclose(got, q if q[3] >= 0 else -q, rtol=0, atol=TOL.quat)
    # Negated input is the same rotation and gives the same canonical quaternion.
    np.testing.assert_allclose(RigidTransform.from_quaternion(t, -q).quaternion_xyzw(), got, rtol=0, atol=TOL.quat)


def test_from_quaternion_normalises_and_rejects_far_from_unit():
    q = Rotation.random(random_state=3).as_quat()
    T = RigidTransform.from_quaternion(np.zeros(3), 1.2 * q)
    np.testing.assert_allclose(T.rotation, _quat_to_matrix(*q), rtol=0, atol=TOL.matrix)
    with pytest.raises(InvalidInputError):
        RigidTransform.from_quaternion(np.zeros(3), np.zeros(4))
    with pytest.raises(InvalidInputError):
        RigidTransform.from_quaternion(np.zeros(3), 5.0 * q)
    with pytest.raises(NonFiniteError):
        RigidTransform.from_quaternion(np.zeros(3), np.array([np.nan, 0.0, 0.0, 1.0]))
    with pytest.raises(ShapeError):
        RigidTransform.from_quaternion(np.zeros(3), q[:3])


def test_apply_and_rotate_against_explicit_matrix_math():
    T = _random_transform(4)
    R, t = T.matrix[:3, :3], T.matrix[:3, 3]
    rng = np.random.default_rng(4)
    p = rng.uniform(-10, 10, size=(2, 5, 3))
    homogeneous = np.concatenate([p, np.ones((2, 5, 1))], axis=-1)
    expected = np.einsum("ij,abj->abi", T.matrix, homogeneous)[..., :3]
    got = T.apply(p)
    assert got.shape == (2, 5, 3) and got.dtype == np.float64
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOL.points_m)
    np.testing.assert_allclose(T.apply(p[0, 0]), R @ p[0, 0] + t, rtol=0, atol=TOL.points_m)
    np.testing.assert_allclose(T.rotate(p), np.einsum("ij,abj->abi", R, p), rtol=0, atol=TOL.points_m)


def test_apply_keeps_float32_and_promotes_ints():
    T = _random_transform(5)
    p32 = np.random.default_rng(5).uniform(-10, 10, (50, 3)).astype(np.float32)
    out = T.apply(p32)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, T.apply(p32.astype(np.float64)), rtol=0, atol=TOL.points_f32)
    assert T.apply(np.array([[1, 2, 3]])).dtype == np.float64
    assert T.rotate(np.array([[1, 2, 3]])).dtype == np.float64
    with pytest.raises(ShapeError):
        T.apply(np.zeros((4, 2)))


def test_rigid_transform_equality():
    a = _random_transform(6, "w", "c")
    assert a == RigidTransform(a.matrix.copy(), "w", "c")
    assert a != RigidTransform(a.matrix.copy(), "w", "d")
    assert a != _random_transform(7, "w", "c")
    assert RigidTransform.identity() == RigidTransform(np.eye(4))


def test_from_rt():
    R = Rotation.from_euler("xyz", [0.1, -0.4, 2.0]).as_matrix()
    T = RigidTransform.from_rt(R, [1, 2, 3], "a", "b")
    expected = np.eye(4)
    expected[:3, :3], expected[:3, 3] = R, [1, 2, 3]
    np.testing.assert_array_equal(T.matrix, expected)


# --------------------------------------------------------------------------------------------------
# Packets
# --------------------------------------------------------------------------------------------------


def _depth_packet(n: int = 5, seed: int = 0, **over) -> DepthPacket:
    rng = np.random.default_rng(seed)
    kw = dict(
        timestamp_ns=1_000_000_123,
        points_m=rng.uniform(-2, 2, (n, 3)).astype(np.float32),
        confidence=rng.uniform(0, 1, n).astype(np.float32),
        T_world_from_depth=_random_transform(seed, "world", "depth"),
    )
    kw.update(over)
    return DepthPacket(**kw)


@pytest.mark.parametrize("bad", [1.2, -0.1, math.nan, math.inf])
def test_depth_packet_rejects_confidence_outside_unit_interval(bad):
    conf = np.full(5, 0.5, dtype=np.float32)
    conf[2] = bad
    with pytest.raises(RangeError):
        _depth_packet(confidence=conf)


def test_depth_packet_accepts_confidence_bounds():
    p = _depth_packet(n=2, confidence=np.array([0.0, 1.0]))
    np.testing.assert_array_equal(p.confidence, [0.0, 1.0])
    assert p.confidence.dtype == np.float32 and p.points_m.dtype == np.float32


def test_depth_packet_rejects_mismatched_lengths_and_shapes():
    with pytest.raises(ShapeError):
        _depth_packet(confidence=np.full(4, 0.5))
    with pytest.raises(ShapeError):
        _depth_packet(points_m=np.zeros((5, 2)))
    with pytest.raises(ShapeError):
        _depth_packet(confidence=np.full((5, 1), 0.5))


def test_depth_packet_rejects_non_transform_pose():
    with pytest.raises(DTypeError, match="T_world_from_depth"):  # a wrong type is a TypeError
        _depth_packet(T_world_from_depth=np.eye(4))


def test_depth_packet_accepts_empty_cloud():
    p = _depth_packet(points_m=np.zeros((0, 3)), confidence=np.zeros(0))
    assert p.points_m.shape == (0, 3) and p.confidence.shape == (0,)
    assert p.kind == "depth"


def test_depth_packet_arrays_are_read_only_copies():
    pts = np.random.default_rng(1).uniform(-1, 1, (5, 3)).astype(np.float32)
    conf = np.full(5, 0.9, dtype=np.float32)
    p = _depth_packet(points_m=pts, confidence=conf)
    pts[0, 0] = 42.0
    conf[0] = 0.1
    assert p.points_m[0, 0] != 42.0
    assert p.confidence[0] == np.float32(0.9)
    for arr in (p.points_m, p.confidence):
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[0] = 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.timestamp_ns = 0  # type: ignore[misc]


def test_depth_packet_equality_by_value():
    a, b = _depth_packet(seed=3), _depth_packet(seed=3)
    assert a is not b and a.points_m is not b.points_m
    assert a == b
    conf = a.confidence.copy()
    conf[1] = conf[1] / 2
    assert a != _depth_packet(seed=3, confidence=conf)
    assert a != _depth_packet(seed=3, timestamp_ns=a.timestamp_ns + 1)
    assert a != _depth_packet(seed=3, T_world_from_depth=_random_transform(99, "world", "depth"))


def _colour_packet(nv21: np.ndarray) -> ColourPacket:
    return ColourPacket(timestamp_ns=5, nv21=nv21, T_world_from_colour=RigidTransform.identity("world", "colour"))


@pytest.mark.parametrize("shape", [(0, 4), (3, 0), (0, 0), (3, 3), (6, 5), (4, 4), (5, 8), (2, 8)],
                         ids=["zero_rows", "zero_width", "empty", "odd_width", "odd_width_2",
                              "rows_not_3k", "rows_not_3k_2", "rows_2"])
def test_colour_packet_rejects_bad_sizes(shape):
    with pytest.raises(InvalidInputError):
        _colour_packet(np.zeros(shape, dtype=np.uint8))


def test_colour_packet_rejects_wrong_rank_and_dtype():
    with pytest.raises(ShapeError):
        _colour_packet(np.zeros(36, dtype=np.uint8))
    with pytest.raises(DTypeError):
        _colour_packet(np.zeros((6, 4), dtype=np.uint16))


def test_colour_packet_sizes_and_immutability():
    buf = np.arange(6 * 8, dtype=np.uint8).reshape(6, 8)
    p = _colour_packet(buf)
    assert (p.height, p.width, p.kind) == (4, 8, "colour")
    buf[0, 0] = 200
    assert p.nv21[0, 0] == 0
    assert not p.nv21.flags.writeable
    assert p == _colour_packet(np.arange(6 * 8, dtype=np.uint8).reshape(6, 8))
    assert p != _colour_packet(buf)
    with pytest.raises(DTypeError, match="T_world_from_colour"):
        ColourPacket(timestamp_ns=0, nv21=np.zeros((6, 8), np.uint8), T_world_from_colour=None)  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------------
# Calibration and RGBDFrame
# --------------------------------------------------------------------------------------------------


def _calibration() -> Calibration:
    return Calibration(
        sensor="tango",
        depth=_intrinsics(),
        colour=Intrinsics(1920, 1080, 1500.0, 1500.0, 959.5, 539.5, Distortion(0.1, -0.05, 0.001, -0.002, 0.01)),
        T_colour_from_depth=_random_transform(11, "colour", "depth"),
        depth_rate_hz=5.0,
        colour_rate_hz=30.0,
    )


def test_calibration_dict_round_trip_through_json():
    cal = _calibration()
    again = Calibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    assert again == cal
    np.testing.assert_array_equal(again.T_colour_from_depth.matrix, cal.T_colour_from_depth.matrix)
    assert (again.T_colour_from_depth.dst, again.T_colour_from_depth.src) == ("colour", "depth")


def test_calibration_rejects_unknown_sensor():
    with pytest.raises(InvalidInputError) as info:
        dataclasses.replace(_calibration(), sensor="realsense")
    assert "realsense" in str(info.value)


def _frame(h: int = 172, w: int = 224, **over) -> RGBDFrame:
    rng = np.random.default_rng(0)
    kw = dict(
        rgb=rng.uniform(0, 1, (h, w, 3)),
        depth_m=rng.uniform(0.5, 4, (h, w)),
        known=rng.uniform(size=(h, w)) > 0.2,
        T_world_from_cam=RigidTransform.identity("world", "cam"),
        intrinsics=_intrinsics(width=w, height=h),
        timestamp_ns=7,
    )
    kw.update(over)
    return RGBDFrame(**kw)


@pytest.mark.parametrize("field,value,error", [
    ("rgb", np.zeros((172, 224)), ShapeError),
    ("rgb", np.zeros((224, 172, 3)), ShapeError),
    ("rgb", np.zeros((172, 224, 4)), ShapeError),
    ("depth_m", np.zeros((172, 224, 1)), ShapeError),
    ("depth_m", np.zeros((171, 224)), ShapeError),
    ("known", np.ones((172, 223), dtype=bool), ShapeError),
    ("known", np.ones((172, 224)), DTypeError),
    ("rgb", np.zeros((172, 224, 3), dtype=np.uint8), DTypeError),
])
def test_rgbd_frame_shape_and_dtype_checks(field, value, error):
    with pytest.raises(error) as info:
        _frame(**{field: value})
    assert isinstance(info.value, RgbdEnvmapError)
    assert field in str(info.value)


def test_rgbd_frame_converts_to_float32_read_only_copies():
    depth = np.full((172, 224), 2.0)
    f = _frame(depth_m=depth)
    assert f.rgb.dtype == np.float32 and f.depth_m.dtype == np.float32 and f.known.dtype == np.bool_
    depth[0, 0] = 9.0
    assert f.depth_m[0, 0] == 2.0
    for arr in (f.rgb, f.depth_m, f.known):
        assert not arr.flags.writeable
    assert f == _frame(depth_m=np.full((172, 224), 2.0))
    assert f != _frame(depth_m=np.full((172, 224), 2.5))


def test_rgbd_frame_with_depth_shares_the_rest_and_copies_writable_depth():
    f = _frame()
    before = f.depth_m.copy()
    depth = np.full((172, 224), 3.0)  # float64, writable: converted and copied
    g = f.with_depth(depth)
    depth[0, 0] = 9.0
    assert g.depth_m.dtype == np.float32 and g.depth_m[0, 0] == 3.0 and not g.depth_m.flags.writeable
    assert g.rgb is f.rgb and g.known is f.known and g.T_world_from_cam is f.T_world_from_cam
    assert g == _frame(depth_m=np.full((172, 224), 3.0))
    np.testing.assert_array_equal(f.depth_m, before)
    frozen = np.full((172, 224), 4.0, np.float32)
    frozen.setflags(write=False)
    assert f.with_depth(frozen).depth_m is frozen  # read-only float32: shared
    with pytest.raises(ShapeError, match="depth_m"):
        f.with_depth(np.zeros((172, 223)))
    with pytest.raises(DTypeError, match="depth_m"):
        f.with_depth(np.zeros((172, 224), np.int32))
