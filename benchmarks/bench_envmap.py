"""Time the colour-correction and environment-map stages on realistic data (paper Table 1 rows
"Collect paired samples", "Compute colour correction matrix", "Calculate MSE", "Project sample to EM"
and the §6.2 translation), the current kernels side by side with the previous ones.

    python benchmarks/bench_envmap.py [--repeats N] [--session S] [--recorded PATH] [--recorded-rounds R]
                                      [--only-recorded] [--only-translation] [--translation-baseline PATH]
                                      [--update-baseline PATH] [--json PATH]

1. One frame: a 4.2 s capture of the default scene warms the map up; the timed frame is the next.
2. A session (``--session``, default 20 s of the default orbit; 0 skips it): every pairs and
   update call of a default capture is run by the current library and, on a mirror map fed the
   same inputs, by the previous kernels; per-frame median and p95 of each, and whether the two
   final maps are identical bit for bit.
3. The recorded session (``--recorded``, default ``runs/default/session``, written by ``bash
   main.sh``; skipped when missing): the capture inputs of every depth frame as the pipeline makes
   them, replayed ``--recorded-rounds`` times; the stages "Collect paired samples" and "Project
   sample to EM*" exactly as ``capture.process`` times them, and the ``update`` call alone, beside
   the previous kernels with the previous numpy gathers on a mirror map; bit-identity of the maps.
4. Translation by 10 cm of the 4.2 s map (23 % covered), of the session's final map (89 %) and of
   the ray-cast true map (everything covered). ``--translation-baseline PATH`` adds another
   version of ``rgbd_envmap/translation.py`` (a copy of the file) timed alternately in the same
   run, with the count of pixels it gives differently; a row with ``out=`` (the output map of
   the previous call overwritten) is timed beside the default; ``--only-translation`` times just the
   translations of the recorded session's final map and the true map (``--translation-rounds``
   repeats each, default ``max(5, repeats // 5)``). One thread unless ``--threads 2``, which adds
   a row for ``translate(..., threads=2)`` (its default) beside it.
5. ``--update-baseline PATH`` (alone): every ``update`` call of the recorded session (its inputs
   captured once from a pipeline replay) run by the library and by another version of
   ``rgbd_envmap/envmap.py`` (a copy of the file) on two maps that both record changes, frame by
   frame alternately (which goes first alternates), ``--recorded-rounds`` passes from empty maps;
   after every frame the maps, the ``UpdateStats`` and the change logs must be identical.
   Median / p95 ms of the call, and of each frame's fastest pass (less sensitive to a noisy
   machine).
6. ``--update-parts`` (alone): the same calls with one part of the update switched off at a time
   (:data:`UPDATE_PARTS`: footprints clamped, colour averaging, carving, footprints, all three),
   each setting on a map of its own, alternately frame by frame: what each part costs per frame
   on one thread, and how many map pixels it touches and takes.

Each pair of rows is timed alternately in the same run (the machine is shared and noisy). Single
thread: every kernel is serial numba. The previous kernels (before the issue-4 speed work) are kept
below, in this script and not in the library, only to time them here.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import math
import sys
import time
from functools import lru_cache
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import cv2  # noqa: E402

import rgbd_envmap.capture as capture_module  # noqa: E402
from apps.replay import default_origin  # noqa: E402
from benchmarks.eval_envmap import ingested_frames  # noqa: E402
from rgbd_envmap.capture import CaptureConfig, EnvironmentCapture  # noqa: E402
from rgbd_envmap.colour import DEFAULT_MAX_CONDITION, DEFAULT_RIDGE, _ccm_from_sums, apply_ccm, estimate_ccm  # noqa: E402
from rgbd_envmap.depth.reliability import discontinuity_test  # noqa: E402
from rgbd_envmap.envmap import (  # noqa: E402
    EnvironmentMap,
    UpdateConfig,
    _frame_pairs,
    collect_pairs,
    frame_points,
    rule_closer,
    rule_empty,
    rule_removal,
    rule_trusted,
    translate,
    update,
)
from rgbd_envmap.logs import SessionLog  # noqa: E402
from rgbd_envmap.pipeline import Pipeline, PipelineConfig  # noqa: E402
from rgbd_envmap.timing import StageTimer  # noqa: E402
from rgbd_envmap.translation import translate_map  # noqa: E402
from sim.colour_camera import ColourCameraConfig  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.groundtruth import render_envmap  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402


def _stats(ms: list[float], cpu_ms: list[float] | None = None) -> dict:
    a = np.asarray(ms)
    out = {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)), "min_ms": float(a.min()), "n": len(a)}
    if cpu_ms is not None:  # thread CPU time: less inflated than wall time when other jobs share the cores
        out["cpu_median_ms"] = float(np.median(cpu_ms))
    return out


def time_alternating(fns: dict, repeats: int, warmup: int = 1) -> dict[str, dict]:
    """Like common.time_it for several functions, called in turn (order reversed every round)."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    ms = {k: [] for k in fns}
    cpu = {k: [] for k in fns}
    keys = list(fns)
    for i in range(repeats):
        for k in keys if i % 2 else keys[::-1]:
            t0, c0 = time.perf_counter(), time.thread_time()
            fns[k]()
            cpu[k].append((time.thread_time() - c0) * 1e3)
            ms[k].append((time.perf_counter() - t0) * 1e3)
    return {k: _stats(ms[k], cpu[k]) for k in fns}


def print_rows(rows: dict[str, dict]) -> None:
    """common.print_table plus the median thread CPU time where measured."""
    width = max(len(k) for k in rows)
    print(f"{'case':<{width}}  {'median ms':>10}  {'p95 ms':>10}  {'cpu med ms':>10}  {'n':>4}")
    for name, r in rows.items():
        cpu = f"{r['cpu_median_ms']:>10.2f}" if "cpu_median_ms" in r else f"{'':>10}"
        print(f"{name:<{width}}  {r['median_ms']:>10.2f}  {r['p95_ms']:>10.2f}  {cpu}  {r['n']:>4}")


# --- the previous kernels (verbatim but for the _old prefix) and thin wrappers ---------------------

@numba.njit(cache=True)
def _old_span(x, half, limit):
    """Pixels k whose centre k + 0.5 lies within ``half`` (≥ 0.5) of continuous coordinate x."""
    h = min(max(half, 0.5), limit)
    return int(math.ceil(x - h - 0.5)), int(math.floor(x + h - 0.5))



@numba.njit(cache=True)
def _old_update_kernel(
    points, colours, fill_only, pv, pu, pr, origin, device, height, width, focal_px, splat, splat_scale, max_splat,
    planes, depth, valid, stamp, frame, trusted_r, removal_r, zbuf, winner, touched, row_sc, col_sc,
):
    n = points.shape[0]
    n_touched = 0
    row_px = height / math.pi
    col_px = width / (2.0 * math.pi)
    for i in range(n):
        if not (np.isfinite(points[i, 0]) and np.isfinite(points[i, 1]) and np.isfinite(points[i, 2])):
            continue
        if not (np.isfinite(colours[i, 0]) and np.isfinite(colours[i, 1]) and np.isfinite(colours[i, 2])):
            continue
        r = pr[i]
        if not r > 0.0:
            continue
        v, u = pv[i], pu[i]
        row = min(int(v), height - 1)
        col = int(u)
        col = col - width if col >= width else col
        r0, r1, c0, c1 = row, row, col, col
        if splat:
            ex = points[i, 0] - device[0]
            ey = points[i, 1] - device[1]
            ez = points[i, 2] - device[2]
            angle = splat_scale * math.sqrt(ex * ex + ey * ey + ez * ez) / (focal_px * r)
            dx, dy = points[i, 0] - origin[0], points[i, 1] - origin[1]
            s = max(math.sqrt(dx * dx + dy * dy) / r, 1e-6)  # sin θ, without a libm call
            r0, r1 = _old_span(v, 0.5 * angle * row_px, max_splat)
            c0, c1 = _old_span(u, 0.5 * angle * col_px / s, min(max_splat / s, width // 2))
        for rr in range(r0, r1 + 1):
            if rr < 0 or rr >= height:
                continue
            for cc0 in range(c0, c1 + 1):
                cc = cc0 % width
                if stamp[rr, cc] != frame:
                    stamp[rr, cc] = frame
                    zbuf[rr, cc] = r
                    winner[rr, cc] = i
                    touched[n_touched] = rr * width + cc
                    n_touched += 1
                elif r < zbuf[rr, cc]:
                    zbuf[rr, cc] = r
                    winner[rr, cc] = i
    # Rules, per touched pixel, against the pixel's own ray.
    ox, oy, oz = device[0] - origin[0], device[1] - origin[1], device[2] - origin[2]
    dev_r = math.sqrt(ox * ox + oy * oy + oz * oz)
    trusted = rule_trusted(dev_r, trusted_r)
    counts = np.zeros(5, np.int64)
    for k in range(n_touched):
        p = touched[k]
        rr = p // width
        cc = p - rr * width
        r = zbuf[rr, cc]
        i = winner[rr, cc]
        take = False
        if rule_empty(valid[rr, cc]):
            take = True
            counts[1] += 1
        elif rule_closer(r, depth[rr, cc]) and not fill_only[i]:
            take = True
            counts[2] += 1
        elif trusted:
            take = True
            counts[3] += 1
        else:
            st = row_sc[rr, 0]
            ux, uy, uz = st * col_sc[cc, 1], st * col_sc[cc, 0], row_sc[rr, 1]
            along = ox * ux + oy * uy + oz * uz
            if along > 0.0:
                px, py, pz = ox - along * ux, oy - along * uy, oz - along * uz
                to_ray = math.sqrt(px * px + py * py + pz * pz)
            else:
                to_ray = dev_r  # the ray starts at the origin: the closest point is the origin
            if rule_removal(along, to_ray, r, depth[rr, cc], removal_r):
                take = True
                counts[4] += 1
        if take:
            counts[0] += 1
            for c in range(3):
                planes[c, rr, cc] = colours[i, c]
            depth[rr, cc] = r if not valid[rr, cc] else 0.5 * (depth[rr, cc] + r)
            valid[rr, cc] = True
    return n_touched, counts



@numba.njit(cache=True)
def _old_pairs_kernel(points, pv, pu, pr, height, width, depth, valid, planes, max_diff):
    n = points.shape[0]
    keep = np.zeros(n, np.bool_)
    dst = np.zeros((n, 3), np.float32)
    for i in range(n):
        if not (np.isfinite(points[i, 0]) and np.isfinite(points[i, 1]) and np.isfinite(points[i, 2])):
            continue
        r = pr[i]
        if not r > 0.0:
            continue
        row = min(int(pv[i]), height - 1)
        col = int(pu[i])
        col = col - width if col >= width else col
        if valid[row, col] and abs(depth[row, col] - r) <= max_diff:
            keep[i] = True
            for c in range(3):
                dst[i, c] = planes[c, row, col]
    return keep, dst



@numba.njit(cache=True, fastmath=True, inline="always")
def _old_atan2_branchless(y, x):
    """atan2 from :data:`_ATAN_POLY`, written with selects only so that loops calling it vectorise
    (libm's atan2 is ~40 ns a call and blocks vectorisation)."""
    ax, ay = abs(x), abs(y)
    mx = max(ax, ay)
    t = min(ax, ay) / (mx if mx > 0.0 else 1.0)
    t2 = t * t
    # _ATAN_POLY written out: a loop over the tuple kept this from vectorising (28 ms → 10 ms pass).
    p = 0.0028340641752807177
    p = p * t2 + -0.01600503000542798
    p = p * t2 + 0.04258760664298073
    p = p * t2 + -0.07495445371631375
    p = p * t2 + 0.10636754062743976
    p = p * t2 + -0.1420257050187139
    p = p * t2 + 0.1999248357706807
    p = p * t2 + -0.33333066780599485
    p = p * t2 + 0.9999999842426203
    a = t * p
    a = 0.5 * math.pi - a if ay > ax else a
    a = math.pi - a if x < 0.0 else a
    return -a if y < 0.0 else a


@numba.njit(cache=True, fastmath=True)
def _old_points_to_equirect(points, origin, height, width, v, u, r):
    """Continuous (v, u) and distance from ``origin`` of (N, 3) points; branch-free so it vectorises.
    Non-finite points give garbage here: callers test the points themselves (fastmath may fold a
    finiteness test on the results away)."""
    kv = height / math.pi
    ku = width / (2.0 * math.pi)
    for i in range(points.shape[0]):
        dx = points[i, 0] - origin[0]
        dy = points[i, 1] - origin[1]
        dz = points[i, 2] - origin[2]
        h = math.sqrt(dx * dx + dy * dy)
        r[i] = math.sqrt(h * h + dz * dz)
        v[i] = _old_atan2_branchless(h, dz) * kv
        u[i] = (_old_atan2_branchless(dy, dx) + math.pi) * ku



def _old_equirect_coords(points: np.ndarray, origin: np.ndarray, height: int, width: int):
    n = len(points)
    v, u, r = np.empty(n), np.empty(n), np.empty(n)
    _old_points_to_equirect(points, origin, height, width, v, u, r)
    return v, u, r



@numba.njit(cache=True, fastmath=True)
def _old_reproject(depth, row_sin, row_cos, col_sin, col_cos, ox, oy, oz, pv, pu, pd):
    """Where every pixel's point lands seen from the new origin: continuous (v, u) and distance.
    Branch-free so that it vectorises (≈10 ms for 2000×1000 instead of ≈150 ms with libm calls)."""
    height, width = depth.shape
    kv = height / math.pi
    ku = width / (2.0 * math.pi)
    for r in range(height):
        s = row_sin[r]
        c = row_cos[r]
        for k in range(width):
            d = depth[r, k]
            x = ox + d * s * col_cos[k]
            y = oy + d * s * col_sin[k]
            z = oz + d * c
            h = math.sqrt(x * x + y * y)
            pd[r, k] = math.sqrt(h * h + z * z)
            pv[r, k] = _old_atan2_branchless(h, z) * kv
            pu[r, k] = (_old_atan2_branchless(y, x) + math.pi) * ku


@numba.njit(cache=True, fastmath=True, inline="always")
def _old_half_extent(a, b, da, db, valid_b, max_rel_jump, period):
    """Half the distance between landing coordinates a and b (b a neighbour), 0 when the neighbour
    is invalid or across a depth jump; ``period`` > 0 wraps the difference (longitude)."""
    diff = abs(b - a)
    if period > 0.0:
        diff = min(diff, period - diff)
    ok = valid_b and abs(db - da) <= max_rel_jump * da
    return 0.5 * diff if ok else 0.0


@numba.njit(cache=True, fastmath=True)
def _old_extents(depth, valid, pv, pu, max_rel_jump, hv, hu):
    """Per pixel, half the (v, u) distance to where its depth-continuous 4-neighbours land (≥ 0.5).
    The longitude wraps; the first and last rows look one way only."""
    height, width = depth.shape
    fw = float(width)
    for r in range(height):
        up = r - 1 if r > 0 else r
        down = r + 1 if r + 1 < height else r
        for c in range(width):
            left = c - 1 if c > 0 else width - 1
            right = c + 1 if c + 1 < width else 0
            d = depth[r, c]
            a_v = max(_old_half_extent(pv[r, c], pv[up, c], d, depth[up, c], valid[up, c], max_rel_jump, 0.0),
                      _old_half_extent(pv[r, c], pv[down, c], d, depth[down, c], valid[down, c], max_rel_jump, 0.0))
            a_v = max(a_v, max(_old_half_extent(pv[r, c], pv[r, left], d, depth[r, left], valid[r, left], max_rel_jump, 0.0),
                               _old_half_extent(pv[r, c], pv[r, right], d, depth[r, right], valid[r, right], max_rel_jump, 0.0)))
            a_u = max(_old_half_extent(pu[r, c], pu[up, c], d, depth[up, c], valid[up, c], max_rel_jump, fw),
                      _old_half_extent(pu[r, c], pu[down, c], d, depth[down, c], valid[down, c], max_rel_jump, fw))
            a_u = max(a_u, max(_old_half_extent(pu[r, c], pu[r, left], d, depth[r, left], valid[r, left], max_rel_jump, fw),
                               _old_half_extent(pu[r, c], pu[r, right], d, depth[r, right], valid[r, right], max_rel_jump, fw)))
            hv[r, c] = max(a_v, 0.5)
            hu[r, c] = max(a_u, 0.5)


@numba.njit(cache=True)
def _old_splat_warped(planes, valid, pv, pu, pd, hv, hu, row_sc, max_splat,
                  out_planes, out_depth, out_valid, zbuf):
    """Scatter each source pixel over its (v, u) extent; z-buffer, closest wins."""
    height, width = valid.shape
    for r in range(height):
        for c in range(width):
            nd = pd[r, c]
            if not valid[r, c] or not (nd > 0.0):
                continue
            v, u = pv[r, c], pu[r, c]
            row = min(int(v), height - 1)
            # The common case, one pixel, written without the span loops: 23 ms instead of 36 ms for
            # 2000×1000 (the loops below reduce to the same single write).
            if hv[r, c] == 0.5 and hu[r, c] == 0.5:
                col = int(u)
                col = col - width if col >= width else col
                if nd < zbuf[row, col]:
                    zbuf[row, col] = nd
                    out_depth[row, col] = nd
                    out_valid[row, col] = True
                    for ch in range(3):
                        out_planes[ch, row, col] = planes[ch, r, c]
                continue
            new_st = max(row_sc[row, 0], 1e-6)
            r0, r1 = _old_span(v, hv[r, c], max_splat)
            c0, c1 = _old_span(u, hu[r, c], min(max_splat / new_st, width // 2))
            for rr in range(max(r0, 0), min(r1, height - 1) + 1):
                for cc0 in range(c0, c1 + 1):
                    cc = cc0 % width
                    if nd < zbuf[rr, cc]:
                        zbuf[rr, cc] = nd
                        out_depth[rr, cc] = nd
                        out_valid[rr, cc] = True
                        for ch in range(3):
                            out_planes[ch, rr, cc] = planes[ch, r, c]


@lru_cache(maxsize=4)
def _old_trig_tables(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    rows = np.stack([np.sin(theta), np.cos(theta)], -1).astype(np.float32)
    cols = np.stack([np.sin(phi), np.cos(phi)], -1).astype(np.float32)
    return rows, cols


class OldUpdater:
    """The previous ``update`` on an EnvironmentMap, with its own per-frame scratch (stamps)."""

    def __init__(self, em: EnvironmentMap) -> None:
        shape = (em.height, em.width)
        self.em = em
        self.scratch = (np.zeros(shape, np.int32), np.zeros(shape, np.float32), np.zeros(shape, np.int32),
                        np.zeros(em.height * em.width, np.int64))
        self.frame = 0

    def __call__(self, pts, col, dev, focal, config=None, fill_only=None):
        config = UpdateConfig() if config is None else config
        em = self.em
        stamp, zbuf, winner, touched = self.scratch
        self.frame += 1
        pts = np.ascontiguousarray(np.asarray(pts, np.float64))
        flags = np.zeros(len(pts), bool) if fill_only is None else fill_only
        pv, pu, pr = _old_equirect_coords(pts, em.origin, em.height, em.width)
        return _old_update_kernel(
            pts, np.ascontiguousarray(col, np.float32), np.ascontiguousarray(flags), pv, pu, pr, em.origin,
            np.asarray(dev, np.float64), em.height, em.width, float(focal), bool(config.splat), float(config.splat_scale),
            int(config.max_splat_px), em.radiance_planes, em.depth_m, em.valid, stamp, self.frame,
            float(config.trusted_radius_m), float(config.removal_radius_m), zbuf, winner, touched,
            *_old_trig_tables(em.height, em.width))


def old_collect_pairs(em, pts, col, max_depth_diff_m=0.01):
    pts = np.ascontiguousarray(np.asarray(pts, np.float64))
    pv, pu, pr = _old_equirect_coords(pts, em.origin, em.height, em.width)
    keep, dst = _old_pairs_kernel(pts, pv, pu, pr, em.height, em.width, em.depth_m, em.valid, em.radiance_planes,
                                  float(max_depth_diff_m))
    return np.asarray(col, np.float32)[keep], dst[keep]


def old_translate(em, offset, max_splat_px=8, max_rel_jump=0.2):
    new_origin = em.origin + np.asarray(offset, np.float64)
    out = EnvironmentMap(em.height, em.width, new_origin)
    shape = (em.height, em.width)
    pv, pu, pd, hv, hu = (np.empty(shape, np.float32) for _ in range(5))
    row_sc, col_sc = _old_trig_tables(em.height, em.width)
    o = (em.origin - new_origin).astype(np.float32)
    _old_reproject(em.depth_m, np.ascontiguousarray(row_sc[:, 0]), np.ascontiguousarray(row_sc[:, 1]),
                   np.ascontiguousarray(col_sc[:, 0]), np.ascontiguousarray(col_sc[:, 1]), o[0], o[1], o[2], pv, pu, pd)
    _old_extents(em.depth_m, em.valid, pv, pu, np.float32(max_rel_jump), hv, hu)
    zbuf = np.full(shape, np.inf, np.float32)
    _old_splat_warped(em.radiance_planes, em.valid, pv, pu, pd, hv, hu, row_sc, int(max_splat_px),
                      out.radiance_planes, out.depth_m, out.valid, zbuf)
    return out


# --- the benchmark ---------------------------------------------------------------------------------


def _maps_differ(a: EnvironmentMap, b: EnvironmentMap) -> int:
    """Pixels whose validity, depth or radiance differ."""
    return int(((a.valid != b.valid) | (a.depth_m != b.depth_m) | (a.radiance_planes != b.radiance_planes).any(0)).sum())


def one_frame(sim, frames, r: int, rows: dict) -> EnvironmentMap:
    cap = EnvironmentCapture(sim.scene.virtual_object_position, CaptureConfig())
    for res in frames[:-1]:
        cap.process(res.frame, res.reliable, res.filled, across_edges=res.across_edges)
    res = frames[-1]
    raw, filled = res.frame, res.filled
    em = cap.em
    # Pairs over the whole cloud (every known pixel, as the paper's 38,528-point figure), and over
    # the reliable pixels the pipeline actually uses.
    pts_all = frame_points(raw.depth_m, raw.known, raw.intrinsics, raw.T_world_from_cam)
    col_all = raw.rgb[raw.known]
    pts_rel = frame_points(raw.depth_m, res.reliable, raw.intrinsics, raw.T_world_from_cam)
    col_rel = raw.rgb[res.reliable]
    src, dst = collect_pairs(em, pts_all, col_all)
    mask = cap.projected_mask(raw, filled)
    pts_proj = frame_points(filled.depth_m, mask, filled.intrinsics, filled.T_world_from_cam)
    col_proj = apply_ccm(filled.rgb[mask], cap.matrix)
    dev = filled.T_world_from_cam.translation
    focal = 0.5 * (filled.intrinsics.fx + filled.intrinsics.fy)
    work_new, work_old = em.copy(), em.copy()
    old_update = OldUpdater(work_old)
    print(f"map coverage before the timed frame: {em.valid.mean():.3f}; pairs of the full cloud identical: "
          f"{all(np.array_equal(a, b) for a, b in zip(old_collect_pairs(em, pts_all, col_all), (src, dst)))}")

    def pmm(pairs, p, c):
        s, d = pairs(em, p, c)
        return estimate_ccm(s, d, method="ridge")

    n_all, n_rel = len(pts_all), len(pts_rel)
    rows.update(time_alternating({
        f"pairs+matrix+mse, all {n_all} known pts ({len(src)} pairs)": lambda: pmm(collect_pairs, pts_all, col_all),
        f"  previous kernels, all {n_all} known pts": lambda: pmm(old_collect_pairs, pts_all, col_all),
        f"pairs+matrix+mse, {n_rel} reliable pts": lambda: pmm(collect_pairs, pts_rel, col_rel),
        f"  previous kernels, {n_rel} reliable pts": lambda: pmm(old_collect_pairs, pts_rel, col_rel),
    }, r))
    # What the pipeline's stage "Collect paired samples" runs: from the frame, not from points and
    # colours gathered beforehand (the rows above leave out frame_points and the boolean gather of
    # raw.rgb[reliable], 0.2 + 1.1 ms of the previous stage on session frames).
    rows.update(time_alternating({
        f"Collect paired samples as capture runs it ({n_rel} reliable px)": lambda: _frame_pairs(
            em, raw.depth_m, res.reliable, raw.intrinsics, raw.T_world_from_cam, raw.rgb),
        "  previous: frame_points + rgb[reliable] + previous kernel": lambda: old_collect_pairs(
            em, frame_points(raw.depth_m, res.reliable, raw.intrinsics, raw.T_world_from_cam), raw.rgb[res.reliable]),
    }, r))
    rows.update(time_alternating({
        "  of which collect_pairs (all pts)": lambda: collect_pairs(em, pts_all, col_all),
        "  of which estimate_ccm ridge": lambda: estimate_ccm(src, dst, method="ridge"),
        "world points of a frame (frame_points)": lambda: frame_points(filled.depth_m, mask, filled.intrinsics, filled.T_world_from_cam),
    }, r))
    point = UpdateConfig(splat=False)
    rows.update(time_alternating({
        f"EM update 2000x1000, {len(pts_proj)} samples, splat": lambda: update(work_new, pts_proj, col_proj, dev, focal),
        "  previous kernel, splat": lambda: old_update(pts_proj, col_proj, dev, focal),
        f"EM update 2000x1000, {len(pts_proj)} samples, one pixel each": lambda: update(work_new, pts_proj, col_proj, dev, focal, point),
        "  previous kernel, one pixel each": lambda: old_update(pts_proj, col_proj, dev, focal, point),
    }, r))
    rows["projected mask (plane test on filled depth)"] = time_alternating({"m": lambda: cap.projected_mask(raw, filled)}, r)["m"]
    return em


def session(sim_factory, seconds: float, rows: dict) -> EnvironmentMap:
    """The default capture over a session, the previous kernels run alongside on a mirror map."""
    sim = sim_factory()
    cap = EnvironmentCapture(sim.scene.virtual_object_position, CaptureConfig())
    mirror = EnvironmentMap(cap.em.height, cap.em.width, cap.em.origin)
    old_update = OldUpdater(mirror)
    ms = {k: [] for k in ("update new", "update old", "pairs new", "pairs old")}
    cpu = {k: [] for k in ms}
    new_update, new_sums = capture_module.update, capture_module._frame_pair_sums
    cfg = cap.config
    state = {"i": 0}

    def timed(name, fn):
        t0, c0 = time.perf_counter(), time.thread_time()
        out = fn()
        cpu[name].append((time.thread_time() - c0) * 1e3)
        ms[name].append((time.perf_counter() - t0) * 1e3)
        return out

    def both(first, second):
        state["i"] += 1
        order = (first, second) if state["i"] % 2 else (second, first)
        return [o() for o in order][0 if state["i"] % 2 else 1]

    def update_both(em, pts, col, dev, focal, config, fill_only, seen=None):
        # The previous kernel has no free-space carving: its map drifts from the current one.
        return both(lambda: timed("update new", lambda: new_update(em, pts, col, dev, focal, config, fill_only, seen)),
                    lambda: timed("update old", lambda: old_update(pts, col, dev, focal, config, fill_only)))

    def pairs_both(em, depth, mask, intrinsics, T, rgb, max_diff, threads=1):
        def current():
            *sums, n = new_sums(em, depth, mask, intrinsics, T, rgb, max_diff, threads=threads)
            _ccm_from_sums(*sums, cfg.ccm_method, max_mse=cfg.max_mse, min_pairs=cfg.min_pairs,
                           max_condition=DEFAULT_MAX_CONDITION, noise_std=None, ridge=DEFAULT_RIDGE)
            return (*sums, n)

        def previous():
            s, d = old_collect_pairs(mirror, frame_points(depth, mask, intrinsics, T), rgb[mask], max_diff)
            estimate_ccm(s, d, method=cfg.ccm_method)

        # As capture.process collects them: from the frame (points and colours of the reliable pixels);
        # each row times the pairs and the fit (capture then fits the current sums once more, untimed).
        return both(lambda: timed("pairs new", current), lambda: timed("pairs old", previous))

    capture_module.update, capture_module._frame_pair_sums = update_both, pairs_both
    try:
        for _, res in ingested_frames(sim, seconds):
            cap.process(res.frame, res.reliable, res.filled, across_edges=res.across_edges)
    finally:
        capture_module.update, capture_module._frame_pair_sums = new_update, new_sums
    n = len(ms["update new"])
    # The first frame (the reference, into an empty map) is left out of the update rows.
    rows[f"session {seconds:.0f} s: EM update per frame ({n} frames)"] = _stats(ms["update new"][1:], cpu["update new"][1:])
    rows["  previous kernel, same frames"] = _stats(ms["update old"][1:], cpu["update old"][1:])
    rows[f"session {seconds:.0f} s: pairs (from the frame)+matrix+mse per frame"] = _stats(ms["pairs new"], cpu["pairs new"])
    rows["  previous kernels, same frames"] = _stats(ms["pairs old"], cpu["pairs old"])
    print(f"session {seconds:.0f} s: final maps of the current and previous kernels (no carving) differ in "
          f"{_maps_differ(cap.em, mirror)} pixels; "
          f"coverage {cap.em.valid.mean():.3f}")
    return cap.em


def _open_session(root: Path):
    """(log, pipeline config with rendering off, default origin) of the recorded session at ``root``;
    None when there is none (``bash main.sh`` writes ``runs/default/session``)."""
    if not (root / "calibration.json").is_file():
        return None
    log = SessionLog.open(root)
    cfg = PipelineConfig()
    return log, dataclasses.replace(cfg, render=dataclasses.replace(cfg.render, enabled=False)), default_origin(log)


def capture_inputs(root: Path) -> tuple[np.ndarray, CaptureConfig, list] | None:
    """Every ``EnvironmentCapture.process`` call of the recorded session at ``root``, replayed through
    the pipeline (rendering off): (origin, capture config, [(raw, reliable, filled)]); None when there
    is no session (``bash main.sh`` writes ``runs/default/session``)."""
    opened = _open_session(root)
    if opened is None:
        return None
    log, cfg, origin = opened
    pipe = Pipeline(cfg, log.calibration, origin)
    calls = []
    real = EnvironmentCapture.process

    def record(self, raw, reliable, filled, *, across_edges=None, timer=None):
        calls.append((raw, reliable.copy(), filled, across_edges))
        return real(self, raw, reliable, filled, across_edges=across_edges, timer=timer)

    EnvironmentCapture.process = record
    try:
        for packet in log:
            pipe.feed(packet)
    finally:
        EnvironmentCapture.process = real
    return origin, pipe.capture.config, calls


def previous_process(state: dict, old_update: OldUpdater, raw, reliable, filled, cfg: CaptureConfig, ms: dict) -> None:
    """``capture.process`` as it was before the kernels above were replaced: the previous kernels
    and the numpy boolean gathers of points and colours; the stages timed into ``ms``."""
    em = old_update.em

    def project(matrix):
        t0 = time.perf_counter()
        mask = filled.known  # filled_pixels "all"
        pts = frame_points(filled.depth_m, mask, filled.intrinsics, filled.T_world_from_cam)
        colours = apply_ccm(filled.rgb[mask], matrix)
        focal = 0.5 * (filled.intrinsics.fx + filled.intrinsics.fy)
        plane = discontinuity_test(filled.depth_m, filled.known).passed
        k = 2 * int(cfg.edge_margin_px) + 1
        fill_only = cv2.dilate((filled.known & ~plane).astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)[mask]
        t1 = time.perf_counter()
        old_update(pts, colours, filled.T_world_from_cam.translation, focal, cfg.update, fill_only)
        t2 = time.perf_counter()
        ms["update old"].append((t2 - t1) * 1e3)
        ms["project old"].append((t2 - t0) * 1e3)

    if not state["reference"]:
        if filled.known.any():
            state["reference"] = True
            project(np.eye(3))
        return
    t0 = time.perf_counter()
    src, dst = old_collect_pairs(em, frame_points(raw.depth_m, reliable, raw.intrinsics, raw.T_world_from_cam),
                                 raw.rgb[reliable], cfg.pair_max_depth_diff_m)
    t1 = time.perf_counter()
    ccm = estimate_ccm(src, dst, method=cfg.ccm_method, max_mse=cfg.max_mse, min_pairs=cfg.min_pairs)
    ms["pairs old"].append((t1 - t0) * 1e3)
    ms["pairs+fit old"].append((time.perf_counter() - t0) * 1e3)
    if ccm.accepted:
        project(np.array(ccm.matrix, dtype=np.float64))


def recorded_session(root: Path, rows: dict, rounds: int) -> EnvironmentMap | None:
    """The capture stages per depth frame of the recorded session, as ``capture.process`` times them
    inside the pipeline ("Collect paired samples", "Project sample to EM*") and the ``update`` call
    alone; beside them, on a mirror map fed the same frames, the previous kernels with the previous
    Python-side gathers. Frames alternate which goes first; ``rounds`` replays of the session."""
    data = capture_inputs(root)
    if data is None:
        print(f"recorded session: none at {root} (bash main.sh writes it); skipped")
        return None
    origin, cfg, calls = data
    if cfg.filled_pixels != "all" or cfg.edge_margin_px is None or not cfg.colour_correction or cfg.freeze:
        raise SystemExit("recorded session: the previous path here assumes the default capture config")
    ms = {k: [] for k in ("project new", "update new", "pairs new", "pairs+fit new", "project old", "update old", "pairs old",
                          "pairs+fit old")}
    new_update = capture_module.update
    n_differ, d_rad = 0, 0.0
    for _ in range(rounds):
        cap = EnvironmentCapture(origin, cfg)
        timer = StageTimer()
        old_update = OldUpdater(EnvironmentMap(cfg.height, cfg.width, origin))
        state = {"reference": False}

        def timed_update(*a, **k):
            t0 = time.perf_counter()
            out = new_update(*a, **k)
            ms["update new"].append((time.perf_counter() - t0) * 1e3)
            return out

        capture_module.update = timed_update
        try:
            for i, (raw, reliable, filled, across) in enumerate(calls):
                for current in ((True, False) if i % 2 else (False, True)):
                    if current:
                        timer.begin("depth")
                        cap.process(raw, reliable, filled, across_edges=across, timer=timer)
                    else:
                        previous_process(state, old_update, raw, reliable, filled, cfg, ms)
        finally:
            capture_module.update = new_update
        ms["project new"] += [r.ms for r in timer.records if r.stage == "Project sample to EM*"]
        ms["pairs new"] += [r.ms for r in timer.records if r.stage == "Collect paired samples"]
        fits = [r.ms for r in timer.records if r.stage == "Compute colour correction matrix"]
        ms["pairs+fit new"] += [a + b for a, b in zip(ms["pairs new"][-len(fits):], fits)]
        n_differ = max(n_differ, _maps_differ(cap.em, old_update.em))
        d_rad = max(d_rad, float(np.abs(cap.em.radiance_planes - old_update.em.radiance_planes).max()))
    n = len(calls)
    # The reference frame (into an empty map) is left out of the projection rows.

    def skip(a):
        return a[1:] if len(a) == n * rounds else a

    rows[f"recorded session ({n} frames): Project sample to EM* per frame"] = _stats(skip(ms["project new"]))
    rows["  previous kernels and gathers"] = _stats(skip(ms["project old"]))
    rows["recorded session: of which update()"] = _stats(skip(ms["update new"]))
    rows["  previous update kernel"] = _stats(skip(ms["update old"]))
    rows["recorded session: Collect paired samples per frame"] = _stats(ms["pairs new"])
    rows["  previous kernel and gathers "] = _stats(ms["pairs old"])
    rows["recorded session: pairs + matrix + MSE per frame (Collect + Compute stages)"] = _stats(ms["pairs+fit new"])
    rows["  previous kernel and gathers, pair arrays, estimate_ccm"] = _stats(ms["pairs+fit old"])
    # Not bit-identical since the samples' colour correction moved into the sample pass (float32
    # arithmetic instead of BLAS's) and the fit into LAPACK through numba: rounding-level differences.
    print(f"recorded session {root}: final maps of the current and previous code (no carving) differ in at most "
          f"{n_differ} pixels, max |Δradiance| {d_rad:.2g}")
    return cap.em


def recorded_update_calls(root: Path) -> tuple[np.ndarray, int, int, list] | None:
    """The arguments of every ``update`` call of the recorded session at ``root`` (pipeline replay,
    rendering off): (origin, map height, width, [(points, colours, device, focal, config,
    fill_only, seen)]); None when there is no session."""
    opened = _open_session(root)
    if opened is None:
        return None
    log, cfg, origin = opened
    calls = []
    real = capture_module.update

    def record(em, pts, col, dev, focal, config, fill_only=None, seen=None):
        calls.append((pts.copy(), col.copy(), np.array(dev), focal, config,
                      None if fill_only is None else fill_only.copy(), seen))
        return real(em, pts, col, dev, focal, config, fill_only, seen)

    capture_module.update = record
    try:
        pipe = Pipeline(cfg, log.calibration, origin)
        for packet in log:
            pipe.feed(packet)
    finally:
        capture_module.update = real
    return origin, cfg.capture.height, cfg.capture.width, calls


def update_against_baseline(root: Path, baseline, rounds: int, rows: dict, threads: int = 1) -> None:
    """``update`` of the library (with ``UpdateConfig.threads=threads``) and of ``baseline`` (another
    envmap module, on one thread) on the recorded session's update calls, alternately
    frame by frame; identical maps, stats and change logs asserted after every frame. The first
    frame (into an empty map) is left out of the times."""
    data = recorded_update_calls(root)
    if data is None:
        print(f"recorded session: none at {root} (bash main.sh writes it); skipped")
        return
    origin, h, w, calls = data
    mods = {"current": sys.modules["rgbd_envmap.envmap"], "baseline": baseline}
    ms = {k: np.zeros((rounds, len(calls) - 1)) for k in mods}
    for r in range(rounds):
        maps = {k: m.EnvironmentMap(h, w, origin) for k, m in mods.items()}
        for em in maps.values():
            em.record_changes()
        for j, (pts, col, dev, focal, config, fill_only, seen) in enumerate(calls):
            stats = {}
            # The baseline on one thread (a module without the setting ignores it): with
            # --update-baseline rgbd_envmap/envmap.py this times one thread against two.
            configs = {"current": dataclasses.replace(config, threads=threads),
                       "baseline": dataclasses.replace(config, threads=1)}
            for k in (("current", "baseline") if (j + r) % 2 == 0 else ("baseline", "current")):
                t0 = time.perf_counter()
                stats[k] = mods[k].update(maps[k], pts, col, dev, focal, configs[k], fill_only, seen)
                if j > 0:
                    ms[k][r, j - 1] = (time.perf_counter() - t0) * 1e3
            a, b = maps["current"], maps["baseline"]
            ca, cb = a.take_changes(), b.take_changes()
            same = (dataclasses.astuple(stats["current"]) == dataclasses.astuple(stats["baseline"])
                    and np.array_equal(a.valid, b.valid)
                    and np.array_equal(a.depth_m.view(np.uint32), b.depth_m.view(np.uint32))
                    and np.array_equal(a.radiance_planes.view(np.uint32), b.radiance_planes.view(np.uint32))
                    and (ca.complete, ca.updates) == (cb.complete, cb.updates)
                    and np.array_equal(ca.index, cb.index) and np.array_equal(ca.was_valid, cb.was_valid)
                    and np.array_equal(ca.old_radiance.view(np.uint32), cb.old_radiance.view(np.uint32)))
            if not same:
                raise SystemExit(f"update: the baseline module differs at frame {j} of round {r}")
    print(f"update on {len(calls)} recorded frames, {rounds} rounds: maps, stats and change logs identical "
          f"to the baseline after every frame")
    n = len(calls) - 1
    rows[f"recorded session ({n} frames): update() per frame, {threads} thread(s)"] = _stats(list(ms["current"].ravel()))
    rows["  baseline module"] = _stats(list(ms["baseline"].ravel()))
    rows[f"recorded session: update(), each frame's fastest round, {threads} thread(s)"] = _stats(list(ms["current"].min(0)))
    rows["  baseline module "] = _stats(list(ms["baseline"].min(0)))


#: ``--update-parts``: the update with one part of it switched off at a time (name, UpdateConfig fields).
UPDATE_PARTS = (
    ("defaults", {}),
    ("footprints clamped to 8 rows (max_splat_px=8)", {"max_splat_px": 8}),
    ("colour replaced, not averaged (colour_average=1)", {"colour_average": 1}),
    ("no free-space carving (carve=False)", {"carve": False}),
    ("one pixel per sample (splat=False)", {"splat": False}),
    ("the paper's update: one pixel, no carving, colour replaced", {"splat": False, "carve": False, "colour_average": 1}),
)


def update_parts(root: Path, rounds: int, rows: dict) -> None:
    """What each part of ``update`` costs on one thread: the recorded session's update calls run with
    each setting of :data:`UPDATE_PARTS` on a map of its own (so each map evolves as a capture with
    that setting would), alternately frame by frame (the order rotating), ``rounds`` passes from
    empty maps, every map recording changes as the pipeline's does. Per setting: median / p95 ms per
    frame, and the median map pixels touched and taken a frame (printed). The first frame is left
    out of the times."""
    data = recorded_update_calls(root)
    if data is None:
        print(f"recorded session: none at {root} (bash main.sh writes it); skipped")
        return
    origin, h, w, calls = data
    names = [name for name, _ in UPDATE_PARTS]
    ms = {name: [] for name in names}
    touched = {name: [] for name in names}
    taken = {name: [] for name in names}
    for r in range(rounds):
        maps = {name: EnvironmentMap(h, w, origin) for name in names}
        for em in maps.values():
            em.record_changes()
        for j, (pts, col, dev, focal, config, fill_only, seen) in enumerate(calls):
            shift = (j + r) % len(UPDATE_PARTS)
            for name, fields in UPDATE_PARTS[shift:] + UPDATE_PARTS[:shift]:
                cfg = dataclasses.replace(config, threads=1, **fields)
                t0 = time.perf_counter()
                stats = update(maps[name], pts, col, dev, focal, cfg, fill_only, seen)
                if j > 0:
                    ms[name].append((time.perf_counter() - t0) * 1e3)
                    touched[name].append(stats.touched)
                    taken[name].append(stats.taken)
                maps[name].take_changes()
    print(f"update on {len(calls) - 1} recorded frames (the first left out), {rounds} rounds, one thread, "
          f"each setting on its own map:")
    for name in names:
        print(f"  {name}: median {np.median(touched[name]):.0f} map pixels touched, {np.median(taken[name]):.0f} taken a frame")
        rows[f"update per frame, {name}"] = _stats(ms[name])


def load_translation_module(path: Path):
    """Another version of a library module (a copy of rgbd_envmap/translation.py or envmap.py), imported
    under its own name."""
    name = path.stem
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # numba's cache pickles the module name
    spec.loader.exec_module(module)
    return module


def translations(maps: dict[str, EnvironmentMap], r: int, rows: dict, baseline=None, previous: bool = True) -> None:
    off = np.array([0.1, 0.0, 0.0])
    import numba

    for name, em in maps.items():
        fns = {f"translate 2000x1000 by 10 cm, {name} (depth)": lambda em=em: translate(em, off, threads=1)}
        if numba.get_num_threads() >= 2:  # --threads 2: the default of translate(), beside one thread
            diff = _maps_differ(translate(em, off, threads=1), translate(em, off, threads=2))
            print(f"translate {name}: {diff} of {em.height * em.width} pixels differ on two threads")
            fns[f"  two threads, {name}"] = lambda em=em: translate(em, off, threads=2)
        # A caller translating every frame can pass last frame's result as out= (no fresh 34 MB).
        reused = EnvironmentMap(em.height, em.width)
        diff = _maps_differ(translate(em, off), translate_map(em, off, out=reused, threads=1))
        print(f"translate {name}: {diff} of {em.height * em.width} pixels differ with out=")
        fns[f"  out= (the output map reused), {name}"] = lambda em=em, reused=reused: translate_map(em, off, out=reused, threads=1)
        if baseline is not None:
            diff = _maps_differ(translate(em, off), baseline.translate_map(em, off))
            print(f"translate {name}: {diff} of {em.height * em.width} pixels differ from the baseline module")
            fns[f"  baseline module, {name}"] = lambda em=em: baseline.translate_map(em, off)
        if previous:
            diff = _maps_differ(translate(em, off), old_translate(em, off))
            print(f"translate {name}: {diff} of {em.height * em.width} pixels differ from the previous kernel "
                  f"(float32 landing positions)")
            fns[f"  previous kernel, {name}"] = lambda em=em: old_translate(em, off)
            fns[f"  gardner, {name}"] = lambda em=em: translate(em, off, "gardner")
        rows.update(time_alternating(fns, r))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--session", type=float, default=20.0, help="seconds of the session part (0: skip it)")
    parser.add_argument("--recorded", type=Path, default=Path("runs/default/session"),
                        help="recorded session for the capture-stage rows (skipped when missing)")
    parser.add_argument("--recorded-rounds", type=int, default=2, help="replays of the recorded session (0: skip it)")
    parser.add_argument("--only-recorded", action="store_true", help="the recorded-session rows only")
    parser.add_argument("--only-translation", action="store_true",
                        help="the translation rows only, for the recorded session's final map and the true map")
    parser.add_argument("--translation-baseline", type=Path, default=None,
                        help="a copy of another version of rgbd_envmap/translation.py to time alternately")
    parser.add_argument("--translation-rounds", type=int, default=None, help="repeats per translation row")
    parser.add_argument("--update-baseline", type=Path, default=None,
                        help="a copy of another version of rgbd_envmap/envmap.py: time update() against it "
                             "on the recorded session (alone; --recorded-rounds passes)")
    parser.add_argument("--update-parts", action="store_true",
                        help="alone: what each part of update() costs on the recorded session (one thread; "
                             "--recorded-rounds passes)")
    parser.add_argument("--update-threads", type=int, default=1,
                        help="with --update-baseline: UpdateConfig.threads of the library's calls")
    parser.add_argument("--threads", type=int, default=1,
                        help="numba threads for the library's kernels (default 1: the issue's figures are "
                             "one-thread; the pipeline's default is 2, see docs/envmap.md, fifth round)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    import numba

    numba.set_num_threads(max(1, min(max(args.threads, args.update_threads if args.update_baseline else 1),
                                      numba.config.NUMBA_NUM_THREADS)))
    baseline = load_translation_module(args.translation_baseline) if args.translation_baseline else None
    t_rounds = args.translation_rounds or max(5, args.repeats // 5)
    if args.update_baseline:
        rows = {}
        update_against_baseline(args.recorded, load_translation_module(args.update_baseline),
                                max(1, args.recorded_rounds), rows, args.update_threads)
        print_rows(rows)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
        return
    if args.update_parts:
        rows = {}
        update_parts(args.recorded, max(1, args.recorded_rounds), rows)
        print_rows(rows)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
        return
    if args.only_recorded:
        rows: dict[str, dict] = {}
        recorded_session(args.recorded, rows, max(1, args.recorded_rounds))
        print_rows(rows)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
        return

    def make_sim():
        return Simulator(load_scene("office"), load_trajectory("orbit"),
                         TangoDeviceConfig(colour=ColourCameraConfig(width=640, height=360)), seed=0)

    sim = make_sim()
    if args.only_translation:
        rows = {}
        maps = {}
        em = recorded_session(args.recorded, {}, 1)
        if em is not None:
            maps["recorded session's final map"] = em
        origin = sim.scene.virtual_object_position
        gt = render_envmap(sim.raycaster, origin, 1000, 2000, 0.0)
        maps["true map"] = EnvironmentMap.from_arrays(gt.radiance, gt.distance_m, gt.valid, origin)
        translations(maps, t_rounds, rows, baseline, previous=False)
        print_rows(rows)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
        return
    frames = [res for _, res in ingested_frames(sim, 4.2)]
    rows: dict[str, dict] = {}
    r = args.repeats
    em4 = one_frame(sim, frames, r, rows)
    maps = {"4.2 s map": em4}
    if args.session > 0:
        maps[f"{args.session:.0f} s map"] = session(make_sim, args.session, rows)
    if args.recorded_rounds > 0:
        recorded_session(args.recorded, rows, args.recorded_rounds)
    origin = sim.scene.virtual_object_position
    gt = render_envmap(sim.raycaster, origin, 1000, 2000, 0.0)
    maps["true map"] = EnvironmentMap.from_arrays(gt.radiance, gt.distance_m, gt.valid, origin)
    translations(maps, t_rounds, rows, baseline)
    print_rows(rows)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
