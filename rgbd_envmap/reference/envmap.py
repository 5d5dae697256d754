"""References of the environment map's kernels: the update, the colour pairs, the translation.

- :func:`update_reference`: :func:`rgbd_envmap.envmap.update` one sample and one pixel at a time;
- :func:`pairs_reference`: :func:`rgbd_envmap.envmap.collect_pairs` with numpy indexing;
- :func:`translate_reference`: the depth warp of :func:`rgbd_envmap.envmap.translate` one source
  pixel at a time with a sequential z-test;
- :func:`gardner_reference`: Gardner et al.'s backward warp with whole-map numpy arrays and libm's
  arctangent.

Free-space carving is not modelled by :func:`update_reference` (call it with ``carve=False`` or
without ``seen``); the carving test has its own reference in the tests (it needs the frame's depth).
"""

from __future__ import annotations

import math

import numpy as np

from rgbd_envmap.envmap.map import EnvironmentMap
from rgbd_envmap.envmap.rules import rule_removal
from rgbd_envmap.envmap.tables import trig_tables
from rgbd_envmap.envmap.translation import reprojected_coordinates
from rgbd_envmap.envmap.map_update import UpdateConfig, map_coordinates
from rgbd_envmap.geometry import equirect_directions, equirect_pixel_index

__all__ = ["span", "span32", "update_reference", "pairs_reference", "translate_reference", "gardner_reference"]


def span(x: float, half: float, limit: float) -> tuple[int, int]:
    """First and last pixel k whose centre k + 0.5 lies within ``half`` of continuous coordinate
    ``x``; ``half`` is at least 0.5 (the pixel ``x`` falls in) and at most ``limit``."""
    h = min(max(half, 0.5), limit)
    return int(np.ceil(x - h - 0.5)), int(np.floor(x + h - 0.5))


def span32(x: float, half: float, limit: float) -> tuple[int, int]:
    """:func:`span` in float32, as the translation computes its footprints."""
    h = np.float32(min(max(half, 0.5), limit))
    x = np.float32(x)
    return int(np.ceil(x - h - np.float32(0.5))), int(np.floor(x + h - np.float32(0.5)))


def update_reference(em: EnvironmentMap, pts: np.ndarray, cols: np.ndarray, device: np.ndarray, focal: float,
                     config: UpdateConfig, fill_only: np.ndarray | None = None,
                     averaged: np.ndarray | None = None, views: np.ndarray | None = None,
                     clipped: np.ndarray | None = None, clip_flags: np.ndarray | None = None) -> tuple[int, dict[str, int]]:
    """The map update one sample and one pixel at a time, writing ``em`` in place.

    1. Each finite sample (point and colour) at a positive finite distance covers its footprint's
       pixels (``config.splat``; else the one pixel it falls in); per pixel the closest sample wins,
       the first in sample order on equal float32 distances.
    2. Each covered pixel takes its winning sample when a rule holds, tested in this order: empty;
       closer (unless the sample is ``fill_only``); the device in the trusted sphere; removal.
    3. A taken pixel's depth becomes the mean of old and new (the new one if it was empty); its
       colour is replaced, or averaged when the sample is of the same surface (its distance within
       ``carve_tol_rel`` · d + ``carve_tol_abs_m`` of the stored d) and ``colour_average`` > 1.
    4. The viewpoint rule (``config.view_ratio`` finite, the device outside the trusted sphere): a
       pixel a rule took whose sample is of the same surface (the test of 3) is kept as it is, and
       counted ``"kept_view"`` instead of under its rule, when the device's distance from the origin
       exceeds view_ratio × the pixel's view distance. A taken pixel's view distance becomes the
       device's distance (float32), or the smaller of the two for a same-surface sample.
    5. HDR (``clipped`` (N,) bool per sample, ``clip_flags`` (H, W) per pixel, 1 where its colour came
       from a clipped sample): after 4, a same-surface clipped sample over an unclipped colour is
       refused (``"kept_clipped"``); a same-surface clipped sample over a clipped colour keeps the
       larger value per channel (not averaged); an unclipped sample over a clipped colour replaces
       it. Every taken pixel's flag becomes the sample's.

    ``averaged``: (H, W) int array of each pixel's colour-average count, ``views``: (H, W) float32
    array of the view distances (inf: unknown), ``clip_flags``, all kept by the caller across calls
    (zeros, inf and zeros when None). Returns the number of covered pixels and the pixels taken per
    rule (plus ``"averaged"``, ``"kept_view"`` and ``"kept_clipped"``).
    """
    if averaged is None:
        averaged = np.zeros((em.height, em.width), int)
    if views is None:
        views = np.full((em.height, em.width), np.inf, np.float32)
    if clip_flags is None:
        clip_flags = np.zeros((em.height, em.width), np.uint8)
    if clipped is None:
        clipped = np.zeros(len(pts), bool)
    h, w = em.height, em.width
    row_px, col_px = h / math.pi, w / (2 * math.pi)
    pts = np.asarray(pts, np.float64)
    device = np.asarray(device, np.float64)
    v_all, u_all, r_all = map_coordinates(pts, em.origin, h, w)
    zbuf: dict[tuple[int, int], tuple[np.float32, int]] = {}
    for i, (p, c) in enumerate(zip(pts, cols)):
        if not (np.isfinite(p).all() and np.isfinite(c).all()):
            continue
        d = p - em.origin
        r, v, u = r_all[i], v_all[i], u_all[i]
        hh = math.sqrt(d[0] * d[0] + d[1] * d[1])
        if not (r > 0 and np.float32(r) < np.inf):
            continue
        row, col = min(int(v), h - 1), int(u) % w
        r0, r1, c0, c1 = row, row, col, col
        if config.splat:
            e = p - device
            angle = config.splat_scale * math.sqrt(e @ e) / (focal * r)
            s = max(hh / r, 1e-6)
            r0, r1 = span(v, 0.5 * angle * row_px, config.max_splat_px)
            c0, c1 = span(u, 0.5 * angle * col_px / s, min(config.max_splat_px / s, w // 2))
        for rr in range(max(r0, 0), min(r1, h - 1) + 1):
            for cc in range(c0, c1 + 1):
                key = (rr, cc % w)
                if key not in zbuf or r < zbuf[key][0]:
                    zbuf[key] = (np.float32(r), i)
    rows, cols_t = trig_tables(h, w)
    o = device - em.origin
    dev_r = math.sqrt(o @ o)
    counts = {"empty": 0, "closer": 0, "trusted": 0, "removal": 0, "averaged": 0, "kept_view": 0, "kept_clipped": 0}
    by_view = config.view_ratio < math.inf and not dev_r < config.trusted_radius_m
    for (rr, cc), (r, i) in zbuf.items():
        rule = None
        if not em.valid[rr, cc]:
            rule = "empty"
        elif r < em.depth_m[rr, cc] and not (fill_only is not None and fill_only[i]):
            rule = "closer"
        elif dev_r < config.trusted_radius_m:
            rule = "trusted"
        else:
            st = rows[rr, 0]
            d = np.array([st * cols_t[cc, 1], st * cols_t[cc, 0], rows[rr, 1]], float)
            along = o @ d
            to_ray = math.sqrt((o - along * d) @ (o - along * d)) if along > 0 else dev_r
            if rule_removal(along, to_ray, r, em.depth_m[rr, cc], config.removal_radius_m):
                rule = "removal"
        if rule:
            stored = float(em.depth_m[rr, cc])
            surface = em.valid[rr, cc] and abs(float(r) - stored) <= stored * config.carve_tol_rel + config.carve_tol_abs_m
            if by_view and surface and dev_r > float(views[rr, cc]) * config.view_ratio:
                counts["kept_view"] += 1
                continue
            sample_clipped, pixel_clipped = bool(clipped[i]), bool(clip_flags[rr, cc])
            if surface and sample_clipped and not pixel_clipped:
                counts["kept_clipped"] += 1
                continue
            counts[rule] += 1
            views[rr, cc] = min(views[rr, cc], np.float32(dev_r)) if surface else np.float32(dev_r)
            clip_flags[rr, cc] = sample_clipped
            n_avg = config.colour_average
            both = surface and sample_clipped and pixel_clipped
            same = surface and n_avg > 1 and sample_clipped == pixel_clipped and not both
            k = averaged[rr, cc]
            if both:  # two lower bounds of the radiance: the larger, per channel
                em.radiance_planes[:, rr, cc] = np.maximum(em.radiance_planes[:, rr, cc], np.asarray(cols[i], np.float32))
                averaged[rr, cc] = 0
            elif same:  # a running mean over at most n_avg samples, in float32 as the kernel
                wgt = np.float32(1.0) / (np.float32(k) + np.float32(2.0))
                old = em.radiance_planes[:, rr, cc].copy()
                em.radiance_planes[:, rr, cc] = old + (np.asarray(cols[i], np.float32) - old) * wgt
                averaged[rr, cc] = min(k + 1, n_avg - 2)
                counts["averaged"] += 1
            else:
                em.radiance_planes[:, rr, cc] = cols[i]
                averaged[rr, cc] = 0
            em.depth_m[rr, cc] = r if not em.valid[rr, cc] else 0.5 * (em.depth_m[rr, cc] + r)
            em.valid[rr, cc] = True
    return len(zbuf), counts


def pairs_reference(em: EnvironmentMap, points_world: np.ndarray, colours: np.ndarray,
                    max_depth_diff_m: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Colour pairs: each point's map pixel; kept where the map has data whose depth is within
    ``max_depth_diff_m`` of the point's distance. Returns (src, dst) float32 in point order."""
    pts = np.asarray(points_world, np.float64)
    rel = pts - em.origin
    rows, cols, ok = equirect_pixel_index(rel, em.height, em.width)
    dist = np.linalg.norm(rel, axis=1)
    keep = ok & em.valid[rows, cols] & (np.abs(em.depth_m[rows, cols] - dist) <= max_depth_diff_m)
    return np.asarray(colours)[keep].astype(np.float32), em.radiance[rows[keep], cols[keep]]


def translate_reference(em: EnvironmentMap, offset: np.ndarray, max_splat_px: int = 8,
                        max_rel_jump: float = 0.2) -> EnvironmentMap:
    """The depth-aware forward warp one source pixel at a time, in raster order, with a sequential
    z-test (closer wins, the first on equal distances).

    Each valid source pixel with a positive finite landing distance covers the target pixels within
    half the distance to where its 4-neighbours land (at least the pixel it lands in), ignoring
    neighbours that are invalid or whose depth differs by more than ``max_rel_jump`` of its own
    (across an edge); rows are clamped to ``max_splat_px`` each side, columns to the same angle.
    """
    h, w = em.height, em.width
    rs = trig_tables(h, w)[0][:, 0]
    pv, pu, pd = reprojected_coordinates(em, offset)
    out = EnvironmentMap(h, w, em.origin + np.asarray(offset, np.float64))
    zbuf = np.full((h, w), np.inf, np.float32)
    for r in range(h):
        for c in range(w):
            if not em.valid[r, c] or not (0 < pd[r, c] < np.inf):
                continue
            ext = []
            for a, period in ((pv, 0.0), (pu, float(w))):
                best = 0.0
                for nr, nc in ((max(r - 1, 0), c), (min(r + 1, h - 1), c), (r, (c - 1) % w), (r, (c + 1) % w)):
                    d, dn = em.depth_m[r, c], em.depth_m[nr, nc]
                    if em.valid[nr, nc] and abs(dn - d) <= np.float32(max_rel_jump) * d:
                        diff = abs(a[nr, nc] - a[r, c])
                        best = max(best, 0.5 * (min(diff, period - diff) if period else diff))
                ext.append(max(best, 0.5))
            v, u, nd = pv[r, c], pu[r, c], pd[r, c]
            row = min(int(v), h - 1)
            if ext == [0.5, 0.5]:
                targets = [(row, int(u) % w)]
            else:
                lim = min(max_splat_px / max(float(rs[row]), 1e-6), w // 2)
                r0, r1 = span32(v, ext[0], max_splat_px)
                c0, c1 = span32(u, ext[1], np.float32(lim))
                targets = [(rr, cc % w) for rr in range(max(r0, 0), min(r1, h - 1) + 1) for cc in range(c0, c1 + 1)]
            for t in targets:
                if nd < zbuf[t]:
                    zbuf[t] = nd
                    out.depth_m[t] = nd
                    out.valid[t] = True
                    out.radiance_planes[(slice(None), *t)] = em.radiance_planes[:, r, c]
    return out


def gardner_reference(em: EnvironmentMap, offset: np.ndarray, radius_m: float) -> EnvironmentMap:
    """Gardner et al.'s warp: every target pixel's ray from the new origin meets the sphere of
    ``radius_m`` around the old one at distance t; the source pixel in that direction gives its
    colour and validity, t its depth. Whole-map numpy arrays and libm's arctangent (the kernel's
    polynomial one may move a ray within 1.2e-8 rad of a pixel edge to the next pixel)."""
    h, w = em.height, em.width
    off = np.asarray(offset, np.float64)
    dirs = equirect_directions(h, w).astype(np.float64)
    b = dirs @ off
    t = -b + np.sqrt(b * b - off @ off + radius_m**2)
    rows, cols, _ = equirect_pixel_index(off + t[..., None] * dirs, h, w)
    out = EnvironmentMap(h, w, em.origin + off)
    ok = em.valid[rows, cols]
    out.valid[:] = ok
    out.depth_m[ok] = t[ok]
    out.radiance_planes[:, ok] = em.radiance_planes[:, rows[ok], cols[ok]]
    return out
