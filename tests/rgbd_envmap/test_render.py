"""Tests for rgbd_envmap.render: offscreen rasterisation (pyrender and numba backends) and compositing.

References are independent of the code under test:

* pixel coverage: a camera-facing rectangle whose edges project (via ``geometry.project_points``) to
  known non-integer columns / rows covers exactly the pixels whose integer centres lie inside (OpenCV
  convention, so the pyrender half-pixel shift is checked exactly); a sphere's silhouette from an
  analytic ray–sphere test; projected vertices via ``geometry.project_points``;
* interpolation: an affine function of the world position, sampled at the vertices of a slanted planar
  quad, must come back at every pixel as that function at the ray–plane intersection (perspective-
  correct Gouraud; screen-space-linear interpolation would be off by percents here);
* clipping: a huge two-triangle floor through and behind the camera covers exactly the rows below the
  horizon up to the far plane (ray–plane intersection);
* the numba rasteriser against rgbd_envmap.reference.render_raster (the z-buffer written out
  triangle by triangle, clipping included), bit for bit;
* compositing: the sRGB encoding in float64 (round half up of 255 · srgb(x)), linear blending written
  out per pixel, ``colour.apply_ccm`` for the colour correction, and the whole composite with numpy
  (all in rgbd_envmap.reference.render_composite), bit for bit.

Tolerances:
    coverage of the rectangle: exact (edges 0.2–0.4 px from any pixel centre).
    sphere silhouette: disagreements only within 1 px of the analytic boundary (icosphere is inscribed).
    uniform colour: 1e-5 relative (llvmpipe's float32 perspective interpolation returns a constant c as
        c·(1 ± 3e-6); the numba backend is within 1e-7; an 8-bit code is ≥ 4e-3 relative).
    affine interpolation: 2e-4 absolute on values O(1) (float32 attributes, vertex snapping 1/256 px).
    backends against each other: masks differ on ≤ 0.2 % of the union, smooth colours ≤ 2e-3.
    floor clipping: rows within 1 of the analytic far-plane row (24-bit depth, snapping).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from rgbd_envmap import colour, geometry, render
from rgbd_envmap.errors import (
    DTypeError,
    InvalidInputError,
    NonFiniteError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
    UnknownMethodError,
)
from rgbd_envmap.reference import render_composite as composite_ref
from rgbd_envmap.reference import render_raster as raster_ref
from rgbd_envmap.types import Intrinsics, RigidTransform

EGL_OK, EGL_REASON = render.egl_available()
needs_egl = pytest.mark.skipif(not EGL_OK, reason=f"pyrender backend needs an EGL/OpenGL context: {EGL_REASON}")
BACKENDS = [pytest.param("numba", id="numba"), pytest.param("pyrender", id="pyrender", marks=needs_egl)]

#: A deliberately asymmetric camera: fx ≠ fy, principal point off-centre and not on a half pixel.
INTR = Intrinsics(320, 240, 310.0, 290.0, 150.3, 125.7)
NO_FACES = np.zeros((0, 3), np.int64)
NO_VERTS = np.zeros((0, 3))


@pytest.fixture(scope="module")
def renderers():
    """One renderer per backend, reused across the module (a GL context is not free)."""
    made = {}

    def get(backend, intr=INTR):
        key = (backend, intr)
        if key not in made:
            made[key] = render.Renderer(intr, backend=backend)
        return made[key]

    yield get
    for r in made.values():
        r.close()


def draw(r, T, ov=NO_VERTS, of=NO_FACES, oc=None, pv=NO_VERTS, pf=NO_FACES, pa=None):
    oc = np.zeros((len(ov), 3)) if oc is None else oc
    pa = np.zeros(len(pv)) if pa is None else pa
    return r.render(T, ov, of, oc, pv, pf, pa)


def rect_at_depth(intr, u0, u1, v0, v1, z):
    """Camera-frame rectangle (4 vertices, 2 faces) at depth z spanning columns u0..u1, rows v0..v1."""
    x = [(u - intr.cx) * z / intr.fx for u in (u0, u1)]
    y = [(v - intr.cy) * z / intr.fy for v in (v0, v1)]
    verts = np.array([[x[0], y[0], z], [x[1], y[0], z], [x[1], y[1], z], [x[0], y[1], z]])
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


def sphere_scene(subdivisions=4):
    """An icosphere (r = 6 cm) standing on a 0.5 m shadow-plane grid, seen from about 0.9 m."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.06)
    centre = np.array([0.0, 0.0, 0.81])
    ov = np.asarray(m.vertices) + centre
    of = np.asarray(m.faces)
    n = 32
    g = np.stack(np.meshgrid(np.linspace(-0.25, 0.25, n), np.linspace(-0.25, 0.25, n)), -1).reshape(-1, 2)
    pv = np.c_[g, np.full(len(g), 0.75)]
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    pf = np.r_[np.c_[a, b, d], np.c_[a, d, c]]
    pa = np.clip(1.0 - np.linalg.norm(g, axis=1) / 0.25, 0.0, 1.0)
    T = geometry.look_at(np.array([0.6, -0.35, 1.25]), centre)
    return T, centre, ov, of, pv, pf, pa


def smooth_colours(ov):
    return (0.4 + 2.0 * (ov - ov.mean(0))).clip(0.0, None) * np.array([1.0, 0.8, 1.5])


# ------------------------------------------------------------------------------------------------
# Coverage and the pixel-centre convention
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_rectangle_covers_exactly_the_pixel_centres_inside(renderers, backend):
    r = renderers(backend)
    u0, u1, v0, v1 = 40.3, 201.7, 30.6, 150.2
    verts, faces = rect_at_depth(INTR, u0, u1, v0, v1, 2.0)
    # the rectangle's corners project where we built them (ties this test to geometry.project_points)
    uv, front = geometry.project_points(verts, INTR)
    assert front.all()
    np.testing.assert_allclose(uv[[0, 2]], [[u0, v0], [u1, v1]], atol=1e-9)
    layer = draw(r, np.eye(4), verts, faces, np.full((4, 3), 0.5))
    expected = np.zeros(INTR.shape, bool)
    expected[31:151, 41:202] = True  # integer centres strictly inside [u0, u1] × [v0, v1]
    np.testing.assert_array_equal(layer.mask, expected)
    assert layer.plane_alpha.max() == 0.0
    r0, r1, c0, c1 = layer.bbox
    assert layer.mask[r0:r1, c0:c1].sum() == layer.mask.sum()


@pytest.mark.parametrize("backend", BACKENDS)
def test_sphere_mask_matches_the_analytic_silhouette(renderers, backend):
    T, centre, ov, of, *_ = sphere_scene(subdivisions=4)
    layer = draw(renderers(backend), T, ov, of, np.ones_like(ov))
    rays = geometry.pixel_rays(INTR)  # camera frame, z = 1
    c_cam = T.inverse().apply(centre)
    d = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    dist = np.linalg.norm(np.cross(d, c_cam), axis=-1)  # distance from the sphere centre to each ray
    analytic = dist < 0.06
    band = ndimage.binary_dilation(analytic) & ~ndimage.binary_erosion(analytic)
    assert layer.mask.sum() > 1000
    assert not ((layer.mask != analytic) & ~band).any()
    # every projected vertex on the near side lies within 1 px of a covered pixel centre
    uv, _ = geometry.project_points(T.inverse().apply(ov), INTR)
    near_side = np.linalg.norm(T.inverse().apply(ov), axis=1) < np.linalg.norm(c_cam)
    rows, cols = np.nonzero(layer.mask)
    assert uv[near_side, 0].min() > cols.min() - 1 and uv[near_side, 0].max() < cols.max() + 1
    assert uv[near_side, 1].min() > rows.min() - 1 and uv[near_side, 1].max() < rows.max() + 1


# ------------------------------------------------------------------------------------------------
# Colours and interpolation
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("rgb", [(0.2, 0.5, 0.8), (2.5, 0.01, 7.0)], ids=["ldr", "hdr"])
def test_uniform_colour_renders_exactly_without_lighting(renderers, backend, rgb):
    T, _, ov, of, *_ = sphere_scene(subdivisions=3)
    layer = draw(renderers(backend), T, ov, of, np.tile(rgb, (len(ov), 1)))
    assert layer.colour.dtype == np.float32
    np.testing.assert_allclose(layer.colour[layer.mask], np.broadcast_to(rgb, (layer.mask.sum(), 3)), rtol=1e-5)
    assert (layer.colour[~layer.mask] == 0).all()


@pytest.mark.parametrize("backend", BACKENDS)
def test_gouraud_interpolation_is_perspective_correct(renderers, backend):
    # A slanted quad from 0.6 m to 3 m deep; colour and alpha are affine in the world position, so the
    # exact Gouraud result at a pixel is that function at the ray's hit point.
    quad = np.array([[-0.5, -0.4, 0.6], [0.5, -0.4, 0.6], [2.0, 1.5, 3.0], [-2.0, 1.5, 3.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    a, B = np.array([0.3, 0.6, 0.1]), np.array([[0.2, 0.0, 0.1], [0.0, -0.2, 0.05], [0.1, 0.1, 0.2]])

    def f(p):
        return a + p @ B.T

    T = np.eye(4)
    layer = draw(renderers(backend), T, quad, faces, f(quad))
    rays = geometry.pixel_rays(INTR)
    normal = np.cross(quad[1] - quad[0], quad[3] - quad[0])
    t = (quad[0] @ normal) / (rays @ normal)
    hits = rays * t[..., None]
    assert layer.mask.sum() > 5000
    np.testing.assert_allclose(layer.colour[layer.mask], f(hits[layer.mask]), atol=2e-4)
    # the same as the shadow plane's alpha
    alpha_fn = lambda p: 0.1 + 0.1 * p[..., 0] + 0.2 * p[..., 2]  # in [0, 1] on the quad
    layer = draw(renderers(backend), T, pv=quad, pf=faces, pa=alpha_fn(quad))
    visible = layer.plane_alpha > 0
    assert visible.sum() > 5000 and not layer.mask.any()
    np.testing.assert_allclose(layer.plane_alpha[visible], alpha_fn(hits[visible]), atol=2e-4)


# ------------------------------------------------------------------------------------------------
# Depth order, clipping, empty results
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_object_hides_the_plane_behind_it_and_not_in_front(renderers, backend):
    r = renderers(backend)
    obj, of = rect_at_depth(INTR, 100.25, 180.25, 80.4, 160.4, 1.0)
    plane, pf = rect_at_depth(INTR, 20.3, 300.3, 20.6, 220.6, 2.0)
    layer = draw(r, np.eye(4), obj, of, np.full((4, 3), 0.7), plane, pf, np.full(4, 0.6))
    assert layer.mask[81:161, 101:181].all() and layer.mask.sum() == 80 * 80
    assert (layer.plane_alpha[layer.mask] == 0).all()
    plane_px = np.zeros(INTR.shape, bool)
    plane_px[21:221, 21:301] = True
    np.testing.assert_allclose(layer.plane_alpha[plane_px & ~layer.mask], 0.6, rtol=1e-5)
    assert (layer.plane_alpha[~plane_px] == 0).all()
    # the plane in front of the object hides it
    plane_front, _ = rect_at_depth(INTR, 20.3, 300.3, 20.6, 220.6, 0.5)
    layer = draw(r, np.eye(4), obj, of, np.full((4, 3), 0.7), plane_front, pf, np.full(4, 0.6))
    assert not layer.mask.any()
    np.testing.assert_allclose(layer.plane_alpha[plane_px], 0.6, rtol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_floor_through_and_behind_the_camera_is_clipped_at_near_and_far(renderers, backend):
    # Two triangles, 100 m across, 0.5 m below an identity camera (y down): half of each triangle is
    # behind the camera. Covered: rows whose ray meets the floor at 0.05 ≤ z ≤ 20 (the far plane).
    r = renderers(backend)
    floor = np.array([[-50, 0.5, -50], [50, 0.5, -50], [50, 0.5, 50], [-50, 0.5, 50]], float)
    layer = draw(r, np.eye(4), pv=floor, pf=np.array([[0, 1, 2], [0, 2, 3]]), pa=np.ones(4))
    covered = layer.plane_alpha > 0
    v_far = INTR.cy + INTR.fy * 0.5 / r.far_m  # row of the far-plane line on the floor
    rows = np.arange(INTR.height)
    full_rows = covered.all(axis=1)
    empty_rows = ~covered.any(axis=1)
    assert (full_rows | empty_rows).all()  # every row is all-or-nothing
    assert full_rows[rows > v_far + 1].all() and empty_rows[rows < v_far - 1].all()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("where", ["behind", "beside", "beyond_far"])
def test_geometry_out_of_view_gives_an_empty_layer(renderers, backend, where):
    T, centre, ov, of, pv, pf, pa = sphere_scene(subdivisions=2)
    cam = T.inverse()
    shift = {"behind": [0.0, 0.0, -3.0], "beside": [5.0, 0.0, 1.0], "beyond_far": [0.0, 0.0, 30.0]}[where]
    move = T.rotate(np.array(shift)) - T.rotate(cam.apply(centre)) * (where == "behind")
    layer = draw(renderers(backend), T, ov + move, of, np.ones_like(ov), pv + move, pf, pa)
    assert layer.is_empty
    assert not layer.mask.any() and layer.plane_alpha.max() == 0 and layer.colour.max() == 0
    assert layer.shape == INTR.shape


@pytest.mark.parametrize("backend", BACKENDS)
def test_empty_meshes_are_allowed(renderers, backend):
    layer = draw(renderers(backend), np.eye(4))
    assert layer.bbox is None and layer.is_empty


def _reference_scenes():
    T, centre, ov, of, pv, pf, pa = sphere_scene(subdivisions=2)
    oc = smooth_colours(ov)
    yield "sphere", T, ov, of, oc, pv, pf, pa
    close = geometry.look_at(np.array([0.05, -0.04, 0.80]), centre)  # the camera inside the plane's span
    yield "close", close, ov, of, oc, pv, pf, pa
    inside = geometry.look_at(centre + np.array([0.02, 0.0, 0.0]), centre + np.array([1.0, 0.2, 0.1]))
    yield "inside the sphere", inside, ov, of, oc, pv, pf, pa  # every face crosses or is behind near
    floor = np.array([[-50, 0.5, -50], [50, 0.5, -50], [50, 0.5, 50], [-50, 0.5, 50]], float)
    obj, obj_f = rect_at_depth(INTR, 100.25, 180.25, 80.4, 160.4, 1.0)
    yield ("floor", np.eye(4), obj, obj_f, np.array([[0.2, 0.4, 0.6], [1.5, 0.1, 0.0], [0.3, 0.3, 0.3], [0.0, 0.9, 2.0]]),
           floor, np.array([[0, 1, 2], [0, 2, 3]]), np.array([0.1, 0.5, 1.0, 0.7]))
    plane_front, plane_f = rect_at_depth(INTR, 20.3, 300.3, 20.6, 220.6, 0.7)
    yield "plane in front", np.eye(4), obj, obj_f, np.full((4, 3), 0.7), plane_front, plane_f, np.full(4, 0.6)
    # corners on pixel centres: the edges, and the shared diagonal, run through pixel centres (tie rule)
    aligned, aligned_f = rect_at_depth(INTR, 100.0, 180.0, 80.0, 160.0, 1.0)
    back, back_f = rect_at_depth(INTR, 60.0, 220.0, 40.0, 200.0, 1.5)
    yield ("pixel-aligned", np.eye(4), aligned, aligned_f, np.array([[0.1, 0.2, 0.3], [0.9, 0.1, 0.4], [0.5, 0.8, 0.2],
                                                                     [0.3, 0.3, 0.9]]),
           back, back_f, np.array([0.2, 0.9, 0.4, 0.6]))


@pytest.mark.parametrize("crop", [True, False])
def test_numba_rasteriser_matches_the_reference_bit_for_bit(crop):
    with render.Renderer(INTR, backend="numba", crop=crop) as r:
        for name, T, ov, of, oc, pv, pf, pa in _reference_scenes():
            layer = draw(r, T, ov, of, oc, pv, pf, pa)
            pose = T if isinstance(T, RigidTransform) else RigidTransform(np.asarray(T, float), "world", "cam")
            colour, mask, alpha = raster_ref.rasterise(pose, INTR, r.near_m, r.far_m, ov, of, oc, pv, pf, pa)
            assert mask.any() or alpha.any(), name
            np.testing.assert_array_equal(layer.mask, mask, err_msg=name)
            np.testing.assert_array_equal(layer.colour, colour, err_msg=name)
            np.testing.assert_array_equal(layer.plane_alpha, alpha, err_msg=name)


# ------------------------------------------------------------------------------------------------
# The two backends against each other; per-frame updates
# ------------------------------------------------------------------------------------------------


@needs_egl
def test_backends_agree_on_the_sphere_and_shadow_plane(renderers):
    T, _, ov, of, pv, pf, pa = sphere_scene(subdivisions=5)
    oc = smooth_colours(ov)
    a = draw(renderers("numba"), T, ov, of, oc, pv, pf, pa)
    b = draw(renderers("pyrender"), T, ov, of, oc, pv, pf, pa)
    assert a.bbox == b.bbox
    r0, r1, c0, c1 = a.bbox
    for layer in (a, b):  # nothing outside the bbox
        assert layer.mask[r0:r1, c0:c1].sum() == layer.mask.sum() > 0
        assert np.count_nonzero(layer.plane_alpha[r0:r1, c0:c1]) == np.count_nonzero(layer.plane_alpha) > 0
    union = (a.mask | b.mask).sum()
    assert (a.mask != b.mask).sum() <= max(2, 0.002 * union)
    pa_vis, pb_vis = a.plane_alpha > 0, b.plane_alpha > 0
    assert (pa_vis != pb_vis).sum() <= max(2, 0.002 * (pa_vis | pb_vis).sum())
    both = a.mask & b.mask
    np.testing.assert_allclose(a.colour[both], b.colour[both], atol=2e-3)
    both = pa_vis & pb_vis
    np.testing.assert_allclose(a.plane_alpha[both], b.plane_alpha[both], atol=1e-3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_per_frame_updates_of_colours_positions_and_faces(renderers, backend):
    r = renderers(backend)
    T, _, ov, of, pv, pf, pa = sphere_scene(subdivisions=3)
    first = draw(r, T, ov, of, np.full_like(ov, 0.25), pv, pf, pa)
    second = draw(r, T, ov, of, np.full_like(ov, 0.75), pv, pf, pa * 0.5)
    np.testing.assert_array_equal(first.mask, second.mask)
    np.testing.assert_allclose(second.colour[second.mask], 0.75, rtol=1e-5)
    vis = first.plane_alpha > 0
    np.testing.assert_allclose(second.plane_alpha[vis], 0.5 * first.plane_alpha[vis], rtol=1e-5, atol=1e-7)
    # move the object 5 cm along the camera's x axis: the mask moves right by about fx · 0.05 / depth
    moved = draw(r, T, ov + T.rotate(np.array([0.05, 0.0, 0.0])), of, np.full_like(ov, 0.75), pv, pf, pa)
    assert np.nonzero(moved.mask)[1].mean() > np.nonzero(second.mask)[1].mean() + 10
    # a different mesh (other faces and vertex count)
    _, _, ov2, of2, *_ = sphere_scene(subdivisions=2)
    other = draw(r, T, ov2, of2, np.full_like(ov2, 0.5), pv, pf, pa)
    assert abs(int(other.mask.sum()) - int(second.mask.sum())) < 0.05 * second.mask.sum()
    np.testing.assert_allclose(other.colour[other.mask], 0.5, rtol=1e-5)


@needs_egl
def test_closing_one_pyrender_renderer_leaves_another_working():
    T, _, ov, of, pv, pf, pa = sphere_scene(subdivisions=2)
    a = render.Renderer(INTR, backend="pyrender")
    with render.Renderer(INTR, backend="pyrender") as b:
        draw(b, T, ov, of, np.ones_like(ov), pv, pf, pa)
    assert b.closed
    layer = draw(a, T, ov, of, np.ones_like(ov), pv, pf, pa)
    assert layer.mask.sum() > 100
    a.close()
    a.close()  # idempotent
    with pytest.raises(render.RendererUnavailableError, match="closed"):
        draw(a, T, ov, of, np.ones_like(ov))


# ------------------------------------------------------------------------------------------------
# Bad input
# ------------------------------------------------------------------------------------------------


def test_constructor_rejects_bad_arguments():
    with pytest.raises(UnknownMethodError, match="backend"):
        render.Renderer(INTR, backend="vulkan")
    with pytest.raises(RangeError, match="near_m"):
        render.Renderer(INTR, near_m=2.0, far_m=1.0, backend="numba")
    with pytest.raises(RangeError, match="near_m"):
        render.Renderer(INTR, near_m=0.0, backend="numba")
    with pytest.raises(NonFiniteError):
        render.Renderer(INTR, far_m=np.inf, backend="numba")
    with pytest.raises(DTypeError, match="intrinsics"):
        render.Renderer((320, 240), backend="numba")


@pytest.mark.parametrize(
    "change, error, match",
    [
        (dict(ov=np.zeros((4, 2))), ShapeError, "object_vertices_world"),
        (dict(ov=np.full((4, 3), np.nan)), NonFiniteError, "object_vertices_world"),
        (dict(of=np.array([[0, 1, 4]])), RangeError, "object_faces"),
        (dict(of=np.array([[0.0, 1.0, 2.0]])), DTypeError, "object_faces"),
        (dict(oc=np.ones((3, 3))), ShapeError, "object_colours"),
        (dict(oc=np.array([[np.nan, 0, 0]] * 4)), NonFiniteError, "object_colours"),
        (dict(pa=np.array([0.0, 0.5, 1.5, 0.0])), RangeError, "plane_alpha"),
        (dict(pa=np.array([0.0, np.nan, 0.0, 0.0])), NonFiniteError, "plane_alpha"),
        (dict(pa=np.zeros(3)), ShapeError, "plane_alpha"),
        (dict(pf=np.array([[0, 1, -1]])), RangeError, "plane_faces"),
        (dict(T=np.full((4, 4), np.nan)), NonFiniteError, "T_world_from_cam"),
        (dict(T=np.eye(3)), ShapeError, "T_world_from_cam"),
        (dict(T=np.diag([2.0, 1.0, 1.0, 1.0])), InvalidInputError, "orthonormal"),
    ],
)
def test_render_rejects_bad_inputs(renderers, change, error, match):
    verts, faces = rect_at_depth(INTR, 10.3, 50.3, 10.3, 50.3, 1.0)
    args = dict(T=np.eye(4), ov=verts, of=faces, oc=np.ones((4, 3)), pv=verts, pf=faces, pa=np.zeros(4))
    args.update(change)
    with pytest.raises(error, match=match):
        draw(renderers("numba"), **args)


def test_plane_alpha_rounding_slack_is_clipped(renderers):
    verts, faces = rect_at_depth(INTR, 10.3, 50.3, 10.3, 50.3, 1.0)
    layer = draw(renderers("numba"), np.eye(4), pv=verts, pf=faces, pa=np.array([1 + 1e-7, 1.0, 1.0, 1 + 1e-7]))
    assert layer.plane_alpha.max() == 1.0
    layer = draw(renderers("numba"), np.eye(4), pv=verts, pf=faces, pa=np.array([-1e-7, 0.0, 0.0, -1e-7]))
    assert layer.plane_alpha.min() == 0.0


def test_layer_validates_and_is_read_only():
    layer = render.Layer.empty(4, 6)
    assert layer.is_empty and layer.shape == (4, 6)
    with pytest.raises(ValueError):
        layer.mask[0, 0] = True
    with pytest.raises(ShapeError):
        render.Layer(np.zeros((4, 6, 3), np.float32), np.zeros((4, 5), bool), np.zeros((4, 6), np.float32), None)
    with pytest.raises(DTypeError):
        render.Layer(np.zeros((4, 6, 3)), np.zeros((4, 6), bool), np.zeros((4, 6), np.float32), None)
    with pytest.raises(InvalidInputError, match="bbox"):
        render.Layer(np.zeros((4, 6, 3), np.float32), np.zeros((4, 6), bool), np.zeros((4, 6), np.float32),
                     (0, 5, 0, 6))


# ------------------------------------------------------------------------------------------------
# Compositing
# ------------------------------------------------------------------------------------------------


encode_ref = composite_ref.encode_srgb8
decode_ref = composite_ref.decode_srgb8


def make_layer(h=40, w=60, seed=0):
    """Object in the left half (random HDR-ish colours), plane with random alpha in the right half."""
    rng = np.random.default_rng(seed)
    col = np.zeros((h, w, 3), np.float32)
    mask = np.zeros((h, w), bool)
    alpha = np.zeros((h, w), np.float32)
    mask[5:35, 5:28] = True
    col[mask] = rng.uniform(0.0, 1.2, (mask.sum(), 3))
    alpha[5:35, 30:55] = rng.uniform(0.0, 1.0, (30, 25))
    return render.Layer(col, mask, alpha, (5, 35, 5, 55))


def random_frame(h=40, w=60, seed=1):
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def test_encoder_matches_the_float64_reference():
    rng = np.random.default_rng(3)
    x = np.r_[rng.uniform(-0.1, 1.1, 200_000), rng.uniform(0, 0.01, 50_000), decode_ref(np.arange(256)), np.nan]
    layer_px = x[: len(x) // 3 * 3].reshape(-1, 1, 3).astype(np.float64)
    frame = np.zeros((len(layer_px), 1, 3), np.uint8)
    layer = render.Layer(layer_px.astype(np.float32), np.ones((len(layer_px), 1), bool),
                         np.zeros((len(layer_px), 1), np.float32), (0, len(layer_px), 0, 1))
    out = render.composite(frame, layer)
    ref = encode_ref(np.nan_to_num(layer_px.astype(np.float32).astype(np.float64), nan=0.0))
    np.testing.assert_array_equal(out, ref)
    # every 8-bit code survives decode → encode
    codes = np.arange(256, dtype=np.uint8)
    lut = colour.srgb8_to_linear_lut()
    layer = render.Layer(np.repeat(lut[codes][:, None, None], 3, axis=2).astype(np.float32),
                         np.ones((256, 1), bool), np.zeros((256, 1), np.float32), (0, 256, 0, 1))
    np.testing.assert_array_equal(render.composite(np.zeros((256, 1, 3), np.uint8), layer)[:, 0, 0], codes)


def test_empty_layer_or_zero_alpha_leaves_the_frame_bit_for_bit():
    frame = random_frame()
    before = frame.copy()
    out = render.composite(frame, render.Layer.empty(40, 60), ccm_inverse=np.diag([2.0, 0.5, 1.0]))
    np.testing.assert_array_equal(out, frame)
    assert out is not frame
    zero_alpha = render.Layer(np.zeros((40, 60, 3), np.float32), np.zeros((40, 60), bool),
                              np.zeros((40, 60), np.float32), (0, 40, 0, 60))
    np.testing.assert_array_equal(render.composite(frame, zero_alpha, shadow_grey=0.0), frame)
    np.testing.assert_array_equal(frame, before)  # input untouched


def test_object_pixels_follow_the_inverse_gain():
    layer, frame = make_layer(), random_frame()
    gains = np.array([1.6, 1.0, 0.7])  # the frame is 1.6× brighter in red than the reference, ...
    ccm = np.diag(1.0 / gains)  # ... so the correction matrix divides by the gains
    out_id = render.composite(frame, layer, ccm_inverse=np.eye(3))
    out_gain = render.composite(frame, layer, ccm_inverse=colour.invert_ccm(ccm))
    c = layer.colour[layer.mask].astype(np.float64)
    np.testing.assert_array_equal(out_id[layer.mask], encode_ref(c))
    np.testing.assert_array_equal(out_gain[layer.mask], encode_ref(c * gains))
    np.testing.assert_array_equal(render.composite(frame, layer)[layer.mask], out_id[layer.mask])
    # outside the object and the plane nothing changes
    untouched = ~layer.mask & (layer.plane_alpha == 0)
    np.testing.assert_array_equal(out_gain[untouched], frame[untouched])


def test_full_matrix_matches_apply_ccm():
    layer, frame = make_layer(seed=4), random_frame(seed=5)
    m = np.array([[0.9, 0.1, -0.05], [0.05, 1.1, 0.0], [-0.02, 0.08, 0.8]])
    out = render.composite(frame, layer, ccm_inverse=m)
    ref = encode_ref(colour.apply_ccm(layer.colour[layer.mask].astype(np.float64), m))
    np.testing.assert_array_equal(out[layer.mask], ref)


def test_shadow_plane_blends_in_linear_light():
    layer, frame = make_layer(seed=6), random_frame(seed=7)
    grey, gains = 0.15, np.array([1.2, 1.0, 0.8])
    m = np.diag(gains)
    out = render.composite(frame, layer, ccm_inverse=m, shadow_grey=grey)
    plane = layer.plane_alpha > 0
    a = layer.plane_alpha[plane].astype(np.float64)[:, None]
    expected = encode_ref((1 - a) * decode_ref(frame[plane]) + a * grey * gains)
    np.testing.assert_array_equal(out[plane], expected)
    # a black plane at alpha 0.5 halves the light: code 200 (linear 0.578) → linear 0.289 → code 146,
    # not the sRGB-space blend's 100
    flat = np.full((1, 1, 3), 200, np.uint8)
    half = render.Layer(np.zeros((1, 1, 3), np.float32), np.zeros((1, 1), bool), np.full((1, 1), 0.5, np.float32),
                        (0, 1, 0, 1))
    got = render.composite(flat, half, shadow_grey=0.0)
    assert got[0, 0, 0] == encode_ref(0.5 * decode_ref(200)) == 146
    # alpha 1 shows the plane's grey exactly
    full = render.Layer(np.zeros((1, 1, 3), np.float32), np.zeros((1, 1), bool), np.ones((1, 1), np.float32),
                        (0, 1, 0, 1))
    np.testing.assert_array_equal(render.composite(flat, full, shadow_grey=0.3)[0, 0], encode_ref([0.3] * 3))


@pytest.mark.parametrize("ccm", [None, "diag", "full"])
@pytest.mark.parametrize("grey", [0.0, 0.15, 0.6])
def test_composite_matches_the_reference(ccm, grey):
    layer, frame = make_layer(seed=8), random_frame(seed=9)
    m = {None: None, "diag": np.diag([1.2, 1.0, 0.8]),
         "full": np.array([[0.9, 0.1, -0.05], [0.05, 1.1, 0.0], [-0.02, 0.08, 0.8]])}[ccm]
    np.testing.assert_array_equal(render.composite(frame, layer, ccm_inverse=m, shadow_grey=grey),
                                  composite_ref.composite(frame, layer, ccm_inverse=m, shadow_grey=grey))


def test_hdr_and_negative_object_colours_are_clipped():
    col = np.zeros((1, 3, 3), np.float32)
    col[0] = [[5.0, 1.0, 0.5], [-1.0, 0.0, 1e-9], [np.inf, 0.2, 0.2]]
    layer = render.Layer(col, np.ones((1, 3), bool), np.zeros((1, 3), np.float32), (0, 1, 0, 3))
    out = render.composite(np.zeros((1, 3, 3), np.uint8), layer)
    np.testing.assert_array_equal(out[0], [[255, 255, 188], [0, 0, 0], [255, 124, 124]])


def test_composite_rejects_bad_inputs():
    layer, frame = make_layer(), random_frame()
    with pytest.raises(ShapeError, match="layer"):
        render.composite(random_frame(40, 61), layer)
    with pytest.raises(DTypeError, match="frame_srgb"):
        render.composite(frame.astype(np.float32), layer)
    with pytest.raises(ShapeError, match="frame_srgb"):
        render.composite(frame[..., 0], layer)
    with pytest.raises(DTypeError, match="layer"):
        render.composite(frame, layer.mask)
    with pytest.raises(NonFiniteError, match="ccm_inverse"):
        render.composite(frame, layer, ccm_inverse=np.full((3, 3), np.nan))
    with pytest.raises(ShapeError, match="ccm_inverse"):
        render.composite(frame, layer, ccm_inverse=np.eye(4))
    with pytest.raises(RangeError, match="shadow_grey"):
        render.composite(frame, layer, shadow_grey=-0.1)
    assert issubclass(render.RendererUnavailableError, RgbdEnvmapError)


def test_rigid_transform_and_matrix_poses_agree(renderers):
    T, _, ov, of, pv, pf, pa = sphere_scene(subdivisions=2)
    r = renderers("numba")
    a = draw(r, T, ov, of, np.ones_like(ov), pv, pf, pa)
    b = draw(r, T.matrix, ov, of, np.ones_like(ov), pv, pf, pa)
    np.testing.assert_array_equal(a.mask, b.mask)
    assert isinstance(T, RigidTransform)
