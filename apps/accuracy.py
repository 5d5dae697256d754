"""Each stage's error against ground truth, accumulated over a run (simulated live or replayed).

Ground truth comes from wherever the run has it: the simulator's packets, or the ``groundtruth/``
folder of a recorded log (per-packet arrays, and ``groundtruth/envmap.npz``, the true map at the end
of the session, written by ``simulate``). Metrics whose truth is missing are left out, never guessed.

Per depth packet: raw and hole-filled depth error (pixels known after filling but not before, against
the true z-depth), and, for accepted correction matrices, the error of the matrix against the true one
(the sensor's per-channel gains: M_true = diag(g_reference / g_frame)). At the end: the EM against the
true map (coverage of its solid angle, WS-PSNR on covered pixels, depth error), the SH coefficients,
the irradiance over the sphere, and the object's shading against the same computed from the true map.
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap import metrics, sh
from rgbd_envmap.pipeline import DepthStep, Pipeline

__all__ = ["AccuracyTracker", "fibonacci_sphere"]


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


class AccuracyTracker:
    """Collects per-frame errors; :meth:`summary` returns the flat ``accuracy.json`` mapping."""

    def __init__(self) -> None:
        self.rows: list[dict] = []
        self._gains: dict[int, np.ndarray] = {}
        self._reference_gains: np.ndarray | None = None
        self._raw_abs: list[np.ndarray] = []
        self._filled_abs: list[np.ndarray] = []
        self._ccm_err: list[float] = []

    def on_colour(self, timestamp_ns: int, groundtruth: dict) -> None:
        if "gains" in groundtruth:
            self._gains[int(timestamp_ns)] = np.asarray(groundtruth["gains"], np.float64)

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
            "bands": step.bands,
        }
        gains = self._gains.get(step.colour_timestamp_ns)
        if cap.reference and gains is not None:
            self._reference_gains = gains
        if cap.ccm is not None and cap.ccm.accepted and gains is not None and self._reference_gains is not None:
            true = np.diag(self._reference_gains / gains)
            err = float(np.linalg.norm(cap.matrix - true) / np.linalg.norm(true))
            row["ccm_rel_error"] = err
            self._ccm_err.append(err)
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
            self._raw_abs.append(e_raw)
            self._filled_abs.append(e_fill)
            row["raw_depth_mae_m"] = float(e_raw.mean()) if e_raw.size else float("nan")
            row["filled_depth_mae_m"] = float(e_fill.mean()) if e_fill.size else float("nan")
            row["filled_pixels"] = int(filled.sum())
        self.rows.append(row)
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
        steps = self.rows
        out["depth_frames"] = len(steps)
        out["depth_frames_projected"] = sum(r["projected"] for r in steps)
        out["depth_frames_rejected"] = sum((not r["projected"]) and r["reason"] not in ("frozen",) for r in steps)
        out["depth_packets_dropped"] = pipeline.dropped_depth
        if self._raw_abs:
            raw = np.concatenate(self._raw_abs)
            fill = np.concatenate(self._filled_abs)
            if raw.size:
                out["ingest_depth_mae_m"] = float(raw.mean())
                out["ingest_depth_rmse_m"] = float(np.sqrt(np.mean(raw**2)))
            if fill.size:
                out["hole_filling_depth_mae_m"] = float(fill.mean())
                out["hole_filling_depth_rmse_m"] = float(np.sqrt(np.mean(fill**2)))
                out["hole_filling_depth_median_abs_m"] = float(np.median(fill))
        if self._ccm_err:
            out["ccm_matrix_rel_error_median"] = float(np.median(self._ccm_err))
            out["ccm_matrix_rel_error_p95"] = float(np.percentile(self._ccm_err, 95))
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
