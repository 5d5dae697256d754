"""Tests of rgbd_envmap.lights: the samplers against their references, the power and irradiance they
stand for, the Q2-Tree's quads, incremental updates and merges, the hard cases and the errors."""

from __future__ import annotations

import healpy
import numpy as np
import pytest

from rgbd_envmap._kernels import lights_q2tree
from rgbd_envmap.errors import (DTypeError, InvalidInputError, NonFiniteError, RangeError, RgbdEnvmapError,
                                ShapeError, UnknownMethodError)
from rgbd_envmap.geometry import equirect_pixel_index
from rgbd_envmap._kernels.kmeans import weighted_kmeans_kernel
from rgbd_envmap.lights import (METHODS, AreaLightState, HemigonState, LightSet, Q2TreeState, irradiance, map_integral,
                                direct_mask, direct_part, light_grid, merge_lights, sample_lights, split_direct_indirect)
from rgbd_envmap.lights import cells as cells_mod
from rgbd_envmap.lights import q2tree as q2
from rgbd_envmap.lights.areas import seed_centres, split_parts
from rgbd_envmap.lights.hemisphere import hemisphere_to_square, square_to_hemisphere
from rgbd_envmap.lights.maps import check_inputs
from rgbd_envmap.reference import lights as ref

ALL = sorted(METHODS)


def lights_of(rad, n, method, **kw):
    """sample_lights, with a unit-sphere depth for "val" where a test gives none (val clusters the
    map's points; on a sphere round the origin it clusters directions)."""
    if method == "val" and "depth_m" not in kw:
        kw["depth_m"] = np.ones(np.shape(rad)[:2])
    return sample_lights(rad, n, method, **kw)


@pytest.fixture(scope="module")
def room():
    return ref.room_map(64, 128)


@pytest.fixture(scope="module")
def room_big():
    return ref.room_map(128, 256)


def fibonacci_normals(m: int = 64) -> np.ndarray:
    k = np.arange(m) + 0.5
    z = 1 - 2 * k / m
    ph = np.pi * (1 + 5 ** 0.5) * k
    return np.stack([np.sqrt(1 - z * z) * np.cos(ph), np.sqrt(1 - z * z) * np.sin(ph), z], 1)


def leaves(lights: LightSet) -> dict:
    return {tuple(c): p for c, p in zip(lights.cells.tolist(), lights.power)}


# --- the result -----------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ALL)
def test_result_shapes_units_and_frozen(room, method):
    rad, _, _ = room
    lights = lights_of(rad, 200, method)
    n = len(lights)
    assert n == (201 if method == "q2tree" else 200)  # val: every one of its 200 clusters holds pixels here
    assert lights.directions.shape == (n, 3) and lights.directions.dtype == np.float64
    assert lights.power.shape == (n, 3) and lights.power.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(lights.directions, axis=1), 1.0, atol=1e-12)
    assert (lights.power >= 0).all()
    assert lights.method == method
    assert (lights.solid_angle is not None) == (method in ("q2tree", "val"))
    if method == "val":  # lights on the (unit-sphere) surfaces, each with its area points
        assert lights.positions.shape == (n, 3) and lights.points.shape == (n, 8, 3)
        np.testing.assert_allclose(lights.point_power.sum(axis=1), lights.power, rtol=1e-12, atol=1e-300)
        np.testing.assert_allclose(lights.solid_angle.sum(), 4 * np.pi, rtol=1e-12)
    else:
        assert lights.positions is None and lights.origin is None and lights.points is None
    with pytest.raises(ValueError):
        lights.power[0, 0] = 1.0


def test_lightset_validates():
    d = np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(InvalidInputError):
        LightSet(np.array([[0.0, 0.0, 2.0]]), np.ones((1, 3)), "x")
    with pytest.raises(InvalidInputError):
        LightSet(d, -np.ones((1, 3)), "x")
    with pytest.raises(ShapeError):
        LightSet(d, np.ones((2, 3)), "x")
    with pytest.raises(InvalidInputError):
        LightSet(d, np.ones((1, 3)), "x", positions=np.zeros((1, 3)))  # positions without origin
    with pytest.raises(InvalidInputError):
        LightSet(d, np.ones((1, 3)), "x", cells=np.array([[0, 12]]))  # level 0 has 12 quads


# --- errors and the dispatcher --------------------------------------------------------------------

def test_unknown_method_lists_the_valid_ones(room):
    with pytest.raises(UnknownMethodError, match="hemigon.*q2tree|pharr"):
        sample_lights(room[0], 10, "median_cut")


@pytest.mark.parametrize("n, err", [(0, RangeError), (-3, RangeError), (True, DTypeError), (2.5, DTypeError),
                                    (10 ** 7, RangeError)])
def test_bad_light_counts(room, n, err):
    with pytest.raises(err, match="n"):
        sample_lights(room[0], n)


@pytest.mark.parametrize("method", ALL)
def test_nan_at_a_valid_pixel_raises_but_not_under_the_mask(room, method):
    rad = room[0].copy()
    rad[10, 20, 1] = np.nan
    with pytest.raises(NonFiniteError, match="radiance"):
        lights_of(rad, 50, method)
    valid = np.ones(rad.shape[:2], bool)
    valid[10, 20] = False
    lights = lights_of(rad, 50, method, valid=valid)
    assert np.isfinite(lights.power).all()
    rad[10, 20, 1] = np.inf
    with pytest.raises(NonFiniteError):
        lights_of(rad, 50, method)


@pytest.mark.parametrize("method", ALL)
def test_negative_radiance_and_all_invalid_raise(room, method):
    rad = room[0].copy()
    rad[3, 4, 2] = -1.0
    with pytest.raises(RangeError, match="≥ 0"):
        lights_of(rad, 20, method)
    with pytest.raises(InvalidInputError, match="valid"):
        lights_of(room[0], 20, method, valid=np.zeros(rad.shape[:2], bool))


def test_input_checks(room):
    rad, dep, org = room
    with pytest.raises(ShapeError):
        sample_lights(rad[..., :2], 10)
    with pytest.raises(ShapeError):
        sample_lights(rad, 10, valid=np.ones((3, 3), bool))
    with pytest.raises(ShapeError):
        sample_lights(np.zeros((0, 0, 3)), 10)
    with pytest.raises(DTypeError):
        sample_lights(rad.astype(np.complex64), 10)
    with pytest.raises(InvalidInputError, match="origin"):
        sample_lights(rad, 10, origin=(0, 0, 1))
    with pytest.raises(InvalidInputError, match="options"):
        sample_lights(rad, 10, "pharr", a=2.0)
    with pytest.raises(InvalidInputError, match="state"):
        sample_lights(rad, 10, "pharr", state=Q2TreeState())
    with pytest.raises(InvalidInputError, match="state"):
        sample_lights(rad, 10, "q2tree", state=HemigonState())
    with pytest.raises(RangeError, match="a"):
        sample_lights(rad, 10, "q2tree", a=-1.0)
    bad = dep.copy()
    bad[0, 0] = np.nan
    with pytest.raises(NonFiniteError, match="depth_m"):
        sample_lights(rad, 10, depth_m=bad, origin=org)
    assert issubclass(UnknownMethodError, RgbdEnvmapError)


@pytest.mark.parametrize("method", ALL)
def test_float64_and_strided_inputs_give_the_same_lights(room, method):
    rad = room[0]
    a = lights_of(rad, 100, method)
    wide = np.zeros((rad.shape[0], rad.shape[1], 4), np.float32)
    wide[..., :3] = rad
    b = lights_of(wide[..., :3], 100, method)  # non-contiguous view
    c = lights_of(rad.astype(np.float64), 100, method)
    np.testing.assert_array_equal(a.directions, b.directions)
    np.testing.assert_allclose(a.directions, c.directions, atol=1e-12)
    np.testing.assert_allclose(a.power, c.power, rtol=1e-12)


# --- power and irradiance -------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 12, 13, 200, 1000, 4000])
def test_q2tree_power_sums_to_the_map_integral_exactly(room, n):
    rad = room[0]
    valid = np.ones(rad.shape[:2], bool)
    valid[20:30, 40:70] = False
    for v in (None, valid):
        lights = sample_lights(rad, n, "q2tree", valid=v)
        np.testing.assert_allclose(lights.total_power, ref.map_integral(rad, v), rtol=1e-13, atol=0)
        np.testing.assert_allclose(map_integral(rad, v), ref.map_integral(rad, v), rtol=1e-13, atol=0)


@pytest.mark.parametrize("method", ["pharr", "hemigon"])
def test_pdf_methods_carry_the_luminance_exactly_and_colour_on_average(room, method):
    rad = room[0]
    lights = sample_lights(rad, 2000, method)
    truth = ref.map_integral(rad)
    y = ref.LUMINANCE
    np.testing.assert_allclose(lights.total_power @ y, truth @ y, rtol=1e-6)
    np.testing.assert_allclose(lights.total_power, truth, rtol=0.02)
    # equal luminance power per light (the PDF methods' samples are of equal power)
    np.testing.assert_allclose(lights.power @ y, truth @ y / 2000, rtol=1e-6)


@pytest.mark.parametrize("method, n, tol", [("pharr", 200, 0.03), ("pharr", 1000, 0.008), ("hemigon", 200, 0.035),
                                            ("hemigon", 1000, 0.01), ("q2tree", 200, 0.02), ("q2tree", 4000, 0.004),
                                            ("val", 200, 0.02), ("val", 1000, 0.01)])
def test_irradiance_from_lights_matches_a_brute_force_cosine_convolution(room_big, method, n, tol):
    rad = room_big[0]
    normals = fibonacci_normals(64)
    truth = ref.brute_force_irradiance(rad, normals) @ ref.LUMINANCE
    got = irradiance(lights_of(rad, n, method), normals) @ ref.LUMINANCE
    rms = np.sqrt(np.mean((got - truth) ** 2)) / np.sqrt(np.mean(truth ** 2))
    assert rms < tol


def test_irradiance_shapes_and_errors(room):
    lights = sample_lights(room[0], 50, "pharr")
    assert irradiance(lights, np.zeros((2, 5, 3)) + [0, 0, 1]).shape == (2, 5, 3)
    with pytest.raises(InvalidInputError, match="positions"):
        irradiance(lights, [[0, 0, 1.0]], points=[[0, 0, 0.0]])
    with pytest.raises(InvalidInputError):
        irradiance("lights", [[0, 0, 1.0]])


# --- the Q2-Tree ----------------------------------------------------------------------------------

@pytest.mark.parametrize("n, a, b", [(1, 1.0, 0.25), (13, 1.0, 0.25), (300, 1.0, 0.25), (2000, 1.0, 0.25),
                                     (300, 0.5, 0.0), (300, 1.0, 1.0), (300, 0.0, 0.25)])
def test_q2tree_is_algorithm_1_one_split_at_a_time(room, n, a, b):
    rad = room[0]
    level = cells_mod.finest_level(*rad.shape[:2], n)
    lights = sample_lights(rad, n, "q2tree", a=a, b=b)
    want = ref.q2tree(rad, n, level, a=a, b=b)
    got = leaves(lights)
    assert set(got) == set(want)
    assert len(lights) == q2.leaf_count(n) == len(want)
    for k, p in want.items():
        np.testing.assert_allclose(got[k], p, rtol=1e-12, atol=1e-300)


def test_q2tree_quads_have_healpix_solid_angles(room_big):
    rad = room_big[0]
    lights = sample_lights(rad, 600, "q2tree", level=6)
    lvl = lights.cells[:, 0]
    np.testing.assert_allclose(lights.solid_angle, [healpy.nside2pixarea(2 ** int(v)) for v in lvl], rtol=1e-14)
    np.testing.assert_allclose(lights.solid_angle.sum(), 4 * np.pi, rtol=1e-13)
    assert lvl.max() > lvl.min() + 2  # an adaptive tree, not a uniform one
    # the pixels whose centres fall in a level-2 quad cover its area to within the ragged edge
    H, W = 256, 512
    table = cells_mod.healpix_table(H, W, 2)
    om = ref.pixel_solid_angles(H, W)
    got = np.bincount(table.ravel(), om.ravel(), 192)
    np.testing.assert_allclose(got, np.pi / (3 * 16), rtol=0.03)
    # and every quad's light lies in its quad (jitter stays inside)
    pix = healpy.vec2pix(2 ** lvl, *lights.directions.T, nest=True)
    np.testing.assert_array_equal(pix, lights.cells[:, 1])


def test_q2tree_without_jitter_places_lights_at_quad_centres(room):
    lights = sample_lights(room[0], 100, "q2tree", jitter=False)
    want = np.stack(healpy.pix2vec(2 ** lights.cells[:, 0], lights.cells[:, 1], nest=True), axis=1)
    np.testing.assert_allclose(lights.directions, want, atol=1e-14)


def test_q2tree_kernels_match_numpy():
    rng = np.random.default_rng(1)
    child = rng.random((12 * 16, 6))
    up = np.empty((48, 6))
    lights_q2tree.level_up(child, up)
    np.testing.assert_allclose(up, child.reshape(-1, 4, 6).sum(axis=1), rtol=1e-15)
    out = np.empty(192)
    lights_q2tree.importance(child, 0.2126, 0.7152, 0.0722, 0.5, 0.3, out)
    np.testing.assert_allclose(out, (child[:, :3] @ ref.LUMINANCE) ** 0.5 * 0.3, rtol=1e-14)


def test_cell_sums_kernel_matches_bincount(room):
    rad, dep, org = room
    valid = np.ones(rad.shape[:2], bool)
    valid[::7, ::5] = False
    H, W = rad.shape[:2]
    for table, ncells in [(cells_mod.healpix_table(H, W, 4), 12 * 4 ** 4), (cells_mod.square_table(H, W, 16), 512)]:
        for v, d in [(None, None), (valid, dep)]:
            got = cells_mod.cell_sums(check_inputs(rad, v, d, None if d is None else org), table, ncells, d is not None)
            np.testing.assert_allclose(got, ref.cell_sums(rad, v, table, ncells, d), rtol=1e-12, atol=1e-15)


def test_q2tree_state_updates_equal_a_tree_built_from_scratch(room):
    rad0, _, _ = room
    rng = np.random.default_rng(3)
    state = Q2TreeState()
    frames = [rad0, rad0, rad0 * 1.5, np.roll(rad0, 9, axis=1), np.roll(rad0, 10, axis=1) * (1 + 0.2 * rng.random(rad0.shape)),
              np.flip(rad0, axis=0).copy(), rad0]
    steps = []
    for i, frame in enumerate(frames):
        n = 400 if i < 5 else 250
        inc = sample_lights(frame, n, "q2tree", state=state)
        fresh = sample_lights(frame, n, "q2tree")
        np.testing.assert_array_equal(inc.cells, fresh.cells)
        np.testing.assert_array_equal(inc.power, fresh.power)
        np.testing.assert_array_equal(inc.directions, fresh.directions)
        steps.append((state.rebuilt, state.steps))
    assert steps[0] == (True, 0)
    assert steps[1] == (False, 0) and steps[2] == (False, 0)  # same map, and a scaled one: no change (a = 1)
    assert steps[3][1] > 0 and steps[5][1] > 0


# --- Hemigon --------------------------------------------------------------------------------------

def test_hemisphere_mapping_round_trip_and_equal_area():
    rng = np.random.default_rng(0)
    ab = rng.uniform(-1, 1, (20000, 2))
    d = square_to_hemisphere(ab)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-14)
    assert d[:, 2].min() >= 0
    np.testing.assert_allclose(hemisphere_to_square(d), ab, atol=1e-12)
    # equal area: uniform points on the square are uniform on the hemisphere (z uniform in [0, 1])
    hist = np.histogram(d[:, 2], bins=10, range=(0, 1))[0]
    assert np.abs(hist - 2000).max() < 200
    # continuity across the square's diagonals (the concentric map's region boundaries)
    t = np.linspace(-1, 1, 101)
    a = square_to_hemisphere(np.stack([t, t + 1e-9], 1))
    b = square_to_hemisphere(np.stack([t, t - 1e-9], 1))
    assert np.abs(a - b).max() < 1e-7


def test_hemigon_filters_energy_and_trajectories(room):
    rad = room[0]
    state = HemigonState(history=3)
    raw, out = [], []
    for k in range(5):
        frame = rad * (1.0 if k % 2 == 0 else 3.0) if k < 4 else np.roll(rad, 5, axis=1)
        raw.append(sample_lights(frame, 100, "hemigon"))
        out.append(sample_lights(frame, 100, "hemigon", state=state))
    np.testing.assert_allclose(out[0].power, raw[0].power)  # first frame: nothing to filter with
    totals = np.array([r.total_power for r in raw])
    for k in range(5):
        lo = max(0, k - 2)
        np.testing.assert_allclose(out[k].total_power, totals[lo:k + 1].mean(axis=0), rtol=1e-12)
        mean_dir = np.mean([r.directions for r in raw[lo:k + 1]], axis=0)
        np.testing.assert_allclose(out[k].directions, mean_dir / np.linalg.norm(mean_dir, axis=1, keepdims=True),
                                   atol=1e-12)
    assert state.frames == 3
    sample_lights(rad, 60, "hemigon", state=state)  # another n restarts the history
    assert state.frames == 1
    with pytest.raises(RangeError):
        HemigonState(history=0)


# --- merging --------------------------------------------------------------------------------------

def _cameras(room, second_lamp=False):
    """Three cameras' maps of one room: sensor noise; another exposure with the lamp seen brighter;
    another white balance with the window dimmer. With ``second_lamp`` the second camera also sees a
    lamp the others do not."""
    rad, _, _ = room
    rng = np.random.default_rng(5)
    a = rad * (1 + 0.1 * rng.random(rad.shape, dtype=np.float32))
    b = rad * np.float32(0.7) + np.float32(0.02) * rng.random(rad.shape, dtype=np.float32)
    b[rad[..., 0] > 100] *= 3
    if second_lamp:
        b[5:9, 90:96] = 40.0
    c = rad * np.array([1.1, 1.0, 0.9], np.float32)
    c[(rad[..., 2] > 3) & (rad[..., 0] < 100)] *= 0.3
    return [a.astype(np.float32), b.astype(np.float32), c.astype(np.float32)]


@pytest.mark.parametrize("weights", [None, [0.5, 0.3, 0.2]])
@pytest.mark.parametrize("second_lamp, n_input", [(False, 1200), (True, 12 * 4 ** 5)])
def test_q2tree_merge_equals_the_tree_of_the_averaged_map(room, weights, second_lamp, n_input):
    """Algorithm 2 against a Q2-Tree built on the per-pixel (weighted) average of the maps: the same
    quads, powers and directions whenever the inputs' trees reach every quad the average's tree
    examines (deeper trees of similar maps; or, with a lamp only one camera sees, full trees)."""
    maps = _cameras(room, second_lamp)
    w = np.full(3, 1 / 3) if weights is None else np.asarray(weights)
    n, level = 300, 5  # 12 288 quads at the finest level
    trees = [sample_lights(m, n_input, "q2tree", level=level) for m in maps]
    if not second_lamp:
        assert len({tuple(map(tuple, t.cells.tolist())) for t in trees}) >= 2  # the inputs' trees differ
    merged = merge_lights(trees, n, weights)
    average = sum(wk * m.astype(np.float64) for wk, m in zip(w, maps))
    fresh = sample_lights(average, n, "q2tree", level=level)
    np.testing.assert_array_equal(merged.cells, fresh.cells)
    np.testing.assert_allclose(merged.power, fresh.power, rtol=1e-10, atol=1e-300)
    np.testing.assert_array_equal(merged.directions, fresh.directions)
    np.testing.assert_allclose(merged.solid_angle, fresh.solid_angle)


def test_q2tree_merge_of_shallow_trees_keeps_the_mean_power(room):
    maps = _cameras(room, second_lamp=True)
    trees = [sample_lights(m, 60, "q2tree") for m in maps]
    merged = merge_lights(trees, 60)
    assert len(merged) == 60
    np.testing.assert_allclose(merged.total_power, np.mean([t.total_power for t in trees], axis=0), rtol=1e-12)
    one = merge_lights([trees[0]], 60)
    np.testing.assert_array_equal(one.cells, trees[0].cells)
    np.testing.assert_allclose(one.power, trees[0].power, rtol=1e-12)


def test_pdf_merge_interpolates_by_index(room):
    maps = _cameras(room)
    a, b = (sample_lights(m, 100, "pharr") for m in maps[:2])
    m = merge_lights([a, b], weights=[3, 1])
    np.testing.assert_allclose(m.power, 0.75 * a.power + 0.25 * b.power)
    d = 0.75 * a.directions + 0.25 * b.directions
    np.testing.assert_allclose(m.directions, d / np.linalg.norm(d, axis=1, keepdims=True))
    same = merge_lights([a, a])
    np.testing.assert_allclose(same.directions, a.directions, atol=1e-15)
    with pytest.raises(InvalidInputError, match="equal length"):
        merge_lights([a, sample_lights(maps[0], 50, "pharr")])
    with pytest.raises(InvalidInputError, match="one method"):
        merge_lights([a, sample_lights(maps[0], 100, "hemigon")])
    with pytest.raises(RangeError):
        merge_lights([a, b], weights=[-1, 1])
    # virtual area lights' clusters do not correspond across cameras: no merge, said so
    rad, dep, org = ref.room_map(32, 64)
    val = sample_lights(rad, 6, "val", depth_m=dep, origin=org)
    with pytest.raises(InvalidInputError, match="'val' has no merge"):
        merge_lights([val, val])


# --- positions ------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ALL)
def test_lights_are_placed_by_the_depth_and_light_near_points_like_the_map(room_big, method):
    rad, dep, org = room_big
    lights = sample_lights(rad, 2000, method, depth_m=dep, origin=org)
    np.testing.assert_array_equal(lights.origin, org)
    top = np.argmax(lights.power @ ref.LUMINANCE) if method == "q2tree" else None
    towards = np.array([0.4, -0.3, 1.9]) / np.linalg.norm([0.4, -0.3, 1.9])
    lamp = lights.directions @ towards > np.cos(0.06)  # the lamp's disc spans 0.079 rad
    assert lamp.sum() >= (1 if method == "q2tree" else 5)  # the finest quads here are 0.06 rad wide
    np.testing.assert_allclose(lights.positions[lamp, 2], 2.9, atol=0.04)  # on the ceiling, 1.9 m above the origin
    assert (np.linalg.norm(lights.positions[lamp, :2] - [0.4, -0.3], axis=1) < 0.15).all()
    if top is not None:
        assert lamp[top]
    # irradiance 0.9 m below the lamp from point lights, against the map's pixels as point sources
    x, nrm = np.array([0.4, -0.3, 2.0]), np.array([0.0, 0.0, 1.0])
    H, W = rad.shape[:2]
    p = org + ref.pixel_directions(H, W) * dep[..., None].astype(np.float64)
    inten = rad * (ref.pixel_solid_angles(H, W) * dep.astype(np.float64) ** 2)[..., None]
    delta = p - x
    r2 = (delta ** 2).sum(-1)
    truth = (inten * (np.maximum(delta @ nrm / np.sqrt(r2), 0) / r2)[..., None]).reshape(-1, 3).sum(0)
    got = irradiance(lights, nrm[None], x[None])[0]
    np.testing.assert_allclose(got @ ref.LUMINANCE, truth @ ref.LUMINANCE, rtol=0.02)
    # at the origin, point lights give what the directional ones give
    np.testing.assert_allclose(irradiance(lights, nrm[None], org[None]), irradiance(lights, nrm[None]), rtol=1e-10)


# --- virtual area lights ("val") -------------------------------------------------------------------

def test_val_power_is_the_map_integral_and_each_light_its_clusters_sum(room):
    rad, dep, org = room
    valid = np.ones(rad.shape[:2], bool)
    valid[20:30, 40:70] = False
    for v in (None, valid):
        lights = sample_lights(rad, 40, "val", valid=v, depth_m=dep, origin=org)
        np.testing.assert_allclose(lights.total_power, ref.map_integral(rad, v), rtol=1e-12, atol=0)
        np.testing.assert_allclose(lights.point_power.sum(axis=1), lights.power, rtol=1e-12)
        omega = ref.pixel_solid_angles(*rad.shape[:2])
        np.testing.assert_allclose(lights.solid_angle.sum(), omega[v].sum() if v is not None else omega.sum(),
                                   rtol=1e-12)
        np.testing.assert_allclose(lights.positions - org, lights.directions
                                   * np.linalg.norm(lights.positions - org, axis=1, keepdims=True), atol=1e-12)


def test_val_puts_the_lamp_and_the_window_in_lights_of_their_own(room_big):
    """On the map's direct part (τ = 0.8: the lamp and the window), every light sits on one of the two
    emitters, its points on that emitter's surface; together the lamp's lights hold the lamp's energy
    and the window's the window's. (Energy-weighted k-means gives the bright lamp several lights.)"""
    rad, dep, org = room_big
    H, W = rad.shape[:2]
    y = ref.LUMINANCE
    p = org + ref.pixel_directions(H, W) * dep[..., None].astype(np.float64)
    energy = (rad * ref.pixel_solid_angles(H, W)[..., None]) @ y
    on_lamp = lambda q: (np.abs(q[..., 2] - 2.9) < 1e-3) & (np.hypot(q[..., 0] - 0.4, q[..., 1] + 0.3) < 0.25)  # noqa: E731
    # The window spans |y| < 0.8, 0.9 < z < 2.1 on the wall x = 2; a light's point is the mean of its
    # pixels, which at the window's edge take in a little of the bright wall around it.
    on_window = lambda q: (np.abs(q[..., 0] - 2.0) < 0.1) & (np.abs(q[..., 1]) < 0.85) & (q[..., 2] > 0.85) & (q[..., 2] < 2.15)  # noqa: E731
    in_window = lambda q: (np.abs(q[..., 0] - 2.0) < 0.1) & (np.abs(q[..., 1]) < 0.8) & (q[..., 2] > 0.9) & (q[..., 2] < 2.1)  # noqa: E731
    lamp_e = energy[on_lamp(p) & (np.hypot(p[..., 0] - 0.4, p[..., 1] + 0.3) < 0.15)].sum()
    window_e = energy[in_window(p)].sum()
    direct = direct_mask(rad, 0.8)[0]
    lights = sample_lights(rad, 12, "val", valid=direct, depth_m=dep, origin=org)
    lamp, window = on_lamp(lights.positions), on_window(lights.positions)
    assert lamp.any() and window.any() and (lamp | window).all() and not (lamp & window).any()
    assert on_lamp(lights.points[lamp]).all() and on_window(lights.points[window]).all()
    assert lamp_e <= lights.power[lamp].sum(0) @ y < 1.02 * lamp_e
    assert 0.9 * window_e < lights.power[window].sum(0) @ y < 1.05 * window_e  # with the wall at its edge
    for j in np.flatnonzero(lamp | window):  # the parts of a light are of about equal power
        part = lights.point_power[j] @ y
        assert part.min() > 0.5 * part.max()


def test_val_point_lights_are_the_area_points():
    rad, dep, org = ref.room_map(32, 64)
    lights = sample_lights(rad, 6, "val", depth_m=dep, origin=org, points=4)
    pl = lights.point_lights
    assert pl is lights.point_lights  # made once
    assert len(pl) == int((lights.point_power.max(axis=2) > 0).sum()) <= 24 and pl.points is None
    np.testing.assert_allclose(pl.total_power, lights.total_power, rtol=1e-12)
    np.testing.assert_allclose(pl.positions, lights.points.reshape(-1, 3)[lights.point_power.reshape(-1, 3).max(1) > 0])
    np.testing.assert_allclose(np.linalg.norm(pl.directions, axis=1), 1.0, atol=1e-12)
    # a set without area points is its own point lights
    q = sample_lights(rad, 12, "q2tree", depth_m=dep, origin=org)
    assert q.point_lights is q
    # one point per light: the point lights are the lights
    one = sample_lights(rad, 6, "val", depth_m=dep, origin=org, points=1)
    np.testing.assert_allclose(one.point_lights.positions, one.positions, atol=1e-12)


def test_val_warm_start_follows_the_map():
    rad, dep, org = ref.room_map(64, 128)
    state = AreaLightState()
    first = sample_lights(rad, 16, "val", depth_m=dep, origin=org, state=state, iterations=200)
    assert state.frames == 1 and state.centres.shape == (16, 3)
    # converged: the same map again gives the same lights
    again = sample_lights(rad, 16, "val", depth_m=dep, origin=org, state=state, iterations=200)
    np.testing.assert_allclose(again.positions, first.positions, atol=1e-12)
    # a little noise on the map moves the lights a little, and each stays the same light (same index)
    rng = np.random.default_rng(1)
    noisy = rad * (1 + 0.01 * rng.standard_normal(rad.shape)).astype(np.float32)
    moved = sample_lights(np.maximum(noisy, 0), 16, "val", depth_m=dep, origin=org, state=state, iterations=200)
    assert np.linalg.norm(moved.positions - first.positions, axis=1).max() < 0.1
    # another count reseeds; reset forgets
    assert len(sample_lights(rad, 5, "val", depth_m=dep, origin=org, state=state)) == 5
    state.reset()
    assert state.centres is None and state.frames == 0


def test_val_errors(room):
    rad, dep, org = room
    with pytest.raises(InvalidInputError, match="depth"):
        sample_lights(rad, 10, "val")
    with pytest.raises(InvalidInputError, match="state"):
        sample_lights(rad, 10, "val", depth_m=dep, origin=org, state=Q2TreeState())
    with pytest.raises(InvalidInputError, match="state"):
        sample_lights(rad, 10, "q2tree", state=AreaLightState())
    with pytest.raises(RangeError, match="points"):
        sample_lights(rad, 10, "val", depth_m=dep, origin=org, points=0)
    with pytest.raises(DTypeError, match="iterations"):
        sample_lights(rad, 10, "val", depth_m=dep, origin=org, iterations=1.5)
    with pytest.raises(InvalidInputError, match="options"):
        sample_lights(rad, 10, "val", depth_m=dep, origin=org, side=4)


def test_lightset_validates_area_points():
    d, pw, o = np.array([[0.0, 0.0, 1.0]]), np.ones((1, 3)), np.zeros(3)
    pts = np.array([[[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]]])
    LightSet(d, pw, "val", positions=d, origin=o, points=pts, point_power=np.full((1, 2, 3), 0.5))
    with pytest.raises(InvalidInputError, match="both"):
        LightSet(d, pw, "val", positions=d, origin=o, points=pts)
    with pytest.raises(InvalidInputError, match="positions"):
        LightSet(d, pw, "val", points=pts, point_power=np.ones((1, 2, 3)))
    with pytest.raises(ShapeError):
        LightSet(d, pw, "val", positions=d, origin=o, points=pts, point_power=np.ones((1, 3, 3)))
    with pytest.raises(InvalidInputError, match="≥ 0"):
        LightSet(d, pw, "val", positions=d, origin=o, points=pts, point_power=-np.ones((1, 2, 3)))
    with pytest.raises(NonFiniteError):
        LightSet(d, pw, "val", positions=d, origin=o, points=pts * np.nan, point_power=np.ones((1, 2, 3)))


def kmeans_cases():
    rng = np.random.default_rng(7)
    blobs = np.concatenate([rng.normal(c, 0.1, (40, 3)) for c in ([0, 0, 0], [2, 0, 0], [0, 3, 1])])
    yield "blobs", blobs, rng.random(len(blobs)) + 0.1, blobs[[0, 1, 2]], 50
    # more centres than distinct points: the spare ones are reseeded, then stay empty
    dup = np.repeat(rng.random((3, 3)), 4, axis=0)
    yield "duplicates", dup, np.ones(12), rng.random((5, 3)), 10
    # two centres on one spot: the second gets nothing (ties go to the first) and is reseeded
    yield "tied centres", blobs, np.ones(len(blobs)), np.zeros((3, 3)), 30
    yield "one point", np.array([[1.0, 2.0, 3.0]]), np.array([2.0]), np.array([[0.0, 0, 0], [5, 5, 5]]), 5
    yield "k = 1", blobs, rng.random(len(blobs)), blobs[:1] + 1.0, 5
    yield "one iteration", blobs, rng.random(len(blobs)) + 0.1, blobs[[5, 6, 7, 8]], 1
    big = rng.normal(0, 1, (3000, 3)) * [1, 2, 0.5]
    yield "many", big, rng.random(3000) ** 4, big[:25], 20


@pytest.mark.parametrize("case", list(kmeans_cases()), ids=lambda c: c[0])
def test_weighted_kmeans_kernel_is_the_reference(case):
    _, pts, w, c0, iters = case
    c_ref, lab_ref, done_ref = ref.weighted_kmeans(pts, w, c0, iters)
    c = np.array(c0, np.float64)
    lab = np.empty(len(pts), np.int64)
    done = weighted_kmeans_kernel(np.ascontiguousarray(pts, np.float64), np.asarray(w, np.float64), c, lab, iters)
    assert done == done_ref
    np.testing.assert_array_equal(c, c_ref)
    np.testing.assert_array_equal(lab, lab_ref)


def test_seeded_weighted_kmeans_finds_separated_blobs():
    rng = np.random.default_rng(3)
    centres = np.array([[0.0, 0, 0], [3, 0, 0], [0, 3, 0], [0, 0, 3]])
    pts = np.concatenate([rng.normal(c, 0.05, (100, 3)) for c in centres])
    w = rng.random(len(pts)) + 0.5
    seeds = seed_centres(pts, w, 4)  # Lloyd alone would not leave a start of four seeds in one blob
    assert len({int(np.argmin(np.linalg.norm(centres - x, axis=1))) for x in seeds}) == 4
    c, lab, done = ref.weighted_kmeans(pts, w, seeds, 100)
    assert done < 100 and len(np.unique(lab)) == 4
    for j in range(4):  # each blob one cluster, its centre the blob's weighted mean
        blob = lab[100 * j:100 * (j + 1)]
        assert (blob == blob[0]).all()
        np.testing.assert_allclose(c[blob[0]], w[100 * j:100 * (j + 1)] @ pts[100 * j:100 * (j + 1)]
                                   / w[100 * j:100 * (j + 1)].sum(), atol=1e-12)



def test_split_parts_cuts_a_light_into_parts_of_equal_weight():
    rng = np.random.default_rng(4)
    # points along a line: the parts are contiguous runs, of equal count for equal weights
    line = np.stack([rng.permutation(1000) / 1000.0, np.zeros(1000), np.zeros(1000)], 1)
    parts = split_parts(line, np.ones(1000), 8)
    assert sorted(len(p) for p in parts) == [125] * 8
    assert sorted(np.concatenate(parts).tolist()) == list(range(1000))
    spans = sorted((line[p, 0].min(), line[p, 0].max()) for p in parts)
    assert all(a[1] < b[0] for a, b in zip(spans, spans[1:]))
    # uneven weights on a cloud: each cut is within half a point of its target, so a part of m = 8 is
    # within 1.5 of the heaviest point of its share (three nested cuts)
    cloud, w = rng.normal(0, 1, (500, 3)), rng.random(500) ** 4
    for m in (3, 5, 8):
        weights = np.array([w[p].sum() for p in split_parts(cloud, w, m)])
        assert np.abs(weights - w.sum() / m).max() <= 1.5 * w.max()
    # fewer points than parts: one point a part, the rest empty; no weight: cut by count
    few = split_parts(cloud[:3], w[:3], 8)
    assert sorted(len(p) for p in few) == [0] * 5 + [1] * 3
    assert sorted(len(p) for p in split_parts(cloud[:40], np.zeros(40), 4)) == [10] * 4



@pytest.mark.parametrize("case", ["cloud", "ties", "zero weights", "few points", "one heavy point"])
def test_split_parts_kernel_is_its_reference_bit_for_bit(case):
    rng = np.random.default_rng(6)
    pts, w = rng.normal(0, 1, (300, 3)), rng.random(300) ** 3
    if case == "ties":  # a disc: equal spreads, repeated coordinates
        pts = np.round(np.concatenate([rng.normal(0, 1, (300, 2)), np.zeros((300, 1))], 1), 1)
    elif case == "zero weights":
        w = np.zeros(300)
    elif case == "few points":
        pts, w = pts[:5], w[:5]
    elif case == "one heavy point":
        w[17] = 1e6
    for m in (1, 2, 3, 8, 13):
        got = split_parts(pts, w, m)
        want = ref.split_parts(pts, w, m)
        assert len(got) == len(want) == m
        for g, e in zip(got, want):
            np.testing.assert_array_equal(g, e)

# --- hard cases -----------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ALL)
def test_an_all_black_map_gives_powerless_lights(method):
    lights = lights_of(np.zeros((16, 32, 3), np.float32), 40, method)
    assert (lights.power == 0).all()
    np.testing.assert_allclose(np.linalg.norm(lights.directions, axis=1), 1.0)


@pytest.mark.parametrize("method", ALL)
@pytest.mark.parametrize("pixel", [(0, 5), (31, 60), (16, 0), (16, 63)])  # poles, seam columns
def test_a_single_bright_pixel(method, pixel):
    rad = np.zeros((32, 64, 3), np.float32)
    rad[pixel] = (100.0, 50.0, 10.0)
    lights = lights_of(rad, 30, method)
    truth = ref.map_integral(rad)
    if method == "q2tree":
        np.testing.assert_allclose(lights.total_power, truth, rtol=1e-14)
        assert (lights.power > 0).any(axis=1).sum() == 1
        top = np.argmax(lights.power[:, 0])
        d = ref.pixel_directions(32, 64)[pixel]
        lvl, p = lights.cells[top]
        assert healpy.vec2pix(2 ** int(lvl), *d, nest=True) == p
    elif method == "val":  # one light of all the power, sitting on that pixel's point
        np.testing.assert_allclose(lights.total_power, truth, rtol=1e-12)
        assert (lights.power > 0).any(axis=1).sum() == 1
        top = np.argmax(lights.power[:, 0])
        np.testing.assert_allclose(lights.positions[top], ref.pixel_directions(32, 64)[pixel], atol=1e-6)
        np.testing.assert_allclose(lights.point_power[top].sum(axis=0), truth, rtol=1e-12)
    else:
        rows, cols, ok = equirect_pixel_index(lights.directions, 32, 64)
        if method == "pharr":  # every sample inside that pixel, with the pixel's power split evenly
            assert ok.all() and (rows == pixel[0]).all() and (cols == pixel[1]).all()
        else:  # in the pixel's Hemigon cell: within a cell's width of it
            d = ref.pixel_directions(32, 64)[pixel]
            assert (lights.directions @ d > np.cos(0.35)).all()
        np.testing.assert_allclose(lights.total_power, truth, rtol=1e-6)


@pytest.mark.parametrize("method", ALL)
def test_one_light_and_more_lights_than_pixels(method):
    rad, _, _ = ref.room_map(8, 16)
    one = lights_of(rad, 1, method)
    assert len(one) == (12 if method == "q2tree" else 1)
    many = lights_of(rad, 500, method)
    if method == "q2tree":
        assert len(many) == 501
        np.testing.assert_allclose(many.total_power, ref.map_integral(rad), rtol=1e-13)
    elif method == "val":  # no more lights than points: one per pixel, each that pixel
        assert len(many) == 128 and (many.power > 0).all()
        np.testing.assert_allclose(many.total_power, ref.map_integral(rad), rtol=1e-12)
        np.testing.assert_allclose(np.sort(many.solid_angle), np.sort(ref.pixel_solid_angles(8, 16).ravel()), rtol=1e-12)
    else:
        assert len(many) == 500 and (many.power > 0).all()


# --- the direct / indirect split ------------------------------------------------------------------

@pytest.mark.parametrize("tau", [0.0, 0.3, 0.6, 0.9, 1.0])
def test_split_counts_energy_once(room, tau):
    rad = room[0]
    valid = np.ones(rad.shape[:2], bool)
    valid[40:, :10] = False
    s = split_direct_indirect(rad, tau, valid)
    total = ref.map_integral(rad, valid)
    np.testing.assert_allclose(s.direct_energy + s.indirect_energy, total, rtol=1e-12)
    np.testing.assert_allclose(ref.map_integral(s.indirect, valid), s.indirect_energy, rtol=1e-12)
    assert not (s.direct & ~valid).any()
    y = rad @ ref.LUMINANCE
    if tau == 0:
        assert not s.direct.any()
        return
    lights = sample_lights(rad, 100, "q2tree", valid=s.direct)
    np.testing.assert_allclose(lights.total_power + ref.map_integral(s.indirect, valid), total, rtol=1e-12)
    assert s.direct_fraction >= tau - 1e-12
    # the brightest pixels: every direct pixel is at least as bright as every indirect valid one
    assert y[s.direct].min() >= y[valid & ~s.direct].max(initial=0)
    # and none can be dropped: without the dimmest direct level the fraction falls below tau
    e = y * ref.pixel_solid_angles(*rad.shape[:2])
    dimmest = s.direct & (y == y[s.direct].min())
    assert (e[s.direct & ~dimmest].sum() / e[valid].sum()) < tau


def _basis_table(H, W, bands=5):
    from rgbd_envmap import sh
    from rgbd_envmap.geometry import equirect_directions, equirect_solid_angles

    return sh.basis(equirect_directions(H, W).reshape(-1, 3), bands) * equirect_solid_angles(H, W).reshape(-1, 1)


def _maps():
    """The room, a map of one repeated value (every pixel in the crossing bin: ties), a random map
    with a few zero and huge pixels, and a map black but for one pixel at the pole and one at the seam."""
    rng = np.random.default_rng(7)
    rad = ref.room_map(64, 128)[0]
    flat = np.full((32, 64, 3), 0.25, np.float32)
    wild = rng.gamma(0.3, 1.0, (48, 96, 3)).astype(np.float32)
    wild[::7, ::5] = 0
    wild[3, 4] = 1e6
    dots = np.zeros((40, 80, 3), np.float64)
    dots[0, 5] = 10.0
    dots[20, 79] = 3.0
    return [rad, flat, wild, dots]


@pytest.mark.parametrize("tau", [0.0, 0.05, 0.5, 0.95, 1.0])
def test_direct_part_kernel_is_the_full_sort_reference(tau):
    """The compiled split (histogram + one sorted bin) against a full sort: the same mask and threshold
    exactly, the direct SH sums to float64 rounding; with and without a valid mask."""
    rng = np.random.default_rng(3)
    for rad in _maps():
        H, W = rad.shape[:2]
        table = _basis_table(H, W)
        for valid in (None, rng.random((H, W)) > 0.4):
            mask, thr, shd = direct_part(rad, tau, table, valid=valid)
            m2, t2, s2 = ref.direct_split(rad, tau, valid, table)
            np.testing.assert_array_equal(mask, m2)
            assert thr == t2
            np.testing.assert_allclose(shd, s2, rtol=1e-12, atol=1e-12 * max(np.abs(s2).max(), 1e-300))
            m3, t3 = direct_mask(rad, tau, valid)
            np.testing.assert_array_equal(m3, mask)
            assert t3 == thr


def test_direct_part_sh_is_the_projection_of_the_direct_pixels(room):
    """Σ direct radiance × basis × Ω = the SH projection (brute force) of the map zeroed off the direct part."""
    from rgbd_envmap.reference.sh_projection import project_equirect

    rad = room[0]
    H, W = rad.shape[:2]
    mask, _, shd = direct_part(rad, 0.5, _basis_table(H, W))
    only = np.where(mask[..., None], rad, np.float32(0))
    want = project_equirect(only, bands=5)
    np.testing.assert_allclose(shd, want, rtol=0, atol=1e-5 * np.abs(want).max())
    mask2, _, shd2 = direct_part(rad, 0.5, 5)  # the separable form, at exact directions
    np.testing.assert_array_equal(mask2, mask)
    np.testing.assert_allclose(shd2, want, rtol=0, atol=1e-9 * np.abs(want).max())


def _exact_basis_table(H, W, bands=5):
    """The SH basis × solid angle at the pixel centres, directions formed in float64 (the library's
    equirect_directions are float32)."""
    from rgbd_envmap import sh
    from rgbd_envmap.geometry import equirect_solid_angles

    theta = np.pi * (np.arange(H) + 0.5) / H
    phi = 2 * np.pi * (np.arange(W) + 0.5) / W - np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    return sh.basis(d, bands) * equirect_solid_angles(H, W).reshape(-1, 1)


@pytest.mark.parametrize("bands", [1, 3, 5, 8])
@pytest.mark.parametrize("tau", [0.05, 0.5, 1.0])
def test_direct_part_separable_sh_is_the_table_form(bands, tau):
    """``basis`` = a band count (per-row Legendre × per-column trig factors) against the (H·W, K)
    table of the same basis at float64 directions: the same mask and threshold, the sums to 1e-10;
    on odd widths (no folding symmetry) and with a valid mask."""
    rng = np.random.default_rng(bands)
    for rad in _maps() + [rng.gamma(0.5, 1.0, (17, 35, 3))]:
        H, W = rad.shape[:2]
        table = _exact_basis_table(H, W, bands)
        for valid in (None, rng.random((H, W)) > 0.3):
            mask, thr, shd = direct_part(rad, tau, bands, valid=valid)
            m2, t2, s2 = ref.direct_split(rad, tau, valid, table)
            np.testing.assert_array_equal(mask, m2)
            assert thr == t2 and shd.shape == (bands * bands, 3)
            np.testing.assert_allclose(shd, s2, rtol=0, atol=1e-10 * max(np.abs(s2).max(), 1e-300))


def test_direct_part_separable_sh_checks_the_band_count():
    rad = np.ones((8, 16, 3))
    with pytest.raises(RangeError, match="basis"):
        direct_part(rad, 0.5, 0)
    with pytest.raises(RangeError, match="basis"):
        direct_part(rad, 0.5, 1000)
    with pytest.raises(ShapeError, match="basis"):
        direct_part(rad, 0.5, True)  # a flag is not a band count (nor a table)


def test_direct_part_hard_cases():
    rad = np.zeros((16, 32, 3), np.float32)
    table = _basis_table(16, 32)
    mask, thr, shd = direct_part(rad, 0.5, table)  # no energy: nothing direct
    assert not mask.any() and thr == np.inf and not shd.any()
    rad[3, 3] = 2.0
    valid = np.zeros((16, 32), bool)
    valid[3, 3] = True
    mask, thr, _ = direct_part(rad, 0.5, table, valid=valid)
    assert mask.sum() == 1 and thr == pytest.approx(2.0)
    bad = rad.copy()
    bad[5, 5, 1] = np.inf
    with pytest.raises(NonFiniteError):
        direct_part(bad, 0.5, table)
    bad[5, 5, 1] = np.nan
    direct_part(bad, 0.5, table, valid=valid)  # a NaN outside the valid pixels is not read
    bad[5, 5, 1] = -1.0
    with pytest.raises(RangeError):
        direct_part(bad, 0.5, table)
    with pytest.raises(ShapeError):
        direct_part(rad, 0.5, table[:-1])
    with pytest.raises(InvalidInputError):
        direct_part(rad, 0.5, table, valid=np.zeros((16, 32), bool))


def test_split_puts_the_lamp_in_the_direct_part(room):
    rad = room[0]
    s = split_direct_indirect(rad, 0.5)
    assert s.direct[rad[..., 0] > 100].all()
    assert (s.indirect[s.direct] == 0).all()
    with pytest.raises(RangeError):
        split_direct_indirect(rad, 1.5)
    bad = rad.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(NonFiniteError):
        split_direct_indirect(bad, 0.5)


# --- the pipeline's coarse light grid ---------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("stride", [1, 3, 4, 7])
def test_light_grid_is_the_reference(dtype, stride):
    rng = np.random.default_rng(stride)
    rad = rng.normal(0.5, 1.0, (26, 51, 3)).astype(dtype)
    rad[rng.random(rad.shape) < 0.05] = np.nan
    rad[0, 0] = (-0.0, np.inf, -np.inf)
    got = light_grid(rad, stride)
    want = ref.light_grid(rad, stride)
    assert got.dtype == dtype and got.flags.c_contiguous and got.shape == want.shape
    np.testing.assert_array_equal(got, want)  # NaN where NaN
    # the numpy form it replaces in the pipeline, where no value is NaN
    finite = np.nan_to_num(rad, nan=-1.0)
    o = stride // 2
    np.testing.assert_array_equal(light_grid(finite, stride), np.maximum(finite[o::stride, o::stride], 0))
    # strided input (a view) and an integer-valued map
    np.testing.assert_array_equal(light_grid(rad[:, ::2], stride), ref.light_grid(rad[:, ::2], stride))


def test_light_grid_hard_cases():
    assert light_grid(np.ones((3, 3, 3), np.float32), 4).shape == (1, 1, 3)  # a stride beyond the map: one pixel
    assert light_grid(np.ones((1, 1, 3)), 9).shape == (0, 0, 3)  # o = 4 lies outside
    with pytest.raises(RangeError, match="stride"):
        light_grid(np.ones((4, 4, 3)), 0)
    with pytest.raises(ShapeError, match="radiance"):
        light_grid(np.ones((4, 4)), 2)
    with pytest.raises(DTypeError, match="radiance"):
        light_grid(np.ones((4, 4, 3), np.uint8), 2)
