"""Tests for apps/accuracy.py: every figure of a run's ``accuracy.json`` (and the per-frame rows of
``depth_frames.csv``) against values computed independently here.

The expected values never go through the helpers accuracy.py calls (``metrics``, ``geometry``,
``sh``, ``prt``): pixel solid angles are re-derived from the equirect convention with ``math.cos``
(row v of an H×W map covers polar angles [π v/H, π (v+1)/H]; a pixel's solid angle is
(2π/W)(cos θ_top − cos θ_bottom), so a full band of rows [v0, v1) covers 2π (cos(π v0/H) − cos(π v1/H))
by telescoping), WS-PSNR follows Sun et al.'s weighted MSE (checked against both the solid-angle and
the cos-latitude weights), the true correction matrix is worked out from the gains by hand, SH
coefficients and irradiance of a map linear in z are closed forms, and the depth errors are plain
numpy over masks written out in the test.

The inputs are the objects a run hands the tracker (apps/run.py): ``DepthStep`` / ``CaptureStep``
/ ``CCMResult`` / ``UpdateStats`` as the pipeline builds them, a real ``EnvironmentMap`` for the
captured map, the true map as the dict ``simulate`` / ``replay`` pass (``radiance``,
``distance_m``, ``valid``, ``origin``), and a stand-in for the pipeline carrying only the
attributes ``AccuracyTracker.summary`` reads.
"""

from __future__ import annotations

import json
import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from apps.accuracy import AccuracyTracker, fibonacci_sphere
from rgbd_envmap.colour import CCMResult
from rgbd_envmap.envmap import EnvironmentMap, UpdateStats
from rgbd_envmap.pipeline import CaptureStep, DepthStep

ORIGIN = np.array([0.0, 0.0, 0.8])
COV_TOL = 1e-12  #: absolute, solid-angle fractions (float64 sums of a few hundred terms)
DB_TOL = 1e-9  #: dB, float64 ratios of weighted sums of exactly representable squares
REL_TOL = 1e-12


# ------------------------------------------------------------------------- independent references


def band_cos(h: int, v0: int, v1: int) -> float:
    """cos(π v0/H) − cos(π v1/H): the full band of rows [v0, v1) covers 2π times this (sr)."""
    return math.cos(math.pi * v0 / h) - math.cos(math.pi * v1 / h)


def row_solid_angles(h: int, w: int) -> np.ndarray:
    """(H,) exact solid angle of one pixel of each row, written out with math.cos."""
    return np.array([(2 * math.pi / w) * band_cos(h, v, v + 1) for v in range(h)])


def solid_angle(mask: np.ndarray) -> float:
    """Σ of the pixel solid angles under ``mask`` (H, W), by brute force over rows."""
    h, w = mask.shape
    sa = row_solid_angles(h, w)
    return float(sum(sa[v] * int(mask[v].sum()) for v in range(h)))


def cos_latitude_weights(h: int, w: int) -> np.ndarray:
    """(H, W) Sun et al.'s ERP weights: cos(latitude) at each pixel centre."""
    lat = (0.5 - (np.arange(h) + 0.5) / h) * math.pi
    return np.repeat(np.cos(lat)[:, None], w, axis=1)


def wmse(a: np.ndarray, b: np.ndarray, mask: np.ndarray, weights: np.ndarray) -> float:
    """Σ_mask ω Σ_c (a − b)² / (C Σ_mask ω), looping over pixels (brute force)."""
    num = den = 0.0
    c = a.shape[2]
    for v, u in zip(*np.nonzero(mask)):
        d = a[v, u].astype(np.float64) - b[v, u].astype(np.float64)
        num += weights[v, u] * float(np.sum(d * d))
        den += weights[v, u]
    return num / (c * den)


def nan_keys(out: dict) -> list[str]:
    return [k for k, v in out.items() if isinstance(v, float) and math.isnan(v)]


def percentile_linear(values, q: float) -> float:
    """The q-th percentile with linear interpolation between order statistics (numpy's default)."""
    x = sorted(values)
    pos = q / 100.0 * (len(x) - 1)
    lo = math.floor(pos)
    hi = min(lo + 1, len(x) - 1)
    return x[lo] + (pos - lo) * (x[hi] - x[lo])


def weighted_pearson(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """Mean over channels of the solid-angle-weighted correlation, with np.cov's aweights."""
    h, w = mask.shape
    wts = np.repeat(row_solid_angles(h, w)[:, None], w, axis=1)[mask]
    rs = []
    for c in range(a.shape[2]):
        cov = np.cov(a[..., c][mask].astype(np.float64), b[..., c][mask].astype(np.float64), aweights=wts)
        rs.append(cov[0, 1] / math.sqrt(cov[0, 0] * cov[1, 1]))
    return float(np.mean(rs))


# ------------------------------------------------------------------------------------ input builders


def make_em(valid, radiance=None, depth=None, origin=ORIGIN) -> EnvironmentMap:
    valid = np.asarray(valid, bool)
    h, w = valid.shape
    radiance = np.full((h, w, 3), 0.25, np.float32) if radiance is None else np.asarray(radiance, np.float32)
    depth = np.full((h, w), 2.0, np.float32) if depth is None else np.asarray(depth, np.float32)
    return EnvironmentMap.from_arrays(radiance, depth, valid, origin)


def make_truth(valid, radiance=None, distance=None, origin=ORIGIN) -> dict:
    """The true map as run.py's ``groundtruth_envmap()`` returns it."""
    valid = np.asarray(valid, bool)
    h, w = valid.shape
    radiance = np.full((h, w, 3), 0.25, np.float32) if radiance is None else np.asarray(radiance, np.float32)
    distance = np.full((h, w), 2.0, np.float32) if distance is None else np.asarray(distance, np.float32)
    return {"radiance": radiance, "distance_m": distance, "valid": valid, "origin": np.asarray(origin, np.float64)}


def make_pipeline(em: EnvironmentMap, *, dropped: int = 0, has_lighting: bool = False, bands: int = 1, coeffs=None,
                  colours=None, transfer=None, albedo=None):
    """What ``AccuracyTracker.summary`` reads of a ``Pipeline``."""
    return SimpleNamespace(
        capture=SimpleNamespace(em=em), dropped_depth=dropped, has_lighting=has_lighting, bands=bands,
        coeffs=np.zeros((25, 3)) if coeffs is None else np.asarray(coeffs, np.float64), colours=colours,
        _transfer=transfer, _object=None if albedo is None else SimpleNamespace(albedo=albedo),
    )


def ccm(matrix, *, accepted: bool = True, mse: float = 0.01, n_pairs: int = 800, reason: str = "") -> CCMResult:
    return CCMResult(np.asarray(matrix, np.float64), mse, n_pairs, accepted, reason, "linear")


def stats(taken: int = 0, taken_freed: int = 0, averaged: int = 0) -> UpdateStats:
    return UpdateStats(samples=taken, touched=taken, taken=taken, taken_empty=taken, taken_closer=0, taken_trusted=0,
                       taken_removal=0, taken_freed=taken_freed, averaged=averaged)


def step(ts: int, *, colour_ts: int | None = None, reference: bool = False, fit: CCMResult | None = None,
         projected: bool = True, reason: str = "", n_pairs: int = 0, matrix=None, update: UpdateStats | None = None,
         raw_depth=None, raw_known=None, filled_depth=None, filled_known=None, bands: int = 3) -> DepthStep:
    if matrix is None:
        matrix = fit.matrix if fit is not None and fit.accepted else np.eye(3)
    cap = CaptureStep(ts, reference, fit, projected, reason, n_pairs, np.array(matrix, np.float64), update)
    z = np.zeros((2, 2))
    f = np.zeros((2, 2), bool)
    return DepthStep(
        timestamp_ns=ts, colour_timestamp_ns=ts if colour_ts is None else colour_ts, capture=cap,
        raw_depth_m=z if raw_depth is None else raw_depth, raw_known=f if raw_known is None else raw_known,
        filled_depth_m=z if filled_depth is None else filled_depth, filled_known=f if filled_known is None else filled_known,
        sh_updated=False, bands=bands,
    )


def summary_of(em: EnvironmentMap, truth: dict | None, tracker: AccuracyTracker | None = None, **pipeline_kw) -> dict:
    tracker = AccuracyTracker() if tracker is None else tracker
    return tracker.summary(make_pipeline(em, **pipeline_kw), truth)


# ------------------------------------------------------------------------------------------ coverage


def test_em_coverage_solid_angle_of_a_map_missing_a_band_of_rows():
    h, w = 12, 24
    valid = np.ones((h, w), bool)
    valid[3:7] = False  # rows 3..6 missing: θ ∈ [π/4, 7π/12]
    out = summary_of(make_em(valid), None)
    expected = 1.0 - band_cos(h, 3, 7) / 2.0  # (4π − 2π (cos(π/4) − cos(7π/12))) / 4π
    assert out["em_coverage_solid_angle"] == pytest.approx(expected, abs=COV_TOL)
    # cos(π/4) = √2/2, cos(7π/12) = −(√6 − √2)/4
    assert expected == pytest.approx(1.0 - (math.sqrt(2) + math.sqrt(6)) / 8.0, abs=1e-15)
    # a solid-angle fraction, not the pixel fraction (8/12 of the rows are valid)
    assert abs(out["em_coverage_solid_angle"] - 8 / 12) > 0.05


def test_em_coverage_solid_angle_partial_rows_and_northern_cap():
    h, w = 10, 20
    valid = np.zeros((h, w), bool)
    valid[:5] = True  # the northern hemisphere: exactly half the sphere
    assert summary_of(make_em(valid), None)["em_coverage_solid_angle"] == pytest.approx(0.5, abs=COV_TOL)
    valid = np.zeros((h, w), bool)
    valid[0, :5] = True  # a quarter of the polar row
    valid[9, ::2] = True  # half the southern polar row
    valid[4, 3] = True  # one equatorial pixel
    expected = (0.25 * band_cos(h, 0, 1) + 0.5 * band_cos(h, 9, 10) + band_cos(h, 4, 5) / w) / 2.0
    assert summary_of(make_em(valid), None)["em_coverage_solid_angle"] == pytest.approx(expected, abs=COV_TOL)


def test_em_coverage_is_the_fraction_of_the_truths_solid_angle():
    """em_coverage = Ω(em ∧ truth) / Ω(truth): pixels the map has but the truth lacks do not count,
    and the denominator is the truth's solid angle, not the map's."""
    h, w = 16, 32
    truth_valid = np.ones((h, w), bool)
    truth_valid[:3] = False  # the truth has no data in a northern cap (rows 0..2)
    em_valid = np.ones((h, w), bool)
    em_valid[6:10] = False  # the map misses an equatorial band (rows 6..9) but has the cap
    out = summary_of(make_em(em_valid), make_truth(truth_valid))
    truth_sa = band_cos(h, 3, h)  # (÷ 2π) rows 3..15
    both_sa = truth_sa - band_cos(h, 6, 10)
    assert out["em_coverage"] == pytest.approx(both_sa / truth_sa, abs=COV_TOL)
    # against the swapped reading Ω(em ∧ truth) / Ω(em)
    em_sa = 2.0 - band_cos(h, 6, 10)
    assert abs(out["em_coverage"] - both_sa / em_sa) > 0.05
    # and the whole-sphere figure is the map's own
    assert out["em_coverage_solid_angle"] == pytest.approx(em_sa / 2.0, abs=COV_TOL)


def test_em_coverage_of_a_scattered_mask_by_brute_force():
    rng = np.random.default_rng(7)
    h, w = 9, 18
    em_valid = rng.random((h, w)) < 0.6
    truth_valid = rng.random((h, w)) < 0.7
    out = summary_of(make_em(em_valid), make_truth(truth_valid))
    assert out["em_coverage"] == pytest.approx(solid_angle(em_valid & truth_valid) / solid_angle(truth_valid), abs=COV_TOL)
    assert out["em_coverage_solid_angle"] == pytest.approx(solid_angle(em_valid) / (4 * math.pi), abs=COV_TOL)


def test_an_empty_map_covers_nothing_and_has_no_image_errors():
    h, w = 8, 16
    out = summary_of(make_em(np.zeros((h, w), bool)), make_truth(np.ones((h, w), bool)))
    assert out["em_coverage_solid_angle"] == 0.0
    assert out["em_coverage"] == 0.0
    for key in ("em_ws_psnr_db", "em_sphere_correlation", "em_depth_median_abs_m"):
        assert key not in out


def test_without_a_truth_map_or_at_another_origin_only_the_maps_own_coverage():
    h, w = 8, 16
    valid = np.ones((h, w), bool)
    valid[:2] = False
    em = make_em(valid)
    for truth in (None, make_truth(np.ones((h, w), bool), origin=ORIGIN + [0.0, 0.1, 0.0])):
        out = summary_of(em, truth)
        assert out["em_coverage_solid_angle"] == pytest.approx(1.0 - band_cos(h, 0, 2) / 2.0, abs=COV_TOL)
        assert set(out) == {"depth_frames", "depth_frames_projected", "depth_frames_rejected", "depth_packets_dropped",
                            "em_coverage_solid_angle"}


def test_a_truth_map_without_data_leaves_em_coverage_out():
    h, w = 8, 16
    out = summary_of(make_em(np.ones((h, w), bool)), make_truth(np.zeros((h, w), bool)))
    assert "em_coverage" not in nan_keys(out)


# ------------------------------------------------------------------------------------------ WS-PSNR


def dyadic_truth(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Radiance in {0.25, 0.375, 0.5}: exact in float32, so offsets of 1/16 square exactly."""
    rng = np.random.default_rng(seed)
    return rng.choice(np.array([0.25, 0.375, 0.5], np.float32), size=(h, w, 3))


def test_ws_psnr_of_a_constant_offset_on_a_band_of_rows():
    h, w, delta = 16, 32, 1.0 / 16.0
    truth = dyadic_truth(h, w)
    est = truth.copy()
    est[5:9] += delta  # every channel of rows 5..8
    valid = np.ones((h, w), bool)
    out = summary_of(make_em(valid, est), make_truth(valid, truth))
    # WMSE = δ² Ω(rows 5..8) / Ω(sphere) = δ² (cos(5π/16) − cos(9π/16)) / 2; peak 1
    expected = -10.0 * math.log10(delta**2 * band_cos(h, 5, 9) / 2.0)
    assert out["em_ws_psnr_db"] == pytest.approx(expected, abs=DB_TOL)
    # the same with Sun et al.'s cos-latitude weights (proportional to the solid angle per row)
    expected_cos = -10.0 * math.log10(wmse(est, truth, valid, cos_latitude_weights(h, w)))
    assert out["em_ws_psnr_db"] == pytest.approx(expected_cos, abs=1e-9)
    # and not the unweighted PSNR (4 of 16 rows off: MSE δ²/4)
    assert abs(out["em_ws_psnr_db"] - (-10.0 * math.log10(delta**2 / 4))) > 0.5


def test_ws_psnr_counts_only_pixels_both_maps_have():
    h, w, delta = 16, 32, 1.0 / 8.0
    truth = dyadic_truth(h, w, seed=1)
    truth_valid = np.ones((h, w), bool)
    truth_valid[12:] = False
    truth[12:] = np.nan  # never read: the truth has no data there
    em_valid = np.ones((h, w), bool)
    em_valid[:2] = False
    est = dyadic_truth(h, w, seed=1)
    est[:2] = np.nan  # the map has no data there
    est[12:] = 1.0  # map data where the truth has none: not compared
    est[2:4, : w // 2] += delta  # half of rows 2..3 off by δ
    out = summary_of(make_em(em_valid, est), make_truth(truth_valid, truth))
    covered_sa = band_cos(h, 2, 12)  # ÷ 2π
    off_sa = band_cos(h, 2, 4) / 2.0  # half of each row
    expected = -10.0 * math.log10(delta**2 * off_sa / covered_sa)
    assert out["em_ws_psnr_db"] == pytest.approx(expected, abs=DB_TOL)
    assert math.isfinite(out["em_sphere_correlation"]) and math.isfinite(out["em_depth_median_abs_m"])


def test_ws_psnr_compares_maps_clipped_to_the_unit_peak():
    h, w, delta = 8, 16, 1.0 / 16.0
    truth = np.full((h, w, 3), 0.5, np.float32)
    truth[0:2] = 1.0
    truth[6:8] = 0.0
    est = truth.copy()
    est[0:2] = 1.5  # over the peak on both sides once clipped: no error
    est[6:8] = -0.25  # below zero: clipped to the truth's 0
    est[3] += delta  # the only error: row 3
    valid = np.ones((h, w), bool)
    out = summary_of(make_em(valid, est), make_truth(valid, truth))
    expected = -10.0 * math.log10(delta**2 * band_cos(h, 3, 4) / 2.0)
    assert out["em_ws_psnr_db"] == pytest.approx(expected, abs=DB_TOL)


def test_ws_psnr_of_identical_maps_is_infinite():
    h, w = 8, 16
    truth = dyadic_truth(h, w, seed=2)
    valid = np.ones((h, w), bool)
    out = summary_of(make_em(valid, truth), make_truth(valid, truth))
    assert out["em_ws_psnr_db"] == math.inf
    assert out["em_sphere_correlation"] == pytest.approx(1.0, abs=1e-12)
    assert out["em_depth_median_abs_m"] == 0.0


# ---------------------------------------------------------------------- correlation and map depth


def test_sphere_correlation_against_a_weighted_pearson():
    h, w = 12, 24
    rng = np.random.default_rng(3)
    truth = rng.random((h, w, 3)).astype(np.float32)
    valid = rng.random((h, w)) < 0.8
    affine = make_em(valid, 0.5 * truth + 0.1)
    assert summary_of(affine, make_truth(valid, truth))["em_sphere_correlation"] == pytest.approx(1.0, abs=1e-9)
    flipped = make_em(valid, 1.0 - truth)
    assert summary_of(flipped, make_truth(valid, truth))["em_sphere_correlation"] == pytest.approx(-1.0, abs=1e-9)
    est = (truth + 0.5 * rng.random((h, w, 3))).astype(np.float32)  # unclipped: the correlation takes raw radiance
    em_valid = valid.copy()
    em_valid[:3] = False
    out = summary_of(make_em(em_valid, est), make_truth(valid, truth))
    assert out["em_sphere_correlation"] == pytest.approx(weighted_pearson(est, truth, em_valid & valid), abs=1e-9)


def test_em_depth_median_is_over_covered_pixels():
    h, w = 6, 12
    truth_valid = np.ones((h, w), bool)
    truth_valid[5] = False
    gdist = np.full((h, w), 3.0, np.float32)
    em_valid = np.ones((h, w), bool)
    em_valid[0] = False
    depth = gdist.copy()
    depth[0] = 100.0  # not covered (map has no data)
    depth[5] = 100.0  # not covered (truth has no data)
    depth[1] += 0.5  # 12 pixels off by 0.5
    depth[2, :10] -= 0.25  # 10 pixels off by 0.25; the other 26 covered pixels are exact
    out = summary_of(make_em(em_valid, depth=depth), make_truth(truth_valid, distance=gdist))
    errors = [0.5] * 12 + [0.25] * 10 + [0.0] * (4 * w - 22)
    assert out["em_depth_median_abs_m"] == pytest.approx(float(np.median(errors)), abs=1e-6)
    assert out["em_depth_median_abs_m"] == pytest.approx(0.0, abs=1e-6)
    depth[3:5] += 0.125  # now 24 more off by 0.125: sorted |e| has 2 zeros, 24 × 0.125, 10 × 0.25, 12 × 0.5
    out = summary_of(make_em(em_valid, depth=depth), make_truth(truth_valid, distance=gdist))
    assert out["em_depth_median_abs_m"] == pytest.approx(0.125, abs=1e-6)


def test_a_constant_map_leaves_the_correlation_out():
    h, w = 8, 16
    valid = np.ones((h, w), bool)
    out = summary_of(make_em(valid), make_truth(valid))
    assert "em_sphere_correlation" not in nan_keys(out)


# --------------------------------------------------------------------------- a truth of another size


def test_truth_at_twice_the_resolution_is_box_averaged_over_its_valid_pixels():
    h, w = 6, 12
    rng = np.random.default_rng(4)
    grad = rng.choice(np.array([0.25, 0.5, 0.75, 1.0], np.float32), size=(2 * h, 2 * w, 3))
    gdist = rng.choice(np.array([1.0, 2.0, 3.0, 5.0], np.float32), size=(2 * h, 2 * w))
    gv = rng.random((2 * h, 2 * w)) < 0.6
    gv[0:2, 0:4] = False  # two whole blocks without data
    grad[~gv] = 7.0  # values under invalid truth pixels must not enter the averages
    gdist[~gv] = 50.0
    # brute force: a map pixel is valid when any of its 2×2 block is; values are means over those
    exp_valid = np.zeros((h, w), bool)
    exp_rad = np.zeros((h, w, 3))
    exp_dist = np.zeros((h, w))
    for i in range(h):
        for j in range(w):
            pix = [(2 * i + a, 2 * j + b) for a in range(2) for b in range(2) if gv[2 * i + a, 2 * j + b]]
            if pix:
                exp_valid[i, j] = True
                exp_rad[i, j] = np.mean([grad[p] for p in pix], axis=0)
                exp_dist[i, j] = np.mean([gdist[p] for p in pix])
    assert not exp_valid[0, 0] and not exp_valid[0, 1]
    em_valid = np.ones((h, w), bool)
    em_valid[h - 1] = False
    est = np.clip(exp_rad, 0, 1).astype(np.float32)
    delta = 0.125
    est[1] = np.clip(exp_rad[1] - delta, 0, 1)  # rows 1: off by δ wherever that stays in [0, 1]
    depth = (exp_dist + 0.5).astype(np.float32)
    out = summary_of(make_em(em_valid, est, depth), make_truth(gv, grad, gdist))
    assert out["em_truth_downsampled"] == 1.0
    covered = em_valid & exp_valid
    assert out["em_coverage"] == pytest.approx(solid_angle(covered) / solid_angle(exp_valid), abs=COV_TOL)
    sa = np.repeat(row_solid_angles(h, w)[:, None], w, axis=1)
    expected_db = -10.0 * math.log10(wmse(est, np.clip(exp_rad, 0, 1), covered, sa))
    assert out["em_ws_psnr_db"] == pytest.approx(expected_db, abs=1e-5)  # float32 block means
    assert out["em_depth_median_abs_m"] == pytest.approx(0.5, abs=1e-5)


def test_truth_of_a_non_integer_factor_is_sampled_at_the_nearest_pixel_centre():
    h, w, H, W = 4, 8, 6, 12  # factor 1.5
    rng = np.random.default_rng(5)
    grad = rng.random((H, W, 3)).astype(np.float32)
    gdist = rng.uniform(1.0, 4.0, (H, W)).astype(np.float32)
    gv = rng.random((H, W)) < 0.7
    # map pixel (i, j) has its centre at θ = π (i + ½)/h, φ-index (j + ½)/w: the truth pixel holding it
    rows = [math.floor(math.pi * (i + 0.5) / h / (math.pi / H)) for i in range(h)]
    cols = [math.floor((j + 0.5) / w * W) for j in range(w)]
    assert rows == [0, 2, 3, 5] and cols == [0, 2, 3, 5, 6, 8, 9, 11]
    exp_valid = gv[np.ix_(rows, cols)]
    exp_dist = gdist[np.ix_(rows, cols)]
    em_valid = np.ones((h, w), bool)
    out = summary_of(make_em(em_valid, depth=exp_dist + 0.25), make_truth(gv, grad, gdist))
    assert out["em_truth_downsampled"] == 1.0
    assert out["em_coverage"] == 1.0
    assert out["em_depth_median_abs_m"] == pytest.approx(0.25, abs=1e-6)
    em_valid[0] = False
    out = summary_of(make_em(em_valid), make_truth(gv, grad, gdist))
    assert out["em_coverage"] == pytest.approx(solid_angle(em_valid & exp_valid) / solid_angle(exp_valid), abs=COV_TOL)


def test_truth_of_the_same_size_is_not_downsampled_and_ignores_nan_where_invalid():
    h, w = 8, 16
    gv = np.ones((h, w), bool)
    gv[7] = False
    grad = dyadic_truth(h, w, seed=6)
    grad[7] = np.nan
    gdist = np.full((h, w), 2.0, np.float32)
    gdist[7] = np.nan
    est = np.nan_to_num(grad)  # the truth where it has data, zeros below
    out = summary_of(make_em(np.ones((h, w), bool), est, np.full((h, w), 2.0)), make_truth(gv, grad, gdist))
    assert "em_truth_downsampled" not in out
    assert out["em_ws_psnr_db"] == math.inf
    assert out["em_depth_median_abs_m"] == 0.0


def test_downsampled_truth_ignores_nan_where_invalid():
    h, w = 4, 8
    grad = np.full((2 * h, 2 * w, 3), 0.5, np.float32)
    gdist = np.full((2 * h, 2 * w), 2.0, np.float32)
    gv = np.ones((2 * h, 2 * w), bool)
    gv[0, 0] = False
    grad[0, 0] = np.nan
    gdist[0, 0] = np.nan
    out = summary_of(make_em(np.ones((h, w), bool), np.full((h, w, 3), 0.5)), make_truth(gv, grad, gdist))
    assert out["em_ws_psnr_db"] == math.inf and out["em_depth_median_abs_m"] == 0.0


# ------------------------------------------------------------------------- colour-correction matrix


G_REF = np.array([1.2, 1.0, 0.8])  # gains of the reference colour frame
G_A = np.array([0.6, 1.0, 1.6])  # → M_true = diag(G_REF / G_A) = diag(2, 1, 0.5)
G_B = np.array([2.4, 0.5, 0.4])  # → M_true = diag(0.5, 2, 2)


def ccm_tracker(matrices: dict[int, np.ndarray]) -> tuple[AccuracyTracker, list[dict]]:
    """Colour frames 100 (reference), 200 (G_A), 300 (G_B); depth steps paired with them, the
    reference first, then accepted fits with the given matrices."""
    tr = AccuracyTracker()
    tr.on_colour(100, {"gains": G_REF})
    tr.on_colour(200, {"gains": G_A})
    tr.on_colour(300, {"gains": G_B})
    rows = [tr.on_depth(step(1, colour_ts=100, reference=True), {})]
    for k, (colour_ts, m) in enumerate(matrices.items()):
        rows.append(tr.on_depth(step(2 + k, colour_ts=colour_ts, fit=ccm(m), n_pairs=800), {}))
    return tr, rows


def test_ccm_error_of_the_exact_matrix_is_zero():
    tr, rows = ccm_tracker({200: np.diag([2.0, 1.0, 0.5]), 300: np.diag([0.5, 2.0, 2.0])})
    assert "ccm_rel_error" not in rows[0]  # the reference frame has no fit
    assert rows[1]["ccm_rel_error"] == pytest.approx(0.0, abs=1e-15)
    assert rows[2]["ccm_rel_error"] == pytest.approx(0.0, abs=1e-15)
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert out["ccm_matrix_rel_error_median"] == pytest.approx(0.0, abs=1e-15)
    assert out["ccm_matrix_rel_error_p95"] == pytest.approx(0.0, abs=1e-15)


def test_ccm_error_is_the_relative_frobenius_distance_to_the_true_matrix():
    m_a = np.diag([2.0, 1.0, 0.5])
    m_a[0, 1] = 0.3  # ‖E‖ = 0.3, ‖M_true‖ = √(4 + 1 + 0.25)
    m_b = np.diag([0.5, 2.0, 2.0]) * 1.1  # ‖E‖ = 0.1 ‖M_true‖
    tr, rows = ccm_tracker({200: m_a, 300: m_b})
    e_a, e_b = 0.3 / math.sqrt(5.25), 0.1
    assert rows[1]["ccm_rel_error"] == pytest.approx(e_a, rel=REL_TOL)
    assert rows[2]["ccm_rel_error"] == pytest.approx(e_b, rel=REL_TOL)
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert out["ccm_matrix_rel_error_median"] == pytest.approx((e_a + e_b) / 2, rel=REL_TOL)
    assert out["ccm_matrix_rel_error_p95"] == pytest.approx(percentile_linear([e_a, e_b], 95), rel=REL_TOL)


def test_ccm_error_statistics_over_many_frames():
    rng = np.random.default_rng(8)
    tr = AccuracyTracker()
    tr.on_colour(10, {"gains": G_REF})
    tr.on_depth(step(10, reference=True), {})
    true = np.diag([2.0, 1.0, 0.5])
    expected = []
    for k in range(11):
        ts = 1000 + k
        tr.on_colour(ts, {"gains": G_A})
        scale = float(rng.uniform(0.0, 0.3))
        expected.append(scale)
        tr.on_depth(step(ts, fit=ccm(true * (1.0 + scale))), {})
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert out["ccm_matrix_rel_error_median"] == pytest.approx(sorted(expected)[5], rel=1e-12)
    assert out["ccm_matrix_rel_error_p95"] == pytest.approx(percentile_linear(expected, 95), rel=1e-12)


def test_ccm_error_only_for_accepted_fits_with_known_gains_after_a_reference():
    tr = AccuracyTracker()
    tr.on_colour(100, {"gains": G_A})
    rows = [tr.on_depth(step(1, colour_ts=100, fit=ccm(np.eye(3))), {})]  # before any reference frame
    tr.on_colour(200, {"gains": G_REF})
    rows.append(tr.on_depth(step(2, colour_ts=200, reference=True), {}))
    tr.on_colour(300, {"gains": G_A})
    rejected = ccm(np.eye(3), accepted=False, reason="too few pairs (12 < 500)", n_pairs=12)
    rows.append(tr.on_depth(step(3, colour_ts=300, fit=rejected, projected=False, reason=rejected.reason, n_pairs=12), {}))
    rows.append(tr.on_depth(step(4, colour_ts=400, fit=ccm(np.eye(3))), {}))  # colour frame without gains
    rows.append(tr.on_depth(step(5, colour_ts=300, fit=ccm(np.diag([2.0, 1.0, 0.5]) * 1.25)), {}))
    assert [("ccm_rel_error" in r) for r in rows] == [False, False, False, False, True]
    assert rows[4]["ccm_rel_error"] == pytest.approx(0.25, rel=REL_TOL)
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert out["ccm_matrix_rel_error_median"] == pytest.approx(0.25, rel=REL_TOL)
    assert out["ccm_matrix_rel_error_p95"] == pytest.approx(0.25, rel=REL_TOL)


def test_no_accepted_fit_leaves_the_ccm_figures_out():
    tr = AccuracyTracker()
    tr.on_colour(1, {"gains": G_REF})
    tr.on_depth(step(1, reference=True), {})
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert not any(k.startswith("ccm_") for k in out)


# ----------------------------------------------------------------------------------- hole filling


def hole_frame():
    """A 6×8 frame: truth 2.0 m; the left half known before filling (error 0.25 m), and six holes
    filled with known errors; NaN wherever a depth is not known (or the truth invalid)."""
    h, w = 6, 8
    truth = np.full((h, w), 2.0)
    tv = np.ones((h, w), bool)
    raw_known = np.zeros((h, w), bool)
    raw_known[:, :4] = True
    raw_known[5, 0] = False  # a hole inside the known half
    raw_depth = np.where(raw_known, truth + 0.25, np.nan)
    filled_known = raw_known.copy()
    filled_depth = raw_depth.copy()
    fills = {(5, 0): 0.5, (0, 4): -0.125, (1, 4): 0.375, (2, 5): 1.0, (3, 6): -0.75, (4, 7): 0.0625}
    for (v, u), e in fills.items():
        filled_known[v, u] = True
        filled_depth[v, u] = 2.0 + e
    filled_known[5, 7] = True  # filled, but the truth has no depth there: not counted
    filled_depth[5, 7] = 9.0
    tv[5, 7] = False
    truth[5, 7] = np.nan
    tv[0, 0] = False  # a raw pixel without truth: not counted either
    truth[0, 0] = np.nan
    gt = {"true_depth_m": truth, "true_valid": tv}
    return raw_depth, raw_known, filled_depth, filled_known, gt, [abs(e) for e in fills.values()], int(raw_known.sum()) - 1


def test_hole_filling_error_counts_only_the_filled_pixels():
    raw_depth, raw_known, filled_depth, filled_known, gt, fill_err, n_raw = hole_frame()
    tr = AccuracyTracker()
    row = tr.on_depth(step(1, raw_depth=raw_depth, raw_known=raw_known, filled_depth=filled_depth,
                           filled_known=filled_known), gt)
    assert row["filled_pixels"] == len(fill_err) == 6
    assert row["filled_depth_mae_m"] == pytest.approx(np.mean(fill_err), abs=1e-12)
    assert row["raw_depth_mae_m"] == pytest.approx(0.25, abs=1e-12)
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert out["hole_filling_depth_mae_m"] == pytest.approx(np.mean(fill_err), abs=1e-12)
    assert out["hole_filling_depth_rmse_m"] == pytest.approx(math.sqrt(np.mean(np.square(fill_err))), abs=1e-12)
    assert out["hole_filling_depth_median_abs_m"] == pytest.approx((0.375 + 0.5) / 2, abs=1e-12)
    assert out["ingest_depth_mae_m"] == pytest.approx(0.25, abs=1e-12)
    assert out["ingest_depth_rmse_m"] == pytest.approx(0.25, abs=1e-12)
    assert n_raw == 22
    assert all(math.isfinite(v) for v in out.values())


def test_depth_errors_pool_pixels_over_frames():
    h, w = 3, 4
    truth = np.full((h, w), 1.5)
    tv = np.ones((h, w), bool)
    tr = AccuracyTracker()
    # frame A: one raw pixel (error 0.5), one filled (error 1.0)
    rk = np.zeros((h, w), bool)
    rk[0, 0] = True
    fk = rk.copy()
    fk[0, 1] = True
    rd = np.where(rk, 2.0, 0.0)
    fd = np.where(fk, 2.5, 0.0)
    fd[0, 0] = 2.0
    row_a = tr.on_depth(step(1, raw_depth=rd, raw_known=rk, filled_depth=fd, filled_known=fk),
                        {"true_depth_m": truth, "true_valid": tv})
    # frame B: three raw pixels (error 0.125), three filled (errors 0.125, 0.25, 0.375)
    rk = np.zeros((h, w), bool)
    rk[1, :3] = True
    fk = rk.copy()
    fk[2, :3] = True
    rd = np.where(rk, 1.625, 0.0)
    fd = rd.copy()
    fd[2, :3] = 1.5 - np.array([0.125, 0.25, 0.375])
    row_b = tr.on_depth(step(2, raw_depth=rd, raw_known=rk, filled_depth=fd, filled_known=fk),
                        {"true_depth_m": truth, "true_valid": tv})
    assert (row_a["filled_pixels"], row_b["filled_pixels"]) == (1, 3)
    assert row_a["filled_depth_mae_m"] == pytest.approx(1.0) and row_b["filled_depth_mae_m"] == pytest.approx(0.25)
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    fills = [1.0, 0.125, 0.25, 0.375]
    raws = [0.5, 0.125, 0.125, 0.125]
    assert out["hole_filling_depth_mae_m"] == pytest.approx(np.mean(fills), abs=1e-12)  # 0.4375, not (1 + 0.25)/2
    assert out["hole_filling_depth_rmse_m"] == pytest.approx(math.sqrt(np.mean(np.square(fills))), abs=1e-12)
    assert out["hole_filling_depth_median_abs_m"] == pytest.approx(0.3125, abs=1e-12)
    assert out["ingest_depth_mae_m"] == pytest.approx(np.mean(raws), abs=1e-12)
    assert out["ingest_depth_rmse_m"] == pytest.approx(math.sqrt(np.mean(np.square(raws))), abs=1e-12)


def test_no_filled_pixels_leaves_the_hole_filling_figures_out():
    raw_depth, raw_known, _, _, gt, _, _ = hole_frame()
    tr = AccuracyTracker()
    row = tr.on_depth(step(1, raw_depth=raw_depth, raw_known=raw_known, filled_depth=raw_depth, filled_known=raw_known), gt)
    assert row["filled_pixels"] == 0
    assert math.isnan(row["filled_depth_mae_m"])
    assert row["raw_depth_mae_m"] == pytest.approx(0.25, abs=1e-12)
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert not any(k.startswith("hole_filling") for k in out)
    assert out["ingest_depth_mae_m"] == pytest.approx(0.25, abs=1e-12)


def test_depth_packets_without_truth_have_no_depth_errors():
    raw_depth, raw_known, filled_depth, filled_known, _, _, _ = hole_frame()
    tr = AccuracyTracker()
    row = tr.on_depth(step(1, raw_depth=raw_depth, raw_known=raw_known, filled_depth=filled_depth,
                           filled_known=filled_known), {})
    assert not {"raw_depth_mae_m", "filled_depth_mae_m", "filled_pixels"} & set(row)
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert not any(k.startswith(("hole_filling", "ingest")) for k in out)
    # nothing known at all, though truth is there: NaN per frame, nothing in the summary
    empty = np.zeros((3, 4), bool)
    tr = AccuracyTracker()
    row = tr.on_depth(step(1, raw_depth=np.zeros((3, 4)), raw_known=empty, filled_depth=np.zeros((3, 4)), filled_known=empty),
                      {"true_depth_m": np.ones((3, 4)), "true_valid": np.ones((3, 4), bool)})
    assert math.isnan(row["raw_depth_mae_m"]) and math.isnan(row["filled_depth_mae_m"]) and row["filled_pixels"] == 0
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    assert not any(k.startswith(("hole_filling", "ingest")) for k in out)


def test_truth_at_twice_the_frame_resolution_is_strided():
    """The Kinect path runs on a [::2, ::2] frame while the truth stays full size."""
    raw_depth, raw_known, filled_depth, filled_known, gt, fill_err, _ = hole_frame()
    big = np.full((12, 16), 100.0)  # off-stride pixels are wrong on purpose
    big_tv = np.ones((12, 16), bool)
    big[::2, ::2] = gt["true_depth_m"]
    big_tv[::2, ::2] = gt["true_valid"]
    tr = AccuracyTracker()
    row = tr.on_depth(step(1, raw_depth=raw_depth, raw_known=raw_known, filled_depth=filled_depth,
                           filled_known=filled_known), {"true_depth_m": big, "true_valid": big_tv})
    assert row["filled_pixels"] == 6
    assert row["filled_depth_mae_m"] == pytest.approx(np.mean(fill_err), abs=1e-12)
    assert row["raw_depth_mae_m"] == pytest.approx(0.25, abs=1e-12)


# ------------------------------------------------------------------------- rows and frame counts


def test_rows_and_frame_counts():
    tr = AccuracyTracker()
    tr.on_colour(1, {"gains": G_REF})
    tr.on_colour(2, {})  # a colour frame without gains is fine
    r0 = tr.on_depth(step(1, reference=True, update=stats(taken=50), bands=2), {})
    r1 = tr.on_depth(step(2, fit=ccm(np.eye(3), accepted=False, reason="mse 0.08 > 0.05", mse=0.08, n_pairs=700),
                          projected=False, reason="mse 0.08 > 0.05", n_pairs=700), {})
    r2 = tr.on_depth(step(3, fit=ccm(np.eye(3), accepted=False, reason="too few pairs (12 < 500)", mse=0.02, n_pairs=12),
                          projected=False, reason="too few pairs (12 < 500)", n_pairs=12), {})
    r3 = tr.on_depth(step(4, fit=ccm(np.eye(3), mse=0.001, n_pairs=900), projected=False, reason="frozen", n_pairs=900), {})
    r4 = tr.on_depth(step(5, fit=ccm(np.eye(3), mse=0.002, n_pairs=1000), n_pairs=1000,
                          update=stats(taken=30, taken_freed=4, averaged=7), bands=4), {})
    assert (r0["reference"], r0["projected"], r0["reason"], r0["taken"], r0["bands"]) == (True, True, "", 50, 2)
    assert math.isnan(r0["ccm_mse"]) and r0["n_pairs"] == 0
    assert (r1["reason"], r1["ccm_mse"], r1["n_pairs"], r1["taken"]) == ("mse 0.08 > 0.05", 0.08, 700, 0)
    assert r2["reason"] == "too few pairs"  # the detail in parentheses is dropped
    assert r3["reason"] == "frozen"
    assert (r4["taken"], r4["taken_freed"], r4["averaged"], r4["bands"], r4["ccm_mse"]) == (30, 4, 7, 4, 0.002)
    assert [r["timestamp_ns"] for r in tr.rows] == [1, 2, 3, 4, 5]
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr, dropped=3)
    assert out["depth_frames"] == 5
    assert out["depth_frames_projected"] == 2
    assert out["depth_frames_rejected"] == 2  # frozen is not a rejection
    assert out["depth_packets_dropped"] == 3


def test_summary_of_an_empty_run():
    out = summary_of(make_em(np.zeros((4, 8), bool)), None)
    assert out == {"depth_frames": 0, "depth_frames_projected": 0, "depth_frames_rejected": 0,
                   "depth_packets_dropped": 0, "em_coverage_solid_angle": 0.0}


# ---------------------------------------------------------------------------------------- lighting

# A true map linear in z = cos θ, L(d) = a + b z (grey), has the closed forms (orthonormal real SH,
# Y_00 = 1/√(4π), Y_10 = √(3/(4π)) z): L_00 = a √(4π), L_10 = b √(4π/3), every other coefficient 0,
# and irradiance E(n) = π a + (2π/3) b n_z.
LA, LB = 0.5, 0.3
LH, LW = 64, 128  # fine enough that the equirect sums match the integrals to ~1e-4


def linear_z_truth() -> dict:
    z = np.cos(math.pi * (np.arange(LH) + 0.5) / LH)
    rad = np.repeat((LA + LB * z)[:, None, None], LW, axis=1).repeat(3, axis=2).astype(np.float32)
    return make_truth(np.ones((LH, LW), bool), rad)


def closed_form_coeffs(bands: int, scale: float = 1.0) -> np.ndarray:
    c = np.zeros((25, 3))
    c[0] = LA * math.sqrt(4 * math.pi) * scale
    if bands > 1:
        c[2] = LB * math.sqrt(4 * math.pi / 3) * scale
    return c


def fib_z(n: int = 512) -> np.ndarray:
    """z of the n Fibonacci-sphere normals: uniform in z, z_i = 1 − (2i + 1)/n."""
    return 1.0 - (2.0 * np.arange(n) + 1.0) / n


def test_lighting_errors_of_the_exact_coefficients():
    em = make_em(np.ones((LH // 4, LW // 4), bool))
    out = summary_of(em, linear_z_truth(), has_lighting=True, bands=2, coeffs=closed_form_coeffs(2))
    assert out["sh_coeff_rel_error"] == pytest.approx(0.0, abs=1e-3)
    assert out["irradiance_rel_error_mean"] == pytest.approx(0.0, abs=1e-3)
    assert out["irradiance_rel_error_vs_true"] == pytest.approx(0.0, abs=1e-3)
    assert "shading_rel_rmse" not in out  # no object shaded


def test_lighting_errors_of_scaled_coefficients_and_band_truncation():
    eps = 0.1
    em = make_em(np.ones((LH // 4, LW // 4), bool))
    out = summary_of(em, linear_z_truth(), has_lighting=True, bands=2, coeffs=closed_form_coeffs(2, 1 + eps))
    assert out["sh_coeff_rel_error"] == pytest.approx(eps, rel=1e-3)
    assert out["irradiance_rel_error_mean"] == pytest.approx(eps, rel=1e-3)
    assert out["irradiance_rel_error_vs_true"] == pytest.approx(eps, rel=1e-3)
    # one band: exact against the 1-band truth, but against the true irradiance it misses (2π/3) b z
    out = summary_of(em, linear_z_truth(), has_lighting=True, bands=1, coeffs=closed_form_coeffs(2))
    assert out["sh_coeff_rel_error"] == pytest.approx(0.0, abs=1e-3)
    assert out["irradiance_rel_error_mean"] == pytest.approx(0.0, abs=1e-3)
    z = fib_z()
    true_e = math.pi * LA + 2 * math.pi / 3 * LB * z
    expected = float(np.mean(np.abs(math.pi * LA - true_e) / true_e))
    assert out["irradiance_rel_error_vs_true"] == pytest.approx(expected, rel=1e-3)
    # ½∫ |(2/3) b z| / (a + (2/3) b z) dz, the continuous mean, is what 512 points approximate
    k = 2 * LB / (3 * LA)
    continuous = 0.5 * ((k - math.log(1 + k)) + (-k - math.log(1 - k))) / k
    assert expected == pytest.approx(continuous, rel=1e-4)


def test_shading_error_against_the_object_shaded_by_the_true_map():
    transfer = np.array([[1.0], [2.0], [0.5], [3.0]], np.float32)  # unshadowed vertices, 1 band
    albedo = 0.6
    em = make_em(np.ones((LH // 4, LW // 4), bool))
    # prt.shade: (albedo / π) Σ_k L_k T_k with the 1-band truth L_00 = a √(4π)
    ref = (albedo / math.pi) * LA * math.sqrt(4 * math.pi) * transfer[:, :1].astype(np.float64) * np.ones(3)
    kw = dict(has_lighting=True, bands=1, coeffs=closed_form_coeffs(1), transfer=transfer, albedo=albedo)
    out = summary_of(em, linear_z_truth(), colours=ref.astype(np.float32), **kw)
    assert out["shading_rel_rmse"] == pytest.approx(0.0, abs=1e-3)
    out = summary_of(em, linear_z_truth(), colours=(1.2 * ref).astype(np.float32), **kw)
    assert out["shading_rel_rmse"] == pytest.approx(0.2, rel=1e-3)
    out = summary_of(em, linear_z_truth(), colours=np.zeros((4, 3), np.float32), **kw)
    assert out["shading_rel_rmse"] == pytest.approx(1.0, rel=1e-6)


def test_no_lighting_figures_before_the_pipeline_has_lighting():
    em = make_em(np.ones((8, 16), bool))
    out = summary_of(em, make_truth(np.ones((8, 16), bool)), has_lighting=False)
    assert not {"sh_coeff_rel_error", "irradiance_rel_error_mean", "irradiance_rel_error_vs_true",
                "shading_rel_rmse"} & set(out)


def test_a_black_true_map_leaves_the_irradiance_errors_out():
    h, w = 8, 16
    truth = make_truth(np.ones((h, w), bool), np.zeros((h, w, 3)))
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # numpy's "mean of empty slice"
        out = summary_of(make_em(np.ones((h, w), bool)), truth, has_lighting=True, bands=1, coeffs=np.zeros((25, 3)))
    assert not {"irradiance_rel_error_mean", "irradiance_rel_error_vs_true"} & set(nan_keys(out))


# ------------------------------------------------------------------------------------- the rest


def test_fibonacci_sphere():
    d = fibonacci_sphere(512)
    assert d.shape == (512, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(d[:, 2], fib_z(512), atol=1e-12)
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=1e-2)  # nearly uniform: centred


def test_summary_is_json_serialisable():
    raw_depth, raw_known, filled_depth, filled_known, gt, _, _ = hole_frame()
    tr, _ = ccm_tracker({200: np.diag([2.0, 1.0, 0.5]) * 1.05})
    tr.on_depth(step(9, raw_depth=raw_depth, raw_known=raw_known, filled_depth=filled_depth, filled_known=filled_known), gt)
    h, w = 8, 16
    truth = dyadic_truth(h, w, seed=9)
    est = truth.copy()
    est[2] += 1.0 / 16
    out = summary_of(make_em(np.ones((h, w), bool), est), make_truth(np.ones((h, w), bool), truth), tr)
    back = json.loads(json.dumps(out, allow_nan=False))
    assert back == out
    assert all(isinstance(v, (int, float)) and math.isfinite(v) for v in out.values())


# ------------------------------------------------------------------------------ bounded memory


def random_depth_frame(rng, h: int = 12, w: int = 16):
    """A frame with random raw and filled pixels and random errors, and its truth."""
    truth = rng.uniform(0.5, 4.0, (h, w))
    tv = rng.random((h, w)) > 0.1
    raw_known = rng.random((h, w)) > 0.5
    filled_known = raw_known | (rng.random((h, w)) > 0.4)
    raw_depth = truth + rng.normal(0.0, 0.01, (h, w))
    filled_depth = np.where(raw_known, raw_depth, truth + rng.normal(0.0, 0.05, (h, w)))
    raw_depth[~raw_known] = np.nan
    filled_depth[~filled_known] = np.nan
    raw = raw_known & tv
    filled = filled_known & ~raw_known & tv
    return (raw_depth, raw_known, filled_depth, filled_known, {"true_depth_m": truth, "true_valid": tv},
            np.abs(raw_depth[raw] - truth[raw]), np.abs(filled_depth[filled] - truth[filled]))


def feed_random_session(tracker: AccuracyTracker, n: int, seed: int = 0):
    """n depth frames with truth, each after a colour frame with gains, the first a reference; returns
    the per-pixel errors and the CCM errors, for a brute-force summary."""
    rng = np.random.default_rng(seed)
    raws, fills, ccms = [], [], []
    tracker.on_colour(0, {"gains": G_REF})
    tracker.on_depth(step(0, reference=True), {})
    true = np.diag(G_REF / G_A)
    for k in range(1, n + 1):
        rd, rk, fd, fk, gt, e_raw, e_fill = random_depth_frame(rng)
        tracker.on_colour(k, {"gains": G_A})
        scale = float(rng.uniform(0.0, 0.3))
        tracker.on_depth(step(k, fit=ccm(true * (1.0 + scale)), raw_depth=rd, raw_known=rk, filled_depth=fd,
                              filled_known=fk), gt)
        raws.append(e_raw)
        fills.append(e_fill)
        ccms.append(scale)
    return np.concatenate(raws), np.concatenate(fills), np.array(ccms)


def brute_force_summary(raws, fills, ccms) -> dict:
    return {"ingest_depth_mae_m": raws.mean(), "ingest_depth_rmse_m": math.sqrt(np.mean(raws**2)),
            "hole_filling_depth_mae_m": fills.mean(), "hole_filling_depth_rmse_m": math.sqrt(np.mean(fills**2)),
            "hole_filling_depth_median_abs_m": float(np.median(fills)),
            "ccm_matrix_rel_error_median": float(np.median(ccms)),
            "ccm_matrix_rel_error_p95": percentile_linear(ccms, 95)}


@pytest.mark.parametrize("exact_values,median_rel", [(2**20, 1e-12), (64, 5.1e-5)])
def test_summary_equals_a_brute_force_computation(exact_values, median_rel):
    """Running sums give the means exactly (to rounding); the medians are exact while the values fit
    in ``exact_values``, and within half a bin (5e-5 relative) once binned."""
    tr = AccuracyTracker(exact_values=exact_values)
    raws, fills, ccms = feed_random_session(tr, 200, seed=5)
    assert fills.size > 5000 and ccms.size == 200
    out = summary_of(make_em(np.ones((4, 8), bool)), None, tr)
    want = brute_force_summary(raws, fills, ccms)
    for key, value in want.items():
        rel = median_rel if ("median" in key or "p95" in key) else 1e-12
        assert out[key] == pytest.approx(value, rel=rel), key
    assert out["depth_frames"] == 201 and out["depth_frames_projected"] == 201
    # the rows, read back from disk, are those on_depth returned, NaN and types included
    rows = list(tr.rows)
    assert len(rows) == len(tr.rows) == 201
    assert [r["timestamp_ns"] for r in rows] == list(range(201))
    assert math.isnan(rows[0]["ccm_mse"]) and rows[1]["ccm_mse"] == 0.01 and rows[1]["reference"] is False
    assert rows[5]["ccm_rel_error"] == pytest.approx(ccms[4], rel=1e-12)
    assert json.dumps(list(tr.rows)) == json.dumps(rows)  # read again: the same (NaN as NaN)


def retained_after(n: int) -> tuple[int, int]:
    """(the tracker's retained_bytes, the Python heap it holds by tracemalloc) after n frames."""
    import gc
    import tracemalloc

    gc.collect()
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    tr = AccuracyTracker(exact_values=256)  # both sessions pass it, the CCM errors too
    feed_random_session(tr, n, seed=1)  # the errors it returns are dropped before measuring
    gc.collect()
    held = tracemalloc.get_traced_memory()[0] - base
    tracemalloc.stop()
    return tr.retained_bytes(), held


def test_the_trackers_memory_does_not_grow_with_the_number_of_frames():
    small, big = retained_after(300), retained_after(900)
    assert small[0] == big[0]  # past exact_values and GAINS_KEPT colour frames: a fixed size
    # The heap it holds by tracemalloc: a per-frame list of rows or of float errors would add at least
    # 600 × 8 bytes; what is allowed is noise (the allocator's pools).
    assert big[1] - small[1] < 4096, (small, big)
