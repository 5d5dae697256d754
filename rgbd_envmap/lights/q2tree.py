"""The Q2-Tree light sampler: an adaptive quad tree on the 12 HEALPix base quads, one light per
leaf (paper 002 §3.2, Algorithm 1, after Wan, Wong and Leung 2005).

The sphere is cut into the 12 base quads of HEALPix; a quad at level i (nside = 2^i) covers exactly
Δω = π / (3 · 4^i) and, in the nested scheme, its four children at level i + 1 are 4p … 4p + 3. The
tree splits, again and again, the leaf of highest importance p = Y^a · Δω^b (Y the luminance of the
quad's power, a = 1, b = 1/4 by default) until it has at least n leaves; each split adds 3, so a tree
has 12 + 3k leaves: n rounded up to that form (at least 12). Each leaf becomes one light: its power
is the quad's Σ radiance × solid angle, its solid angle Δω, its direction the quad's centre jittered
deterministically (the centre of one of its 16 grandchildren, chosen by a hash of the quad), as the
source proposes.

How (where we depart): the quads' sums come from one pass over the map into the finest level's
cells (:mod:`rgbd_envmap.lights.cells`: each pixel into the quad holding its centre), then a sum
pyramid up the nested levels (4 → 1 per level), which gives every quad's sum in O(1) as the
paper's summed-area tables do, and makes Σ power equal the map's integral to float64 rounding. The
tree itself is not grown one split at a time: with a, b ≥ 0 a child is never more important than its
parent, so the tree Algorithm 1 grows by k splits holds exactly the k most important quads as its
interior nodes (ties: lower level, then lower index, first). :func:`build` selects them at once
(a partition over all quads, O(quads)). The readable one-split-at-a-time form is
:func:`rgbd_envmap.reference.lights.q2tree`, and the tests check the two agree.

Across frames (:class:`Q2TreeState`), the tree is not rebuilt: the new frame's importances are
evaluated for the previous tree and merge-and-split steps (merge the least important interior node
whose children are leaves, split the most important leaf) run until no leaf outranks an interior
node; the result is exactly the tree built from scratch on the new frame (tested), in as many steps
as the tree changed.

References:
    - Wan, Wong, Leung: Spherical Q2-tree for Sampling Dynamic Environment Sequences, EGSR 2005.
    - Górski et al.: HEALPix (nested scheme, equal-area quads).
    - Agarwal et al. 2003: the importance L^a · Δω^b.
    - Nikodým, Havran, Bittner (paper 002) §3.2, Algorithm 1 and Table 1 ("Q2-Tree").
"""

from __future__ import annotations

import heapq
from typing import NamedTuple

import numpy as np

from rgbd_envmap._kernels import lights_q2tree as kernels
from rgbd_envmap.checks import check_flag, check_number
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.lights.cells import MAX_LEVEL, cell_sums, finest_level, healpix_table
from rgbd_envmap.lights.maps import LUMINANCE_WEIGHTS, MapInputs, luminance

__all__ = ["Pyramid", "Q2TreeState", "build", "importances", "leaves_of", "leaf_count", "pyramid", "place",
           "quad_solid_angle", "splits_for", "tree_lights", "check_q2_options", "q2tree_samples"]


def quad_solid_angle(level: np.ndarray | int) -> np.ndarray:
    """Δω = π / (3 · 4^level) steradians of a HEALPix quad (float64)."""
    return np.pi / (3.0 * 4.0 ** np.asarray(level, np.float64))


def splits_for(n: int) -> int:
    """Splits k a tree needs for at least n leaves: the smallest k ≥ 0 with 12 + 3k ≥ n."""
    return max(0, -(-(n - 12) // 3))


def leaf_count(n: int) -> int:
    """Lights a Q2-Tree gives when n are asked for: 12 + 3 · :func:`splits_for` (n)."""
    return 12 + 3 * splits_for(n)


class Pyramid(NamedTuple):
    """Per-level sums of a map over HEALPix quads: ``levels[l]`` is (12·4^l, C) float64, C = 3 (RGB
    power) or 6 with depth (see :func:`rgbd_envmap.lights.cells.cell_sums`)."""

    levels: list


def pyramid(inputs: MapInputs, level: int) -> Pyramid:
    """Sum a checked map into the quads of levels 0 … ``level``."""
    H, W = inputs.radiance.shape[:2]
    fine = cell_sums(inputs, healpix_table(H, W, level), 12 * 4 ** level, inputs.depth_m is not None)
    levels = [fine]
    for _ in range(level):
        up = np.empty((levels[-1].shape[0] // 4, levels[-1].shape[1]))
        kernels.level_up(levels[-1], up)
        levels.append(up)
    return Pyramid(levels[::-1])


def importances(pyr: Pyramid, a: float, b: float, finest: bool = False) -> list:
    """Per level (12·4^l,) float64 importance Y^a · Δω^b of every quad; without ``finest`` the
    finest level (never split, so never compared) is left out."""
    out = []
    wr, wg, wb = LUMINANCE_WEIGHTS
    for lvl, s in enumerate(pyr.levels if finest else pyr.levels[:-1]):
        imp = np.empty(s.shape[0])
        kernels.importance(s, wr, wg, wb, float(a), float(quad_solid_angle(lvl)) ** b, imp)
        out.append(imp)
    return out


def build(imp: list, k: int) -> list:
    """Interior masks, one (12·4^l,) bool per level < the finest, of the tree Algorithm 1 grows by k
    splits: the k most important quads above the finest level (ties: lower level, then lower index).
    ``imp``: the importances of the levels above the finest (:func:`importances`)."""
    L = len(imp)
    if L == 0:
        return []
    flat = np.concatenate(imp)
    k = min(k, flat.size)
    mask = np.zeros(flat.size, bool)
    if k > 0:
        t = -np.partition(-flat, k - 1)[k - 1]
        mask = flat > t
        ties = np.flatnonzero(flat == t)[: k - int(mask.sum())]
        mask[ties] = True
    out, start = [], 0
    for lvl in range(L):
        m = 12 * 4 ** lvl
        out.append(mask[start:start + m])
        start += m
    return out


def leaves_of(interior: list, L: int) -> np.ndarray:
    """(m, 2) int64 (level, index) of the leaves of the tree with these interior masks and finest
    level L, in the order of their first finest-level descendant (a walk over the sphere)."""
    parts = []
    parent = None
    for lvl in range(L + 1):
        own = interior[lvl] if lvl < L else np.zeros(12 * 4 ** L, bool)
        here = ~own if parent is None else (np.repeat(parent, 4) & ~own)
        idx = np.flatnonzero(here)
        parts.append(np.stack([np.full(idx.size, lvl), idx], axis=1))
        parent = own
    cells = np.concatenate(parts).astype(np.int64)
    start = cells[:, 1] << (2 * (L - cells[:, 0]))
    return cells[np.argsort(start, kind="stable")]


def place(cells: np.ndarray, jitter: bool = True) -> np.ndarray:
    """(m, 3) float64 unit directions of the lights of quads (level, index): the quad's centre, or
    with ``jitter`` the centre of one of its 16 grandchildren chosen by a hash of (level, index)."""
    import healpy

    lvl = cells[:, 0].astype(np.int64)
    p = cells[:, 1].astype(np.int64)
    if jitter:
        h = ((p.astype(np.uint64) * np.uint64(2654435761)) ^ (lvl.astype(np.uint64) * np.uint64(2246822519)))
        sub = ((h >> np.uint64(11)) & np.uint64(15)).astype(np.int64)
        x, y, z = healpy.pix2vec(2 ** (lvl + 2), 16 * p + sub, nest=True)
    else:
        x, y, z = healpy.pix2vec(2 ** lvl, p, nest=True)
    d = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def tree_lights(pyr: Pyramid, cells: np.ndarray, jitter: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """(directions, power, solid angle, mean distance or None) of the leaves ``cells``."""
    sums = np.empty((cells.shape[0], pyr.levels[0].shape[1]))
    for lvl in np.unique(cells[:, 0]):
        sel = cells[:, 0] == lvl
        sums[sel] = pyr.levels[lvl][cells[sel, 1]]
    dist = None
    if sums.shape[1] == 6:
        y = luminance(sums[:, :3])
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = np.where(y > 0, sums[:, 3] / np.where(y > 0, y, 1.0),
                            sums[:, 4] / np.where(sums[:, 5] > 0, sums[:, 5], np.nan))
    return place(cells, jitter), sums[:, :3].copy(), quad_solid_angle(cells[:, 0]), dist


class Q2TreeState:
    """The tree kept between frames for ``sample_lights(..., method="q2tree", state=state)``: each
    frame updates the previous tree by merge-and-split steps instead of rebuilding it.

    Attributes:
        steps: merge-and-split swaps of the last update (0 when the tree did not change), and
            ``rebuilt`` True when the last frame built the tree from scratch (first frame, or another
            map size, finest level, a or b).
    """

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._interior: set = set()
        self.steps = 0
        self.rebuilt = False

    def reset(self) -> None:
        """Forget the tree (the next frame builds one from scratch)."""
        self._key = None
        self._interior = set()

    def interior_masks(self, imp: list, k: int, key: tuple) -> list:
        """Interior masks for this frame's importances: from scratch on a new key, else by
        merge-and-split from the previous tree."""
        L = len(imp)
        if key != self._key:
            masks = build(imp, k)
            self._key = key
            self._interior = {(lvl, int(p)) for lvl, m in enumerate(masks) for p in np.flatnonzero(m)}
            self.steps, self.rebuilt = 0, True
            return masks
        self.rebuilt = False
        self.steps = _merge_and_split(self._interior, imp, min(k, sum(12 * 4 ** lvl for lvl in range(L))), L)
        masks = [np.zeros(12 * 4 ** lvl, bool) for lvl in range(L)]
        for lvl, p in self._interior:
            masks[lvl][p] = True
        return masks


def _merge_and_split(S: set, imp: list, k: int, L: int) -> int:
    """Update the interior set S in place to the k most important quads (ties: lower level, lower
    index), by splitting the best leaf and merging the worst interior node whose children are all
    leaves; returns the number of swaps."""
    def value(node):
        return float(imp[node[0]][node[1]])

    def children(node):
        lvl, p = node
        return [(lvl + 1, 4 * p + c) for c in range(4)]

    def parent(node):
        return None if node[0] == 0 else (node[0] - 1, node[1] // 4)

    def is_leaf_front(node):  # a leaf of the tree that may be split
        if node in S or node[0] >= L:
            return False
        par = parent(node)
        return par is None or par in S

    def is_candidate(node):
        return node in S and all(c not in S for c in children(node))

    leaves: list = []
    cands: list = []

    def push_leaf(node):
        if node[0] < L:
            heapq.heappush(leaves, (-value(node), node[0], node[1]))

    def push_cand(node):
        heapq.heappush(cands, (value(node), -node[0], -node[1]))

    for p in range(12):
        if (0, p) not in S:
            push_leaf((0, p))
    for node in S:
        for c in children(node):
            if c not in S:
                push_leaf(c)
        if is_candidate(node):
            push_cand(node)

    def best_leaf():
        while leaves:
            v, lvl, p = leaves[0]
            if is_leaf_front((lvl, p)) and -v == value((lvl, p)):
                return (lvl, p)
            heapq.heappop(leaves)
        return None

    def worst_cand():
        while cands:
            v, lvl, p = cands[0]
            if is_candidate((-lvl, -p)) and v == value((-lvl, -p)):
                return (-lvl, -p)
            heapq.heappop(cands)
        return None

    def split(node):
        S.add(node)
        push_cand(node)
        for c in children(node):
            push_leaf(c)

    def merge(node):
        S.discard(node)
        push_leaf(node)
        par = parent(node)
        if par is not None and is_candidate(par):
            push_cand(par)

    while len(S) < k and (f := best_leaf()) is not None:
        split(f)
    while len(S) > k:
        merge(worst_cand())
    steps = 0
    while True:
        f, c = best_leaf(), worst_cand()
        if f is None or c is None or not ((-value(f), f[0], f[1]) < (-value(c), c[0], c[1])):
            return steps
        merge(c)
        split(f)
        steps += 1


def check_q2_options(a: object, b: object, jitter: object) -> tuple[float, float, bool]:
    """Check the importance exponents (a, b ≥ 0) and the jitter flag."""
    return (check_number(a, "a", low=0.0, high=16.0), check_number(b, "b", low=0.0, high=16.0),
            check_flag(jitter, "jitter"))


def q2tree_samples(inputs: MapInputs, n: int, state: Q2TreeState | None = None, a: float = 1.0, b: float = 0.25,
                   jitter: bool = True, level: int | None = None):
    """Sample a checked map: (directions, power, solid angle, mean distance or None, cells).
    ``level``: the finest level (default :func:`rgbd_envmap.lights.cells.finest_level`); a tree
    with fewer than n quads at that level gives all of them."""
    a, b, jitter = check_q2_options(a, b, jitter)
    if state is not None and not isinstance(state, Q2TreeState):
        raise InvalidInputError(f"state: expected a Q2TreeState for method 'q2tree', got {type(state).__name__}")
    H, W = inputs.radiance.shape[:2]
    L = finest_level(H, W, n) if level is None else check_number(level, "level", low=0, high=MAX_LEVEL, integer=True)
    pyr = pyramid(inputs, L)
    imp = importances(pyr, a, b)
    k = splits_for(n)
    masks = build(imp, k) if state is None else state.interior_masks(imp, k, (H, W, L, a, b))
    cells = leaves_of(masks, L)
    d, power, omega, dist = tree_lights(pyr, cells, jitter)
    return d, power, omega, dist, cells
