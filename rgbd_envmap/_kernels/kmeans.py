"""Kernels of the virtual area lights (:mod:`rgbd_envmap.lights.areas`), called from that module
only: the weighted k-means, and the cuts of each light into its parts.

What they compute, in numpy: :func:`rgbd_envmap.reference.lights.weighted_kmeans` and
:func:`rgbd_envmap.reference.lights.split_parts`; the tests compare each pair bit for bit (no
fastmath: the same operations in the same order). numpy needs an (N, k, 3) temporary per
iteration for the distances; one pass over the points here assigns each to its nearest centre and
adds it to that centre's sums at once. The cuts took a handful of numpy calls per cut, 7 cuts a
light, from Python; here they run for all lights in one call, sorting each group in place.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["split_parts_kernel", "weighted_kmeans_kernel"]


@numba.njit(cache=True, nogil=True)
def _nearest(points, centres, labels, d2):  # pragma: no cover - compiled
    """labels[i], d2[i]: the nearest centre of point i (the first of equals) and its squared distance.
    Returns whether any label changed."""
    N = points.shape[0]
    k = centres.shape[0]
    changed = False
    for i in range(N):
        x0, x1, x2 = points[i, 0], points[i, 1], points[i, 2]
        best = np.inf
        arg = 0
        for j in range(k):
            e0 = x0 - centres[j, 0]
            e1 = x1 - centres[j, 1]
            e2 = x2 - centres[j, 2]
            d = e0 * e0 + e1 * e1 + e2 * e2
            if d < best:
                best = d
                arg = j
        if labels[i] != arg:
            changed = True
        labels[i] = arg
        d2[i] = best
    return changed


@numba.njit(cache=True, nogil=True)
def weighted_kmeans_kernel(points, weights, centres, labels, iterations):  # pragma: no cover - compiled
    """Lloyd's iterations on ``points`` (N, 3) with ``weights`` (N,) > 0 from ``centres`` (k, 3),
    updated in place; ``labels`` (N,) int64 gets each point's centre. Each iteration: assign every
    point to its nearest centre, move each centre to its points' weighted mean; a centre left with
    no weight moves to the point of largest weight × squared distance to its nearest centre
    (updated as each empty centre moves). Stops after ``iterations`` or when no label changes
    (labels start at −1, so the first assignment always counts). Returns the iterations done."""
    N = points.shape[0]
    k = centres.shape[0]
    d2 = np.empty(N)
    sums = np.empty((k, 3))
    wsum = np.empty(k)
    for i in range(N):
        labels[i] = -1
    done = 0
    for _ in range(iterations):
        if not _nearest(points, centres, labels, d2):
            break
        done += 1
        sums[:] = 0.0
        wsum[:] = 0.0
        for i in range(N):
            j = labels[i]
            w = weights[i]
            wsum[j] += w
            sums[j, 0] += w * points[i, 0]
            sums[j, 1] += w * points[i, 1]
            sums[j, 2] += w * points[i, 2]
        for j in range(k):
            if wsum[j] > 0.0:
                centres[j, 0] = sums[j, 0] / wsum[j]
                centres[j, 1] = sums[j, 1] / wsum[j]
                centres[j, 2] = sums[j, 2] / wsum[j]
        for j in range(k):
            if wsum[j] > 0.0:
                continue
            # d2 is still the distance to the centres before the move: the reseed uses it, then
            # lowers it by the new centre
            best = -1.0
            arg = 0
            for i in range(N):
                s = weights[i] * d2[i]
                if s > best:
                    best = s
                    arg = i
            centres[j, 0] = points[arg, 0]
            centres[j, 1] = points[arg, 1]
            centres[j, 2] = points[arg, 2]
            for i in range(N):
                e0 = points[i, 0] - centres[j, 0]
                e1 = points[i, 1] - centres[j, 1]
                e2 = points[i, 2] - centres[j, 2]
                d = e0 * e0 + e1 * e1 + e2 * e2
                if d < d2[i]:
                    d2[i] = d
    _nearest(points, centres, labels, d2)
    return done


@numba.njit(cache=True, nogil=True, error_model="numpy")
def split_parts_kernel(points, weights, order, bounds, m, part_of):  # pragma: no cover - compiled
    """``part_of[i]``: the part (0 … m − 1) of point i within its group, for the groups
    ``order[bounds[j]:bounds[j + 1]]`` (point indices), each cut into ``m`` parts of about equal
    weight as :func:`rgbd_envmap.reference.lights.split_parts` cuts them (same order of parts, same
    sums point after point: bit for bit). ``order`` is reordered in place within each group."""
    stack_s = np.empty(m + 1, np.int64)
    stack_e = np.empty(m + 1, np.int64)
    stack_p = np.empty(m + 1, np.int64)
    var = np.empty(3)
    mu = np.empty(3)
    for g in range(bounds.shape[0] - 1):
        top = 0
        stack_s[0], stack_e[0], stack_p[0] = bounds[g], bounds[g + 1], m
        top = 1
        part = 0
        while top > 0:
            top -= 1
            s, e, parts = stack_s[top], stack_e[top], stack_p[top]
            if parts == 1 or e - s <= 1:
                for t in range(s, e):
                    part_of[order[t]] = part
                part += parts
                continue
            tw0 = 0.0
            for t in range(s, e):
                tw0 += weights[order[t]]
            uniform = not (tw0 > 0.0)
            tw = 0.0
            for t in range(s, e):
                tw += 1.0 if uniform else weights[order[t]]
            for c in range(3):
                acc = 0.0
                for t in range(s, e):
                    w = 1.0 if uniform else weights[order[t]]
                    acc += w * points[order[t], c]
                mu[c] = acc / tw
            for c in range(3):
                acc = 0.0
                for t in range(s, e):
                    w = 1.0 if uniform else weights[order[t]]
                    d = points[order[t], c] - mu[c]
                    acc += w * (d * d)
                var[c] = acc
            vmax = max(var[0], max(var[1], var[2]))
            axis = 0 if var[0] >= 0.8 * vmax else (1 if var[1] >= 0.8 * vmax else 2)
            seg = order[s:e].copy()
            keys = np.empty(e - s)
            for t in range(e - s):
                keys[t] = points[seg[t], axis]
            perm = np.argsort(keys, kind="mergesort")
            for t in range(e - s):
                order[s + t] = seg[perm[t]]
            a = (parts + 1) // 2
            target = tw * a / parts
            # the first prefix reaching the target (cum[i] ≥ target), then one point fewer if that
            # is nearer; none reaching it (rounding): all but one point
            cum = 0.0
            cut = e - s - 1
            for t in range(e - s):
                prev = cum
                cum += 1.0 if uniform else weights[order[s + t]]
                if cum >= target:
                    cut = t + 1
                    if cut > 1 and target - prev < cum - target:
                        cut -= 1
                    break
            cut = min(max(cut, 1), e - s - 1)
            stack_s[top], stack_e[top], stack_p[top] = s + cut, e, parts - a
            top += 1
            stack_s[top], stack_e[top], stack_p[top] = s, s + cut, a
            top += 1
