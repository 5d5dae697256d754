"""Kernel of the weighted k-means of the virtual area lights (:mod:`rgbd_envmap.lights.areas`),
called from that module only.

What it computes, in numpy: :func:`rgbd_envmap.reference.lights.weighted_kmeans`; the tests compare
the two bit for bit (no fastmath: the same operations in the same order). numpy needs an (N, k, 3)
temporary per iteration for the distances; one pass over the points here assigns each to its
nearest centre and adds it to that centre's sums at once.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["weighted_kmeans_kernel"]


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
