"""Virtual area lights (paper 000 §4.3): the pixels of a map's direct part grouped by where they are
in the room, each group one light with its area.

With the map's depth every pixel is a point of the room (origin + direction × distance). The valid
pixels are clustered by weighted k-means on those positions, each pixel weighted by its energy
(luminance × solid angle). Light j then stands for its cluster's pixels exactly:

- ``power`` = Σ L Ω over its pixels per channel (so Σ power is the map's integral, to rounding);
- ``positions`` = the energy-weighted mean of their positions, ``directions`` the unit vector from
  the origin to it (the mean of the pixels' directions, when that point is the origin itself);
- ``solid_angle`` = Σ Ω of its pixels: the light's extent as seen from the origin;
- ``points`` (n, k, 3) and ``point_power`` (n, k, 3): the cluster cut into k parts of about equal
  energy, each part's energy-weighted mean position and its power. The parts are made by halving
  (a k-d tree): a part that is to hold m points is cut across its widest world axis (the first of
  x, y, z whose energy-weighted spread is at least 0.8 of the largest) where ⌈m/2⌉ / m of its energy
  lies on one side. A renderer that gives each part its own shadow ray gets the light's penumbra
  (:meth:`LightSet.point_lights`). World axes rather than the principal axis: a round lamp's spread
  is nearly isotropic, and its principal axis, and with it every part, would turn with the noise of
  its pixels from frame to frame; the parts of a lamp that holds still stay put, so their shadow
  rays are reused.

A window and a ceiling lamp a metre apart in the room fall into different lights even when they
are close on the sphere, and each light sits on its emitter, where a direction sampler's light
sits at the mean distance of whatever its region holds (for a region that mixes the lamp and the
table below it, somewhere in between).

k-means starts from the centres of the last call (:class:`AreaLightState`), so a light follows its
emitter from one frame to the next instead of being re-chosen; the first call (or one asking for
another count) seeds them deterministically: the pixel of most energy, then each time the pixel of
largest energy × squared distance to its nearest seed (the greedy form of k-means++ seeding).
Lloyd's iterations are one compiled pass each (:mod:`rgbd_envmap._kernels.kmeans`, tested bit for
bit against :func:`rgbd_envmap.reference.lights.weighted_kmeans`).

Where we depart: the paper clusters 4k importance samples of the direct atlas by position and
normal, then assigns every texel to its nearest centre. We cluster all the direct pixels (no
sampling noise; the direct part is a few thousand pixels on the pipeline's grid) and by position
only (the map has no normals; positions already part the emitters of a room).

References:
    - Rohmer, Büschel, Dachselt, Grosch (paper 000) §4.3 (virtual area lights, k-means clustering,
      a light's intensity summed over its texels, eq. 6).
    - Arthur, Vassilvitskii (2007), k-means++: the advantages of careful seeding.
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap._kernels.kmeans import split_parts_kernel, weighted_kmeans_kernel
from rgbd_envmap.checks import check_number
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.geometry import equirect_directions
from rgbd_envmap.lights.maps import MapInputs, luminance, raise_bad_values

__all__ = ["AreaLightState", "area_samples", "seed_centres", "split_parts"]


class AreaLightState:
    """The cluster centres (k, 3) world metres of the last :func:`area_samples` call, the next call's
    starting point. ``reset()`` forgets them."""

    def __init__(self) -> None:
        self.centres: np.ndarray | None = None
        self.frames = 0

    def reset(self) -> None:
        self.centres = None
        self.frames = 0


def seed_centres(points: np.ndarray, weights: np.ndarray, k: int) -> np.ndarray:
    """(k, 3) deterministic seeds: the point of largest weight, then each time the point of largest
    weight × squared distance to its nearest seed (the first of equals)."""
    i = int(np.argmax(weights))
    out = np.empty((k, 3))
    out[0] = points[i]
    d2 = np.sum((points - points[i]) ** 2, axis=1)
    for j in range(1, k):
        i = int(np.argmax(weights * d2))
        out[j] = points[i]
        d2 = np.minimum(d2, np.sum((points - points[i]) ** 2, axis=1))
    return out


def split_parts(points: np.ndarray, weights: np.ndarray, m: int) -> list[np.ndarray]:
    """Index arrays of ``m`` parts of ``points`` (N, 3) of about equal weight: recursive cuts across
    the widest world axis of the weighted positions (module docstring; compiled, bit for bit
    :func:`rgbd_envmap.reference.lights.split_parts`). Parts may be empty (fewer points than parts,
    or one point holding most of the weight)."""
    pts = np.ascontiguousarray(points, np.float64)
    order = np.arange(len(pts), dtype=np.int64)
    part_of = np.zeros(len(pts), np.int64)
    split_parts_kernel(pts, np.ascontiguousarray(weights, np.float64), order, np.array([0, len(pts)], np.int64),
                       int(m), part_of)
    return [order[part_of[order] == p] for p in range(int(m))]


def area_samples(inputs: MapInputs, n: int, state: AreaLightState | None = None, points: int = 8,
                 iterations: int = 20) -> tuple:
    """Virtual area lights of a checked map with depth (module docstring): (directions (n', 3),
    power (n', 3), solid_angle (n',), positions (n', 3), parts' positions (n', k, 3), parts' power
    (n', k, 3)), n' ≤ n the clusters that hold a pixel (fewer than n when the map has fewer
    distinct points)."""
    if inputs.depth_m is None:
        raise InvalidInputError("depth_m: method 'val' clusters the map's points; it needs the map's depth")
    if state is not None and not isinstance(state, AreaLightState):
        raise InvalidInputError(f"state: method 'val' takes an AreaLightState, got {type(state).__name__}")
    points = check_number(points, "points", low=1, high=4096, integer=True)
    iterations = check_number(iterations, "iterations", low=1, high=10_000, integer=True)
    H, W = inputs.radiance.shape[:2]
    if inputs.valid is None:
        rows, cols = np.divmod(np.arange(H * W), W)
    else:
        rows, cols = np.nonzero(inputs.valid)
    rad = inputs.radiance[rows, cols].astype(np.float64)
    if not np.isfinite(rad).all() or (len(rad) and rad.min() < 0):
        raise_bad_values(inputs, float(np.nanmin(rad)) if np.isfinite(rad).any() else 0.0, bool(np.isfinite(rad).all()))
    omega = inputs.row_omega[rows]
    energy = rad * omega[:, None]
    weight = luminance(energy)
    dirs = equirect_directions(H, W)[rows, cols].astype(np.float64)
    pos = inputs.origin + dirs * inputs.depth_m[rows, cols].astype(np.float64)[:, None]
    # all-black pixels: the clusters still part the room (uniform weights); their power is zero
    w_cluster = weight if weight.sum() > 0 else np.ones(len(weight))
    k = min(n, len(pos))
    start = state.centres if state is not None and state.centres is not None and len(state.centres) == k else None
    centres = np.ascontiguousarray(seed_centres(pos, w_cluster, k) if start is None else start, np.float64).copy()
    labels = np.empty(len(pos), np.int64)
    weighted_kmeans_kernel(np.ascontiguousarray(pos), np.ascontiguousarray(w_cluster), centres, labels, iterations)
    if state is not None:
        state.centres = centres.copy()
        state.frames += 1
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(k + 1))
    # every light's parts in one compiled call, then each part's sums by (light, part)
    part_of = np.zeros(len(pos), np.int64)
    split_parts_kernel(np.ascontiguousarray(pos), np.ascontiguousarray(weight, np.float64), order.copy(),
                       bounds.astype(np.int64), points, part_of)
    key = labels * points + part_of
    size = k * points
    part_w = np.bincount(key, weights=weight, minlength=size)
    part_n = np.bincount(key, minlength=size)
    part_wx = np.stack([np.bincount(key, weights=weight * pos[:, c], minlength=size) for c in range(3)], axis=1)
    part_x = np.stack([np.bincount(key, weights=pos[:, c], minlength=size) for c in range(3)], axis=1)
    part_e = np.stack([np.bincount(key, weights=energy[:, c], minlength=size) for c in range(3)], axis=1)
    out_d, out_p, out_o, out_x, out_pts, out_pp = [], [], [], [], [], []
    for j in range(k):
        idx = order[bounds[j]:bounds[j + 1]]
        if not len(idx):
            continue
        wj = weight[idx]
        tw = float(wj.sum())
        x = (wj @ pos[idx]) / tw if tw > 0 else pos[idx].mean(axis=0)
        v = x - inputs.origin
        nv = float(np.linalg.norm(v))
        if nv > 1e-9:
            d = v / nv
        else:  # the light's points surround the origin: the mean of its directions
            s = (wj if tw > 0 else np.ones(len(idx))) @ dirs[idx]
            d = s / np.linalg.norm(s) if np.linalg.norm(s) > 0 else dirs[idx[0]]
        sl = slice(j * points, (j + 1) * points)
        pw, pn = part_w[sl, None], part_n[sl, None]
        # a part's energy-weighted mean position; without energy its plain mean; empty: the light's
        part_pos = np.where(pw > 0, part_wx[sl] / np.where(pw > 0, pw, 1.0),
                            np.where(pn > 0, part_x[sl] / np.maximum(pn, 1), x))
        part_pow = part_e[sl]
        out_d.append(d)
        out_p.append(energy[idx].sum(axis=0))
        out_o.append(float(omega[idx].sum()))
        out_x.append(x)
        out_pts.append(part_pos)
        out_pp.append(part_pow)
    return (np.array(out_d).reshape(-1, 3), np.array(out_p).reshape(-1, 3), np.array(out_o),
            np.array(out_x).reshape(-1, 3), np.array(out_pts).reshape(-1, points, 3),
            np.array(out_pp).reshape(-1, points, 3))
