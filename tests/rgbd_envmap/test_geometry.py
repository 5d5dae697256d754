"""Tests for rgbd_envmap.geometry: Brown projection, SE(3) helpers and the equirectangular mapping.

References are independent of the code under test: OpenCV's ``projectPoints`` for the camera model,
the docs/reference/conventions.md formulas re-derived here for the equirect mapping, and numerical quadrature of
sin θ for the pixel solid angles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate

from rgbd_envmap import geometry
from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
)
from rgbd_envmap.types import Distortion, Intrinsics, RigidTransform


@dataclass(frozen=True)
class _Tolerances:
    px: float = 1e-9  #: pixel coordinates from the float64 camera model
    m: float = 1e-9  #: metres, unproject(project(p)) round trip
    normalized: float = 1e-12  #: normalised image coordinates, undistort(distort(xy))
    solid_angle_rel: float = 1e-10  #: relative, closed-form solid angles (float64, exact formula)
    unit_f32: float = 1e-6  #: float32 direction components and norms
    angle_deg: float = 1e-3  #: angle between a direction and its round trip through (u, v)
    rot: float = 1e-12  #: rotation-matrix entries built in float64


TOL = _Tolerances()

# A VGA camera with lens-like Brown coefficients (OpenCV order k1, k2, p1, p2, k3).
FX, FY, CX, CY, WIDTH, HEIGHT = 500.0, 505.0, 319.5, 241.0, 640, 480
K1, K2, P1, P2, K3 = 0.12, -0.08, 0.0015, -0.0012, 0.015
RK1, RK2, RK3 = -0.2, 0.06, -0.01  # the 3-coefficient radial form of the ToF camera


def _camera_matrix() -> np.ndarray:
    return np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])


def _intrinsics(distortion: Distortion) -> Intrinsics:
    return Intrinsics(WIDTH, HEIGHT, FX, FY, CX, CY, distortion)


DISTORTIONS = {
    "none": Distortion(),
    "brown5": Distortion(K1, K2, P1, P2, K3),
    "radial3": Distortion.radial(RK1, RK2, RK3),
    "k1_plus_0.2": Distortion.radial(0.2, 0.0, 0.0),
    "k1_minus_0.2": Distortion.radial(-0.2, 0.0, 0.0),
}


def _points_over_image(rng: np.random.Generator, n: int) -> np.ndarray:
    """Camera-frame points whose undistorted rays span the whole VGA image and a little beyond."""
    x = rng.uniform(-0.7, 0.7, n)
    y = rng.uniform(-0.55, 0.55, n)
    z = rng.uniform(0.2, 12.0, n)
    return np.stack([x * z, y * z, z], axis=-1)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between (..., 3) vectors, accurate near 0 (atan2 of |a×b| and a·b)."""
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    dot = np.sum(a * b, axis=-1)
    return np.degrees(np.arctan2(cross, dot))


def _design_direction(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """docs/reference/conventions.md: d = (sin θ cos φ, sin θ sin φ, cos θ)."""
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


# --------------------------------------------------------------------------------------------------
# Projection with Brown distortion
# --------------------------------------------------------------------------------------------------


def test_project_points_matches_cv2_with_five_coefficients():
    rng = np.random.default_rng(1)
    p = _points_over_image(rng, 2000)
    uv, in_front = geometry.project_points(p, _intrinsics(Distortion(K1, K2, P1, P2, K3)))
    ref, _ = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), _camera_matrix(),
                               np.array([K1, K2, P1, P2, K3]))
    assert in_front.all()
    np.testing.assert_allclose(uv, ref[:, 0, :], rtol=0, atol=TOL.px)


def test_project_points_matches_cv2_with_radial_form():
    rng = np.random.default_rng(2)
    p = _points_over_image(rng, 2000)
    uv, _ = geometry.project_points(p, _intrinsics(Distortion.radial(RK1, RK2, RK3)))
    # OpenCV's order is (k1, k2, p1, p2, k3): the radial form's k3 is the fifth coefficient.
    ref, _ = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), _camera_matrix(),
                               np.array([RK1, RK2, 0.0, 0.0, RK3]))
    np.testing.assert_allclose(uv, ref[:, 0, :], rtol=0, atol=TOL.px)


def test_project_points_without_distortion_is_pinhole():
    p = np.array([[0.0, 0.0, 2.0], [1.0, -0.5, 2.0], [-3.0, 1.0, 4.0]])
    uv, in_front = geometry.project_points(p, _intrinsics(Distortion()))
    expected = np.array([[CX, CY], [CX + FX * 0.5, CY - FY * 0.25], [CX - FX * 0.75, CY + FY * 0.25]])
    np.testing.assert_allclose(uv, expected, rtol=0, atol=TOL.px)
    assert in_front.tolist() == [True, True, True]


def test_project_points_shapes_and_dtypes():
    intr = _intrinsics(Distortion(K1, K2, P1, P2, K3))
    uv, in_front = geometry.project_points(np.array([[0, 0, 1], [1, 1, 3]]), intr)  # ints accepted
    assert uv.shape == (2, 2) and uv.dtype == np.float64
    assert in_front.shape == (2,) and in_front.dtype == np.bool_
    uv0, in_front0 = geometry.project_points(np.zeros((0, 3)), intr)
    assert uv0.shape == (0, 2) and in_front0.shape == (0,)


@pytest.mark.parametrize("distortion", [Distortion(), Distortion(K1, K2, P1, P2, K3)], ids=["none", "brown5"])
def test_points_behind_camera_or_non_finite_are_not_in_front(distortion):
    p = np.array([
        [0.1, 0.2, -1.0],  # behind
        [0.1, 0.2, 0.0],  # on the camera plane
        [np.nan, 0.0, 1.0],
        [0.0, np.inf, 1.0],
        [0.0, 0.0, np.nan],
        [0.1, -0.1, 2.0],  # the one good point
    ])
    uv, in_front = geometry.project_points(p, _intrinsics(distortion))
    assert in_front.tolist() == [False, False, False, False, False, True]
    assert np.isnan(uv[:5]).all()
    assert np.isfinite(uv[5]).all()


@pytest.mark.parametrize("name", list(DISTORTIONS))
def test_unproject_inverts_project(name):
    intr = _intrinsics(DISTORTIONS[name])
    rng = np.random.default_rng(3)
    p = _points_over_image(rng, 3000)
    uv, in_front = geometry.project_points(p, intr)
    assert in_front.all()
    # The sample reaches the image corners, so the inverse is exercised over the whole image.
    assert uv[:, 0].min() < 20 and uv[:, 0].max() > WIDTH - 20
    assert uv[:, 1].min() < 20 and uv[:, 1].max() > HEIGHT - 20
    back = geometry.unproject_pixels(uv, p[:, 2], intr)
    np.testing.assert_allclose(back, p, rtol=0, atol=TOL.m)


@pytest.mark.parametrize("name", list(DISTORTIONS))
def test_project_inverts_unproject_on_every_corner_and_edge(name):
    intr = _intrinsics(DISTORTIONS[name])
    u = np.array([-0.5, 0.0, CX, WIDTH - 1.0, WIDTH - 0.5])
    v = np.array([-0.5, 0.0, CY, HEIGHT - 1.0, HEIGHT - 0.5])
    uu, vv = np.meshgrid(u, v)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=-1)
    z = np.linspace(0.3, 9.0, len(uv))
    p = geometry.unproject_pixels(uv, z, intr)
    np.testing.assert_allclose(p[:, 2], z, rtol=0, atol=TOL.m)
    uv_back, in_front = geometry.project_points(p, intr)
    assert in_front.all()
    np.testing.assert_allclose(uv_back, uv, rtol=0, atol=TOL.px)


@pytest.mark.parametrize("name", ["brown5", "radial3", "k1_plus_0.2", "k1_minus_0.2"])
def test_undistort_inverts_distort(name):
    distortion = DISTORTIONS[name]
    rng = np.random.default_rng(4)
    xy = rng.uniform(-0.75, 0.75, size=(500, 2))
    xyd = geometry.distort_normalized(xy, distortion)
    assert np.abs(xyd - xy).max() > 1e-3  # the distortion really moves points
    np.testing.assert_allclose(geometry.undistort_normalized(xyd, distortion), xy, rtol=0, atol=TOL.normalized)
    # Batched (..., 2) input keeps its shape.
    batched = geometry.undistort_normalized(xyd.reshape(10, 50, 2), distortion)
    np.testing.assert_allclose(batched.reshape(-1, 2), xy, rtol=0, atol=TOL.normalized)


def test_distort_normalized_matches_brown_formula():
    x, y = 0.3, -0.2
    r2 = x * x + y * y
    radial = 1 + K1 * r2 + K2 * r2**2 + K3 * r2**3
    expected = [x * radial + 2 * P1 * x * y + P2 * (r2 + 2 * x * x), y * radial + P1 * (r2 + 2 * y * y) + 2 * P2 * x * y]
    got = geometry.distort_normalized(np.array([x, y]), Distortion(K1, K2, P1, P2, K3))
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOL.normalized)


def test_pixel_rays_have_unit_z_and_match_unproject_of_pixel_centres():
    intr = Intrinsics(40, 30, 35.0, 36.0, 19.5, 14.0, Distortion(K1, K2, P1, P2, K3))
    rays = geometry.pixel_rays(intr)
    assert rays.shape == (30, 40, 3) and rays.dtype == np.float64
    np.testing.assert_array_equal(rays[..., 2], 1.0)
    vv, uu = np.mgrid[0:30, 0:40]
    uv = np.stack([uu.ravel(), vv.ravel()], axis=-1).astype(np.float64)
    expected = geometry.unproject_pixels(uv, np.ones(len(uv)), intr).reshape(30, 40, 3)
    np.testing.assert_allclose(rays, expected, rtol=0, atol=TOL.m)
    # Independent of unproject: each ray projects back onto its own pixel centre.
    uv_back, _ = geometry.project_points(rays.reshape(-1, 3), intr)
    np.testing.assert_allclose(uv_back, uv, rtol=0, atol=TOL.px)


# --- signed focal lengths (ICL-NUIM's fy = −480) ------------------------------------------------------

SIGNS = [(1, -1), (-1, 1), (-1, -1)]


def _signed(fx_sign: int, fy_sign: int, distortion: Distortion) -> Intrinsics:
    return Intrinsics(WIDTH, HEIGHT, fx_sign * FX, fy_sign * FY, CX, CY, distortion)


@pytest.mark.parametrize("fx_sign, fy_sign", SIGNS)
@pytest.mark.parametrize("name", ["none", "brown5", "radial3"])
def test_signed_focal_lengths_project_as_written_and_match_cv2(fx_sign, fy_sign, name):
    """u = fx·x′ + cx, v = fy·y′ + cy with the signs as given: against OpenCV's projectPoints with the
    same (signed) camera matrix, and against the positive camera mirrored about the principal point
    (u ↦ 2cx − u where fx < 0, v ↦ 2cy − v where fy < 0)."""
    d = DISTORTIONS[name]
    intr = _signed(fx_sign, fy_sign, d)
    p = _points_over_image(np.random.default_rng(11), 2000)
    uv, in_front = geometry.project_points(p, intr)
    assert in_front.all()
    K = np.array([[fx_sign * FX, 0.0, CX], [0.0, fy_sign * FY, CY], [0.0, 0.0, 1.0]])
    ref, _ = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, d.coefficients)
    np.testing.assert_allclose(uv, ref[:, 0, :], rtol=0, atol=TOL.px)
    pos, _ = geometry.project_points(p, _intrinsics(d))
    mirrored = np.stack([pos[:, 0] if fx_sign > 0 else 2 * CX - pos[:, 0], pos[:, 1] if fy_sign > 0 else 2 * CY - pos[:, 1]], -1)
    np.testing.assert_allclose(uv, mirrored, rtol=0, atol=TOL.px)


@pytest.mark.parametrize("fx_sign, fy_sign", SIGNS)
@pytest.mark.parametrize("name", list(DISTORTIONS))
def test_signed_focal_lengths_round_trip(fx_sign, fy_sign, name):
    """unproject(project(p)) = p and project(unproject(uv)) = uv over the whole image (Newton
    undistortion included) with negative focal lengths."""
    intr = _signed(fx_sign, fy_sign, DISTORTIONS[name])
    p = _points_over_image(np.random.default_rng(12), 3000)
    uv, in_front = geometry.project_points(p, intr)
    assert in_front.all()
    assert uv[:, 0].min() < 20 and uv[:, 0].max() > WIDTH - 20 and uv[:, 1].min() < 20 and uv[:, 1].max() > HEIGHT - 20
    np.testing.assert_allclose(geometry.unproject_pixels(uv, p[:, 2], intr), p, rtol=0, atol=TOL.m)
    uu, vv = np.meshgrid(np.array([-0.5, 0.0, CX, WIDTH - 1.0, WIDTH - 0.5]), np.array([-0.5, 0.0, CY, HEIGHT - 1.0, HEIGHT - 0.5]))
    corners = np.stack([uu.ravel(), vv.ravel()], axis=-1)
    q = geometry.unproject_pixels(corners, np.linspace(0.3, 9.0, len(corners)), intr)
    back, in_front = geometry.project_points(q, intr)
    assert in_front.all()
    np.testing.assert_allclose(back, corners, rtol=0, atol=TOL.px)


def test_pixel_rays_with_negative_fy_point_up_the_image():
    """fy < 0: the top rows see +y of the camera frame, and the ray grid is the positive camera's
    grid upside down (exactly, with the principal point on the centre row)."""
    pos = Intrinsics(40, 30, 35.0, 36.0, 19.5, 14.5, Distortion(K1, K2, P1, P2, K3))
    neg = Intrinsics(40, 30, 35.0, -36.0, 19.5, 14.5, Distortion(K1, K2, P1, P2, K3))
    rays_pos, rays_neg = geometry.pixel_rays(pos), geometry.pixel_rays(neg)
    assert (rays_neg[0, :, 1] > 0).all() and (rays_neg[-1, :, 1] < 0).all()
    np.testing.assert_allclose(rays_neg, rays_pos[::-1], rtol=0, atol=1e-15)
    uv_back, _ = geometry.project_points(rays_neg.reshape(-1, 3), neg)
    vv, uu = np.mgrid[0:30, 0:40]
    np.testing.assert_allclose(uv_back, np.stack([uu.ravel(), vv.ravel()], -1), rtol=0, atol=TOL.px)


def test_pixel_rays_are_read_only_and_cached():
    intr = Intrinsics(8, 6, 5.0, 5.0, 3.5, 2.5, Distortion(0.1, 0.0, 0.0, 0.0, 0.0))
    rays = geometry.pixel_rays(intr)
    assert not rays.flags.writeable
    with pytest.raises(ValueError):
        rays[0, 0, 0] = 5.0
    assert geometry.pixel_rays(Intrinsics(8, 6, 5.0, 5.0, 3.5, 2.5, Distortion(0.1, 0.0, 0.0, 0.0, 0.0))) is rays
    # A different camera gets different rays.
    other = geometry.pixel_rays(Intrinsics(8, 6, 6.0, 5.0, 3.5, 2.5, Distortion(0.1, 0.0, 0.0, 0.0, 0.0)))
    assert other is not rays and not np.allclose(other, rays)


# --------------------------------------------------------------------------------------------------
# Equirectangular solid angles and directions
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [(1000, 2000), (1, 2), (3, 6), (5, 10), (2, 4), (7, 3)])
def test_solid_angles_sum_to_4pi(size):
    omega = geometry.equirect_solid_angles(*size)
    assert omega.shape == size and omega.dtype == np.float64
    assert (omega > 0).all()
    assert math.fsum(omega.ravel()) == pytest.approx(4.0 * math.pi, rel=TOL.solid_angle_rel)


@pytest.mark.parametrize("size", [(1, 2), (3, 6), (7, 14), (64, 128)])
def test_solid_angle_rows_match_quadrature(size):
    h, w = size
    omega = geometry.equirect_solid_angles(h, w)
    for v in range(h):
        top, bottom = math.pi * v / h, math.pi * (v + 1) / h
        band, _ = integrate.quad(math.sin, top, bottom, epsabs=0, epsrel=1e-13)
        expected = band * 2.0 * math.pi / w
        np.testing.assert_allclose(omega[v], expected, rtol=TOL.solid_angle_rel, atol=0)


def test_solid_angles_are_symmetric_about_the_equator_and_read_only_cached():
    omega = geometry.equirect_solid_angles(9, 18)
    np.testing.assert_allclose(omega, omega[::-1], rtol=TOL.solid_angle_rel, atol=0)
    assert not omega.flags.writeable
    assert geometry.equirect_solid_angles(9, 18) is omega


def test_equirect_directions_are_unit_and_follow_design_formula():
    h, w = 8, 16
    d = geometry.equirect_directions(h, w)
    assert d.shape == (h, w, 3) and d.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d.astype(np.float64), axis=-1), 1.0, rtol=0, atol=TOL.unit_f32)
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    expected = _design_direction(np.pi * (vv + 0.5) / h, 2.0 * np.pi * (uu + 0.5) / w - np.pi)
    np.testing.assert_allclose(d, expected, rtol=0, atol=TOL.unit_f32)


def test_equirect_directions_hand_computed_2x4():
    d = geometry.equirect_directions(2, 4)
    s = math.sqrt(0.5)
    # Pixel (0, 0): θ = π/4, φ = −3π/4.  Pixel (1, 3): θ = 3π/4, φ = 3π/4.  Pixel (0, 2): θ = π/4, φ = π/4.
    np.testing.assert_allclose(d[0, 0], [-0.5, -0.5, s], rtol=0, atol=TOL.unit_f32)
    np.testing.assert_allclose(d[1, 3], [-0.5, 0.5, -s], rtol=0, atol=TOL.unit_f32)
    np.testing.assert_allclose(d[0, 2], [0.5, 0.5, s], rtol=0, atol=TOL.unit_f32)


def test_equirect_directions_row0_is_zenith_last_row_is_nadir():
    d = geometry.equirect_directions(64, 128)
    assert (d[0, :, 2] > 0.999).all()
    assert (d[-1, :, 2] < -0.999).all()
    # z decreases monotonically down the rows.
    assert (np.diff(d[:, 0, 2]) < 0).all()


def test_equirect_directions_are_read_only_and_cached():
    d = geometry.equirect_directions(4, 8)
    assert not d.flags.writeable
    with pytest.raises(ValueError):
        d[0, 0, 0] = 1.0
    assert geometry.equirect_directions(4, 8) is d


# --------------------------------------------------------------------------------------------------
# Direction ↔ (u, v) ↔ pixel index
# --------------------------------------------------------------------------------------------------

SIZES = [(1, 2), (2, 4), (8, 16), (90, 180), (1000, 2000)]


@settings(max_examples=300, deadline=None)
@given(
    xyz=st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3).filter(lambda t: np.linalg.norm(t) > 1e-3),
    scale=st.floats(1e-6, 1e6),
    size=st.sampled_from(SIZES),
)
def test_direction_round_trip_property(xyz, scale, size):
    h, w = size
    d = np.array(xyz) * scale
    uv = geometry.directions_to_equirect(d, h, w)
    assert uv.shape == (2,)
    assert -0.5 <= uv[0] < w - 0.5
    assert -0.5 <= uv[1] <= h - 0.5
    back = geometry.equirect_to_directions(uv, h, w)
    assert abs(np.linalg.norm(back) - 1.0) < TOL.unit_f32
    assert _angle_deg(back, d) < TOL.angle_deg


@settings(max_examples=300, deadline=None)
@given(
    xyz=st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3).filter(lambda t: np.linalg.norm(t) > 1e-3),
    size=st.sampled_from(SIZES),
)
def test_pixel_index_is_the_pixel_containing_the_direction(xyz, size):
    h, w = size
    d = np.array(xyz)
    rows, cols, valid = geometry.equirect_pixel_index(d, h, w)
    assert bool(valid)
    assert 0 <= rows < h and 0 <= cols < w
    # Independent spherical coordinates; the direction must lie inside the pixel (half a pixel from
    # its centre in θ and in wrapped φ, plus rounding slack).
    theta = math.atan2(math.hypot(d[0], d[1]), d[2])
    phi = math.atan2(d[1], d[0])
    slack = 1e-9
    assert abs(theta - math.pi * (rows + 0.5) / h) <= math.pi / (2 * h) + slack
    dphi = (phi - (2 * math.pi * (cols + 0.5) / w - math.pi) + math.pi) % (2 * math.pi) - math.pi
    assert abs(dphi) <= math.pi / w + slack


def test_round_trip_is_batched_over_leading_dimensions():
    rng = np.random.default_rng(5)
    d = rng.normal(size=(4, 5, 3))
    uv = geometry.directions_to_equirect(d, 32, 64)
    assert uv.shape == (4, 5, 2) and uv.dtype == np.float64
    back = geometry.equirect_to_directions(uv, 32, 64)
    assert back.shape == (4, 5, 3)
    assert (_angle_deg(back, d) < TOL.angle_deg).all()


@pytest.mark.parametrize("y", [1e-12, -1e-12, 0.0, -0.0, 1e-300])
def test_seam_round_trip(y):
    h, w = 8, 16
    d = np.array([-1.0, y, 0.0])
    uv = geometry.directions_to_equirect(d, h, w)
    assert -0.5 <= uv[0] < w - 0.5
    assert _angle_deg(geometry.equirect_to_directions(uv, h, w), d) < TOL.angle_deg


def test_seam_pixel_index_wraps_into_range():
    h, w = 8, 16
    # φ just below +π is the last column; φ just above −π is the first; φ = ±π exactly lands in [0, W).
    d = np.array([[-1.0, 1e-12, 0.0], [-1.0, -1e-12, 0.0], [-1.0, 0.0, 0.0], [-1.0, -0.0, 0.0]])
    rows, cols, valid = geometry.equirect_pixel_index(d, h, w)
    assert valid.all()
    assert cols[0] == w - 1
    assert cols[1] == 0
    assert 0 <= cols[2] < w and 0 <= cols[3] < w
    assert (rows == h // 2).all() or (rows == h // 2 - 1).all()  # on the equator (a row edge for even H)


def test_seam_columns_over_many_widths():
    for w in [2, 6, 16, 360, 2000]:
        # |φ ∓ π| ≤ 1e-5 is well inside the first / last column for every width here.
        d = np.array([[-1.0, s * 10.0**-e, 0.0] for s in (1, -1) for e in range(5, 17)])
        _, cols, valid = geometry.equirect_pixel_index(d, w // 2, w)
        assert valid.all()
        assert ((cols >= 0) & (cols < w)).all()
        assert (cols[d[:, 1] < 0] == 0).all()
        # Below ~1e-16 the azimuth rounds to exactly ±π, which may land in either seam column.
        near = (d[:, 1] > 0) & (d[:, 1] > 1e-15)
        assert (cols[near] == w - 1).all()


def test_exact_poles():
    h, w = 8, 16
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 7.0], [0.0, 0.0, -0.1]])
    uv = geometry.directions_to_equirect(d, h, w)
    np.testing.assert_allclose(uv[:, 1], [-0.5, h - 0.5, -0.5, h - 0.5], rtol=0, atol=TOL.px)
    back = geometry.equirect_to_directions(uv, h, w)
    np.testing.assert_allclose(back, d / np.linalg.norm(d, axis=-1, keepdims=True), rtol=0, atol=TOL.rot)
    rows, cols, valid = geometry.equirect_pixel_index(d, h, w)
    assert valid.all()
    assert rows.tolist() == [0, h - 1, 0, h - 1]  # the pole row, clamped at the bottom
    assert ((cols >= 0) & (cols < w)).all()


@pytest.mark.parametrize("eps", [1e-15, 1e-9, 1e-6, 1e-3])
def test_near_poles(eps):
    h, w = 90, 180
    d = np.array([[eps, 0.0, 1.0], [0.0, -eps, 1.0], [-eps, eps, -1.0], [eps, eps, -1.0]])
    uv = geometry.directions_to_equirect(d, h, w)
    assert (_angle_deg(geometry.equirect_to_directions(uv, h, w), d) < TOL.angle_deg).all()
    rows, _, valid = geometry.equirect_pixel_index(d, h, w)
    assert valid.all()
    assert rows.tolist() == [0, 0, h - 1, h - 1]


def test_every_pixel_centre_maps_back_to_its_own_index():
    h, w = 8, 16
    vv, uu = np.mgrid[0:h, 0:w]
    # From the library's grid (float32) ...
    rows, cols, valid = geometry.equirect_pixel_index(geometry.equirect_directions(h, w), h, w)
    assert valid.all()
    np.testing.assert_array_equal(rows, vv)
    np.testing.assert_array_equal(cols, uu)
    # ... and from directions computed here from the conventions' formula (docs/reference/conventions.md).
    d = _design_direction(np.pi * (vv + 0.5) / h, 2.0 * np.pi * (uu + 0.5) / w - np.pi)
    uv = geometry.directions_to_equirect(d, h, w)
    np.testing.assert_allclose(uv[..., 0], uu, rtol=0, atol=1e-9)
    np.testing.assert_allclose(uv[..., 1], vv, rtol=0, atol=1e-9)
    rows, cols, _ = geometry.equirect_pixel_index(d, h, w)
    np.testing.assert_array_equal(rows, vv)
    np.testing.assert_array_equal(cols, uu)


def test_equirect_to_directions_of_integer_grid_is_the_direction_grid():
    h, w = 6, 12
    vv, uu = np.mgrid[0:h, 0:w]
    d = geometry.equirect_to_directions(np.stack([uu, vv], axis=-1), h, w)  # ints accepted
    assert d.shape == (h, w, 3) and d.dtype == np.float64
    np.testing.assert_allclose(d, geometry.equirect_directions(h, w), rtol=0, atol=TOL.unit_f32)


def test_zero_and_nan_directions_are_invalid():
    h, w = 8, 16
    d = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 1.0], [0.0, np.nan, 0.0], [1.0, 0.0, 0.0]])
    uv = geometry.directions_to_equirect(d, h, w)
    assert np.isnan(uv[:3]).all()
    assert np.isfinite(uv[3]).all()
    rows, cols, valid = geometry.equirect_pixel_index(d, h, w)
    assert valid.tolist() == [False, False, False, True]
    assert rows.dtype == np.int64 and cols.dtype == np.int64
    assert rows[:3].tolist() == [0, 0, 0] and cols[:3].tolist() == [0, 0, 0]


def test_infinite_directions_are_invalid():
    """The docstrings of directions_to_equirect ("zero or non-finite directions give NaN") and
    equirect_pixel_index ("valid is False for zero or non-finite directions") promise this."""
    h, w = 8, 16
    d = np.array([[np.inf, 0.0, 0.0], [0.0, -np.inf, 0.0], [np.inf, np.inf, 0.0], [0.0, 0.0, np.inf]])
    uv = geometry.directions_to_equirect(d, h, w)
    assert np.isnan(uv).all(), f"non-finite directions gave (u, v) = {uv.tolist()}"
    _, _, valid = geometry.equirect_pixel_index(d, h, w)
    assert not valid.any(), f"non-finite directions marked valid: {valid.tolist()}"


@pytest.mark.parametrize("scale", [1e-170, 1e170])
def test_direction_length_does_not_matter_at_extreme_scales(scale):
    """directions_to_equirect accepts "any non-zero length"; a length whose square under- or
    overflows float64 must still map like the unit vector."""
    h, w = 8, 16
    unit = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    expected = geometry.directions_to_equirect(unit, h, w)
    with np.errstate(over="ignore", under="ignore"):
        got = geometry.directions_to_equirect(unit * scale, h, w)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)


# --------------------------------------------------------------------------------------------------
# look_at and the OpenGL axis flip
# --------------------------------------------------------------------------------------------------


def test_look_at_along_plus_x_is_the_hand_derived_rotation():
    # Right-handed, z up, looking along +x: world −y is to the right, world −z is image down.
    T = geometry.look_at(np.array([0.0, 0.0, 0.0]), np.array([5.0, 0.0, 0.0]))
    expected = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns: x, y, z axes
    np.testing.assert_allclose(T.rotation, expected, rtol=0, atol=TOL.rot)
    assert (T.dst, T.src) == ("world", "cam")


@pytest.mark.parametrize("seed", range(5))
def test_look_at_axes(seed):
    rng = np.random.default_rng(seed)
    eye = rng.uniform(-3, 3, 3)
    target = eye + np.append(rng.uniform(-3, 3, 2), rng.uniform(-1, 1))
    T = geometry.look_at(eye, target)
    R = T.rotation
    forward = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(R[:, 2], forward, rtol=0, atol=TOL.rot)  # camera z points at target
    assert abs(R[2, 0]) < TOL.rot  # camera x is horizontal
    assert R[2, 1] < 0  # camera y (image down) points down in the world
    np.testing.assert_allclose(R.T @ R, np.eye(3), rtol=0, atol=TOL.rot)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=TOL.rot)
    np.testing.assert_allclose(T.translation, eye, rtol=0, atol=TOL.rot)
    # The target sits on the optical axis; a point above it is in the upper half of the image.
    p_cam = T.inverse().apply(np.stack([target, target + [0.0, 0.0, 0.5]]))
    np.testing.assert_allclose(p_cam[0], [0.0, 0.0, np.linalg.norm(target - eye)], rtol=0, atol=1e-9)
    assert p_cam[1, 1] < 0


@pytest.mark.parametrize("target", [[0.0, 0.0, 3.0], [0.0, 0.0, -2.0]], ids=["up", "down"])
def test_look_at_parallel_to_up_raises(target):
    with pytest.raises(InvalidInputError):
        geometry.look_at(np.zeros(3), np.array(target))


def test_look_at_eye_equal_target_raises():
    with pytest.raises(InvalidInputError):
        geometry.look_at(np.ones(3), np.ones(3))


def test_look_at_bad_input():
    with pytest.raises(ShapeError):
        geometry.look_at(np.zeros(2), np.ones(3))
    with pytest.raises(NonFiniteError):
        geometry.look_at(np.array([np.nan, 0.0, 0.0]), np.ones(3))


def test_opengl_from_opencv_flips_y_and_z():
    T = geometry.look_at(np.array([1.0, 2.0, 1.5]), np.array([-2.0, 4.0, 0.5]))
    G = geometry.opengl_from_opencv(T)
    np.testing.assert_allclose(G.matrix[:, 0], T.matrix[:, 0], rtol=0, atol=TOL.rot)
    np.testing.assert_allclose(G.matrix[:, 1], -T.matrix[:, 1], rtol=0, atol=TOL.rot)
    np.testing.assert_allclose(G.matrix[:, 2], -T.matrix[:, 2], rtol=0, atol=TOL.rot)
    np.testing.assert_allclose(G.matrix[:, 3], T.matrix[:, 3], rtol=0, atol=TOL.rot)
    assert G.rotation[2, 1] > 0  # OpenGL y is up in the image, so up in the world
    assert G.dst == T.dst
    assert G.src != T.src  # a different frame: the OpenGL camera


# --------------------------------------------------------------------------------------------------
# Hard cases: bad shapes, bad sizes
# --------------------------------------------------------------------------------------------------

INTR = Intrinsics(8, 6, 5.0, 5.0, 3.5, 2.5)

BAD_SHAPE_CALLS = {
    "project_points_1d": lambda: geometry.project_points(np.zeros(3), INTR),
    "project_points_xy_only": lambda: geometry.project_points(np.zeros((4, 2)), INTR),
    "project_points_batched": lambda: geometry.project_points(np.zeros((2, 4, 3)), INTR),
    "unproject_uv_3cols": lambda: geometry.unproject_pixels(np.zeros((4, 3)), np.ones(4), INTR),
    "unproject_depth_length": lambda: geometry.unproject_pixels(np.zeros((4, 2)), np.ones(5), INTR),
    "unproject_depth_2d": lambda: geometry.unproject_pixels(np.zeros((4, 2)), np.ones((4, 1)), INTR),
    "directions_to_equirect_2vec": lambda: geometry.directions_to_equirect(np.ones((5, 2)), 4, 8),
    "directions_to_equirect_scalar": lambda: geometry.directions_to_equirect(np.float64(1.0), 4, 8),
    "equirect_to_directions_3vec": lambda: geometry.equirect_to_directions(np.ones((5, 3)), 4, 8),
    "equirect_pixel_index_4vec": lambda: geometry.equirect_pixel_index(np.ones((5, 4)), 4, 8),
}


@pytest.mark.parametrize("call", list(BAD_SHAPE_CALLS))
def test_wrong_shapes_raise_shape_error(call):
    with pytest.raises(ShapeError) as info:
        BAD_SHAPE_CALLS[call]()
    assert isinstance(info.value, ValueError)
    assert isinstance(info.value, RgbdEnvmapError)


SIZE_FUNCS = {
    "equirect_directions": lambda h, w: geometry.equirect_directions(h, w),
    "equirect_solid_angles": lambda h, w: geometry.equirect_solid_angles(h, w),
    "directions_to_equirect": lambda h, w: geometry.directions_to_equirect(np.array([1.0, 0.0, 0.0]), h, w),
    "equirect_to_directions": lambda h, w: geometry.equirect_to_directions(np.array([0.0, 0.0]), h, w),
    "equirect_pixel_index": lambda h, w: geometry.equirect_pixel_index(np.array([1.0, 0.0, 0.0]), h, w),
}


@pytest.mark.parametrize("func", list(SIZE_FUNCS))
@pytest.mark.parametrize("size", [(0, 0), (0, 8), (4, 0), (-4, 8), (4, -8)])
def test_non_positive_sizes_raise_range_error(func, size):
    with pytest.raises(RangeError) as info:
        SIZE_FUNCS[func](*size)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("func", list(SIZE_FUNCS))
@pytest.mark.parametrize("size", [(4.0, 8), (4, 8.5), (True, 2), ("4", 8)])
def test_non_integer_sizes_raise_project_errors(func, size):
    with pytest.raises(RgbdEnvmapError) as info:
        SIZE_FUNCS[func](*size)
    assert isinstance(info.value, DTypeError)


def test_non_numeric_points_raise_dtype_error():
    with pytest.raises(DTypeError):
        geometry.project_points(np.array([["a", "b", "c"]]), INTR)


def test_inputs_are_not_mutated():
    p = np.array([[0.1, 0.2, 1.0], [0.0, 0.0, -1.0]])
    p_copy = p.copy()
    geometry.project_points(p, _intrinsics(Distortion(K1, K2, P1, P2, K3)))
    np.testing.assert_array_equal(p, p_copy)
    xy = np.array([[0.2, 0.1]])
    geometry.undistort_normalized(xy, Distortion(K1, K2, P1, P2, K3))
    np.testing.assert_array_equal(xy, [[0.2, 0.1]])
    d = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    geometry.directions_to_equirect(d, 4, 8)
    np.testing.assert_array_equal(d, [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])


def test_rigid_transform_from_look_at_is_a_rigid_transform():
    assert isinstance(geometry.look_at(np.zeros(3), np.ones(3)), RigidTransform)
