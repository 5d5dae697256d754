"""Each stage's error against ground truth, accumulated over a run (simulated live or replayed).

Ground truth comes from wherever the run has it: the simulator's packets, or the ``groundtruth/``
folder of a recorded log (per-packet arrays, and ``groundtruth/envmap.npz``, the true map at the end
of the session, written by ``simulate``). Metrics whose truth is missing are left out, never guessed.

Per depth packet: raw and hole-filled depth error (pixels known after filling but not before, against
the true z-depth), and, for accepted correction matrices, the error of the matrix against the true one
(the sensor's per-channel gains: M_true = diag(g_reference / g_frame)). At the end: the EM against the
true map (coverage of its solid angle, WS-PSNR on covered pixels, depth error), the SH coefficients,
the irradiance over the sphere, and the object's shading against the same computed from the true map.

Memory does not grow with the session: per-pixel errors go into running sums (mean, RMSE) and into
:class:`StreamQuantiles` (medians, p95), which keeps values exactly up to a fixed count and a fixed
log-binned histogram beyond it; per-frame rows are spooled to a temporary file, read back by
:attr:`AccuracyTracker.rows`; only the last colour frames' gains are kept.
"""

from __future__ import annotations

import json
import math
import re
import tempfile
from collections.abc import Iterator

import numpy as np

from rgbd_envmap import metrics, sh
from rgbd_envmap.pipeline import DepthStep, Pipeline

__all__ = ["AccuracyTracker", "StreamQuantiles", "fibonacci_sphere"]


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) nearly uniform unit vectors."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _downsample_truth(radiance: np.ndarray, distance: np.ndarray, valid: np.ndarray, shape: tuple[int, int]):
    """The true map box-averaged (over its valid pixels) to a map ``shape`` whose size divides it (a
    pixel is valid when any of its block is), else sampled at the nearest pixel centre."""
    H, W = valid.shape
    h, w = shape
    if H % h or W % w or H // h != W // w:
        # not an integer factor: the truth at the nearest pixel centre of each map pixel
        rows = np.minimum(((np.arange(h) + 0.5) * H / h).astype(int), H - 1)
        cols = np.minimum(((np.arange(w) + 0.5) * W / w).astype(int), W - 1)
        return radiance[rows][:, cols], distance[rows][:, cols], valid[rows][:, cols]
    k = H // h
    v = valid.reshape(h, k, w, k)
    n = v.sum(axis=(1, 3)).astype(np.float32)
    # Selected, not multiplied by the mask: what lies under an invalid pixel (NaN is allowed) counts nowhere.
    with np.errstate(invalid="ignore", divide="ignore"):
        rad = np.where(v[..., None], radiance.reshape(h, k, w, k, 3), 0).sum(axis=(1, 3)) / n[..., None]
        dist = np.where(v, distance.reshape(h, k, w, k), 0).sum(axis=(1, 3)) / n
    ok = n > 0
    return np.where(ok[..., None], rad, 0).astype(np.float32), np.where(ok, dist, 0).astype(np.float32), ok


class StreamQuantiles:
    """Quantiles of a stream of non-negative values in bounded memory.

    Up to ``exact_limit`` values are kept as they are, and :meth:`quantile` is ``np.percentile``'s
    (linear interpolation between order statistics) exactly. Past it, the values go into a fixed
    histogram of log-spaced bins of relative width ``rel_width`` over [``low``, ``high``] (2.2 MiB at
    the defaults), plus an under- and an overflow bin; an order statistic is then its bin's geometric
    centre clamped to the exact minimum and maximum seen, within ``rel_width`` / 2 of the exact one
    (relative) for values in the range, within ``low`` (absolute) below it. Sums of values and of
    their squares, the count, the minimum and the maximum are exact (float64 running sums)."""

    def __init__(self, exact_limit: int = 2**20, rel_width: float = 1e-4, low: float = 1e-9, high: float = 1e3,
                 *, quantiles: bool = True) -> None:
        self.exact_limit = int(exact_limit)
        self._quantiles = quantiles  # False: the sums, count, minimum and maximum only
        self._log_low = math.log(low)
        self._log_step = math.log1p(rel_width)
        self._n_bins = int(math.ceil((math.log(high) - self._log_low) / self._log_step))
        self._low = low
        self._chunks: list[np.ndarray] = []
        self._n_chunked = 0
        self._hist: np.ndarray | None = None  # [under, bins..., over] once past exact_limit
        self.count = 0
        self.total = 0.0
        self.total_sq = 0.0
        self.min = math.inf
        self.max = -math.inf

    @property
    def nbytes(self) -> int:
        """Bytes held by the values and the histogram."""
        return sum(c.nbytes for c in self._chunks) + (self._hist.nbytes if self._hist is not None else 0)

    def add(self, values: np.ndarray) -> None:
        v = np.asarray(values, np.float64).ravel()
        if not v.size:
            return
        self.count += v.size
        self.total += float(v.sum())
        self.total_sq += float(np.dot(v, v))
        self.min = min(self.min, float(v.min()))
        self.max = max(self.max, float(v.max()))
        if not self._quantiles:
            return
        if self._hist is None and self._n_chunked + v.size <= self.exact_limit:
            self._chunks.append(v.copy())
            self._n_chunked += v.size
            return
        if self._hist is None:
            self._hist = np.zeros(self._n_bins + 2, np.int64)
            for c in self._chunks:
                self._bin(c)
            self._chunks, self._n_chunked = [], 0
        self._bin(v)

    def _bin(self, v: np.ndarray) -> None:
        with np.errstate(divide="ignore"):
            idx = np.floor((np.log(v) - self._log_low) / self._log_step)
        idx = np.clip(np.nan_to_num(idx, nan=-1.0, neginf=-1.0), -1, self._n_bins).astype(np.int64) + 1
        u, c = np.unique(idx, return_counts=True)
        self._hist[u] += c

    def _order_statistic(self, k: int, cum: np.ndarray) -> float:
        b = int(np.searchsorted(cum, k, side="right"))  # the first bin holding more than k values
        if b == 0:
            centre = 0.5 * self._low
        elif b == self._n_bins + 1:
            centre = self.max
        else:
            centre = math.exp(self._log_low + (b - 0.5) * self._log_step)
        return min(max(centre, self.min), self.max)

    def quantile(self, q: float) -> float:
        """The ``q`` percentile (0–100), as ``np.percentile(values, q)``; NaN when empty."""
        if not self._quantiles:
            raise ValueError("quantile: this stream keeps no values (quantiles=False)")
        if not self.count:
            return float("nan")
        if self._hist is None:
            return float(np.percentile(np.concatenate(self._chunks), q))
        pos = q / 100.0 * (self.count - 1)
        lo, frac = int(math.floor(pos)), pos - math.floor(pos)
        cum = np.cumsum(self._hist)
        a = self._order_statistic(lo, cum)
        b = self._order_statistic(min(lo + 1, self.count - 1), cum) if frac else a
        return a + frac * (b - a)


def _python_scalar(value: object) -> object:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"row value: expected a number, bool or string, got {type(value).__name__}")


class _RowSpool:
    """Rows (flat dicts of numbers, bools and strings) kept in a temporary file, one JSON line each;
    iterated again each time (in order), so that rows cost no memory over a session."""

    def __init__(self) -> None:
        self._file = None
        self._n = 0

    def append(self, row: dict) -> None:
        if self._file is None:
            self._file = tempfile.TemporaryFile("w+", encoding="utf-8")
        self._file.seek(0, 2)
        # floats as repr: they read back bit for bit, NaN too; numpy scalars as the Python ones
        self._file.write(json.dumps(row, default=_python_scalar) + "\n")
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def __iter__(self) -> Iterator[dict]:
        if self._file is None:
            return
        self._file.flush()
        self._file.seek(0)
        for line in self._file:
            yield json.loads(line)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


class AccuracyTracker:
    """Collects per-frame errors; :meth:`summary` returns the flat ``accuracy.json`` mapping and
    :attr:`rows` the per-frame rows of ``depth_frames.csv``. What it holds does not grow with the
    number of frames (:meth:`retained_bytes`)."""

    #: colour frames whose gains are kept for pairing with a later depth step (8.5 s at 30 Hz; a
    #: depth step pairs with a colour frame at most ``max_colour_lag_ms`` away).
    GAINS_KEPT = 256

    def __init__(self, exact_values: int = 2**20) -> None:
        """``exact_values``: how many per-pixel depth errors (and CCM errors) are kept as they are for
        exact medians (8 MiB at the default, about 40 s of a Tango session); past it the medians
        are binned (:class:`StreamQuantiles`)."""
        self._rows = _RowSpool()
        # the last GAINS_KEPT colour frames' gains, a ring: fixed arrays, whatever the session's length
        self._gain_ts = np.full(self.GAINS_KEPT, -1, np.int64)
        self._gain_values = np.zeros((self.GAINS_KEPT, 3), np.float64)
        self._gain_next = 0
        self._reference_gains: np.ndarray | None = None
        self._raw = StreamQuantiles(quantiles=False)  # only its sums are read
        self._filled = StreamQuantiles(exact_values)
        self._ccm = StreamQuantiles(exact_values)
        self._n_depth_truth = 0
        self._n_frames = self._n_projected = self._n_rejected = 0
        #: depth frames the capture did not project, by reason ("too few pairs", "mse", ...)
        self.rejected_by_reason: dict[str, int] = {}

    @property
    def rows(self) -> _RowSpool:
        """Every depth step's row, in order (an iterable read back from disk; ``len`` works)."""
        return self._rows

    def retained_bytes(self) -> int:
        """Bytes of per-frame state held in memory (values, histograms, gains): bounded, whatever
        the number of frames."""
        return self._raw.nbytes + self._filled.nbytes + self._ccm.nbytes + self._gain_ts.nbytes + self._gain_values.nbytes

    def on_colour(self, timestamp_ns: int, groundtruth: dict) -> None:
        if "gains" in groundtruth:
            i = self._gain_next % self.GAINS_KEPT
            self._gain_ts[i] = timestamp_ns
            self._gain_values[i] = groundtruth["gains"]
            self._gain_next += 1

    def _gains_of(self, timestamp_ns: int) -> np.ndarray | None:
        """The gains of the latest colour frame at ``timestamp_ns`` among the kept ones, or None."""
        hits = np.flatnonzero(self._gain_ts == timestamp_ns)
        if not hits.size:
            return None
        # the most recent write wins, as a dict's would: ring positions after the next slot are older
        order = (hits - self._gain_next) % self.GAINS_KEPT
        return self._gain_values[hits[np.argmax(order)]].copy()

    def on_depth(self, step: DepthStep, groundtruth: dict) -> dict:
        """Record one depth step; returns its row (also kept for ``depth_frames.csv``)."""
        cap = step.capture
        row = {
            "timestamp_ns": step.timestamp_ns, "reference": cap.reference, "projected": cap.projected,
            "reason": cap.reason.split(" (")[0], "n_pairs": cap.n_pairs,
            "ccm_mse": float(cap.ccm.mse) if cap.ccm is not None else float("nan"),
            "taken": cap.update.taken if cap.update is not None else 0,
            "taken_freed": cap.update.taken_freed if cap.update is not None else 0,
            "averaged": cap.update.averaged if cap.update is not None else 0,
            "kept_view": cap.update.kept_view if cap.update is not None else 0,
            "bands": step.bands,
        }
        gains = self._gains_of(step.colour_timestamp_ns)
        if cap.reference and gains is not None:
            self._reference_gains = gains
        if cap.ccm is not None and cap.ccm.accepted and gains is not None and self._reference_gains is not None:
            # A bracketed frame's colours were brought to the live exposure first (HDR capture).
            true = np.diag(self._reference_gains / gains) / getattr(step, "exposure_scale", 1.0)
            err = float(np.linalg.norm(cap.matrix - true) / np.linalg.norm(true))
            row["ccm_rel_error"] = err
            self._ccm.add(np.array([err]))
        if "true_depth_m" in groundtruth and "true_valid" in groundtruth:
            truth = np.asarray(groundtruth["true_depth_m"], np.float64)
            tv = np.asarray(groundtruth["true_valid"], bool)
            if truth.shape != step.raw_known.shape:  # the step ran on a subsampled frame (Kinect path)
                st = truth.shape[0] // step.raw_known.shape[0]
                truth, tv = truth[::st, ::st], tv[::st, ::st]
            raw = step.raw_known & tv
            filled = step.filled_known & ~step.raw_known & tv
            e_raw = np.abs(step.raw_depth_m[raw] - truth[raw])
            e_fill = np.abs(step.filled_depth_m[filled] - truth[filled])
            self._raw.add(e_raw)
            self._filled.add(e_fill)
            self._n_depth_truth += 1
            row["raw_depth_mae_m"] = float(e_raw.mean()) if e_raw.size else float("nan")
            row["filled_depth_mae_m"] = float(e_fill.mean()) if e_fill.size else float("nan")
            row["filled_pixels"] = int(filled.sum())
        self._n_frames += 1
        self._n_projected += bool(row["projected"])
        rejected = (not row["projected"]) and row["reason"] not in ("frozen",)
        self._n_rejected += rejected
        if rejected:  # by the reason's words: "mse 0.08 > 0.05" counts as "mse"
            why = re.split(r"[0-9(]", row["reason"], maxsplit=1)[0].strip() or "unknown"
            self.rejected_by_reason[why] = self.rejected_by_reason.get(why, 0) + 1
        self._rows.append(row)
        return row

    @staticmethod
    def _lighting_errors(out: dict, pipeline: Pipeline, grad: np.ndarray, gv: np.ndarray) -> None:
        """SH coefficients, irradiance over the sphere and the object's shading against the same
        computed from the complete true map (at its own resolution)."""
        n = pipeline.bands
        truth = sh.project_equirect(grad, gv, n)
        est = pipeline.coeffs[: n * n]
        out["sh_coeff_rel_error"] = float(np.linalg.norm(est - truth) / max(np.linalg.norm(truth), 1e-12))
        normals = fibonacci_sphere(512)
        lum = np.array([0.2126, 0.7152, 0.0722])
        lt, le = sh.irradiance(truth, normals) @ lum, sh.irradiance(est, normals) @ lum
        ok = lt > 1e-6 * max(lt.max(), 1e-12)
        if ok.any():  # a black or empty true map lights no normal: no relative error to give
            out["irradiance_rel_error_mean"] = float(np.mean(np.abs(le[ok] - lt[ok]) / lt[ok]))
        # against the true irradiance (8 bands of the true map: within 0.4 % of a brute-force cosine
        # convolution, docs/design/sh.md), so SH truncation counts too: the error a band count buys
        l8 = sh.irradiance(sh.project_equirect(grad, gv, 8), normals) @ lum
        ok8 = l8 > 1e-6 * max(l8.max(), 1e-12)
        if ok8.any():
            out["irradiance_rel_error_vs_true"] = float(np.mean(np.abs(le[ok8] - l8[ok8]) / l8[ok8]))
        if pipeline.colours is not None:
            from rgbd_envmap import prt

            ref = prt.shade(pipeline._transfer[:, : n * n], truth, pipeline._object.albedo)
            out["shading_rel_rmse"] = float(np.sqrt(np.mean((pipeline.colours - ref) ** 2)) / max(np.sqrt(np.mean(ref**2)), 1e-12))

    def summary(self, pipeline: Pipeline, gt_em: dict | None) -> dict:
        """The flat mapping metric → value (floats; NaN-free: unavailable metrics are left out)."""
        out: dict[str, float] = {}
        out["depth_frames"] = self._n_frames
        out["depth_frames_projected"] = self._n_projected
        out["depth_frames_rejected"] = self._n_rejected
        out["depth_packets_dropped"] = pipeline.dropped_depth
        if self._n_depth_truth:
            raw, fill = self._raw, self._filled
            if raw.count:
                out["ingest_depth_mae_m"] = raw.total / raw.count
                out["ingest_depth_rmse_m"] = math.sqrt(raw.total_sq / raw.count)
            if fill.count:
                out["hole_filling_depth_mae_m"] = fill.total / fill.count
                out["hole_filling_depth_rmse_m"] = math.sqrt(fill.total_sq / fill.count)
                out["hole_filling_depth_median_abs_m"] = fill.quantile(50)
        if self._ccm.count:
            out["ccm_matrix_rel_error_median"] = self._ccm.quantile(50)
            out["ccm_matrix_rel_error_p95"] = self._ccm.quantile(95)
        em = pipeline.capture.em
        out["em_coverage_solid_angle"] = metrics.coverage(em.valid)
        if gt_em is None or not np.allclose(np.asarray(gt_em["origin"]), em.origin):
            return out
        gv = np.asarray(gt_em["valid"], bool)
        grad = np.asarray(gt_em["radiance"], np.float32)
        gdist = np.asarray(gt_em["distance_m"], np.float32)
        if pipeline.has_lighting:
            self._lighting_errors(out, pipeline, grad, gv)
        if gv.shape != em.valid.shape:
            grad, gdist, gv = _downsample_truth(grad, gdist, gv, em.valid.shape)
            out["em_truth_downsampled"] = 1.0
        covered = em.valid & gv
        if gv.any():  # coverage of a truth with no data is undefined
            out["em_coverage"] = metrics.coverage_of(em.valid, gv)
        if covered.any():
            out["em_ws_psnr_db"] = metrics.ws_psnr(np.clip(em.radiance, 0, 1), np.clip(grad, 0, 1), covered)
            corr = metrics.sphere_correlation(em.radiance, grad, covered)
            if np.isfinite(corr):  # undefined where the covered pixels are constant
                out["em_sphere_correlation"] = corr
            d = np.abs(em.depth_m[covered] - gdist[covered])
            out["em_depth_median_abs_m"] = float(np.median(d))
        return out
