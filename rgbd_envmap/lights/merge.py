"""Merging the lights of several cameras or probes into one set (paper 002 §4).

- **PDF methods** (``"pharr"``, ``"hemigon"``; §4.1): all inputs used the same Halton points, so
  light i of every input comes from the same point and they correspond by index. The merged light
  i has the weighted mean of their powers and the normalised weighted mean of their directions (and
  of their positions, when every input has them).
- **Q2-Tree** (§4.2, Algorithm 2): each input's tree is rebuilt from its leaves (an interior quad's
  power is the sum of its leaves'); the trees are traversed together and every quad of their union
  gets the weighted sum of the inputs that have it; the powers are normalised top-down, the 12 base
  quads to the weighted mean of the inputs (every input has them) and each quad's four children
  scaled, per channel, so that they add up to their parent (split equally when the inputs that
  reach them hold no power there); importances Y^a · Δω^b are evaluated again; and the least
  important interior quad whose children are leaves is cut, again and again, until the tree has the
  leaves asked for (12 + 3k ≥ n, or fewer when the union tree has fewer).

The Q2-Tree merge gives exactly the lights of a Q2-Tree built on the weighted per-pixel average of
the maps whenever every input tree reaches the quads that the average's tree examines (then each
quad's merged power is the weighted mean of its powers, and the cut keeps the same quads); where an
input's tree stops higher, its share of the deeper quads is interpolated by the normalisation, as in
the paper. Σ power of the merged set equals the weighted mean of the inputs' totals either way.

References:
    - Nikodým, Havran, Bittner (paper 002) §4.1, §4.2 and Algorithm 2.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence

import numpy as np

from rgbd_envmap.checks import check_array, check_flag, check_number
from rgbd_envmap.errors import InvalidInputError, RangeError
from rgbd_envmap.lights.maps import LUMINANCE_WEIGHTS
from rgbd_envmap.lights.q2tree import check_q2_options, place, quad_solid_angle, splits_for
from rgbd_envmap.lights.result import LightSet

__all__ = ["merge_lights"]


def _weights(weights: object, k: int) -> np.ndarray:
    if weights is None:
        return np.full(k, 1.0 / k)
    w = check_array(weights, "weights", shape=(k,), dtype=("float", "int"), finite=True).astype(np.float64)
    if w.min() < 0 or w.sum() <= 0:
        raise RangeError(f"weights: expected values ≥ 0 with a positive sum, got {w.tolist()}")
    return w / w.sum()


def merge_lights(sets: Sequence[LightSet], n: int | None = None, weights: object = None, *, a: float = 1.0,
                 b: float = 0.25, jitter: bool = True) -> LightSet:
    """Merge light sets of one method from several cameras (paper 002 §4).

    Args:
        sets: one or more :class:`LightSet` of the same method: ``"pharr"`` / ``"hemigon"`` sets of
            equal length, or ``"q2tree"`` sets (with ``cells``).
        n: Q2-Tree only: lights asked for (default: the most any input has).
        weights: (k,) non-negative weight per input (default equal); normalised to sum 1.
        a, b, jitter: Q2-Tree only: the importance exponents and light placement the inputs used.

    Returns:
        A :class:`LightSet` of the same method.
    """
    sets = list(sets) if not isinstance(sets, LightSet) else [sets]
    if not sets or not all(isinstance(s, LightSet) for s in sets):
        raise InvalidInputError(f"sets: expected one or more LightSet, got {[type(s).__name__ for s in sets]}")
    methods = sorted({s.method for s in sets})
    if len(methods) != 1:
        raise InvalidInputError(f"sets: expected sets of one method, got {methods}")
    w = _weights(weights, len(sets))
    if methods[0] == "q2tree":
        if any(s.cells is None for s in sets):
            raise InvalidInputError("sets: expected Q2-Tree sets with cells")
        n = max(len(s) for s in sets) if n is None else check_number(n, "n", low=1, high=10**6, integer=True)
        return _merge_q2(sets, n, w, *check_q2_options(a, b, jitter))
    if methods[0] not in ("pharr", "hemigon"):
        raise InvalidInputError(f"sets: method {methods[0]!r} has no merge; valid: ['pharr', 'hemigon', 'q2tree']")
    if n is not None:
        raise InvalidInputError(f"n: the {methods[0]} merge keeps the inputs' length; got n={n!r}")
    check_flag(jitter, "jitter")
    lens = sorted({len(s) for s in sets})
    if len(lens) != 1:
        raise InvalidInputError(f"sets: expected sets of equal length (lights correspond by index), got {lens}")
    d = np.einsum("k,knc->nc", w, np.stack([s.directions for s in sets]))
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where(norm > 1e-12, d / np.where(norm > 1e-12, norm, 1.0), sets[0].directions)
    power = np.einsum("k,knc->nc", w, np.stack([s.power for s in sets]))
    positions = origin = None
    if all(s.positions is not None for s in sets):
        positions = np.einsum("k,knc->nc", w, np.stack([s.positions for s in sets]))
        origin = np.einsum("k,kc->c", w, np.stack([s.origin for s in sets]))
    return LightSet(d, power, methods[0], positions=positions, origin=origin)


def _merge_q2(sets: list, n: int, w: np.ndarray, a: float, b: float, jitter: bool) -> LightSet:
    # Step 1: rebuild each tree (node -> RGB power) from its leaves, and its interior nodes.
    union: dict = {}  # node -> weighted sum of the inputs having it
    interior: set = set()
    for s, wk in zip(sets, w):
        vals: dict = {}
        for (lvl, p), pw in zip(s.cells.tolist(), s.power):
            node = (lvl, p)
            while True:
                vals[node] = vals[node] + pw if node in vals else pw.copy()
                if node[0] == 0:
                    break
                node = (node[0] - 1, node[1] // 4)
                interior.add(node)
        if len(vals) and sorted(p for (lvl, p) in vals if lvl == 0) != list(range(12)):
            raise InvalidInputError("sets: a Q2-Tree set must cover the 12 base quads")
        for node, v in vals.items():
            union[node] = union[node] + wk * v if node in union else wk * v
    # Step 3: normalise top-down (base quads: the weighted mean; children: scaled to their parent).
    value: dict = {(0, p): union[(0, p)] for p in range(12)}
    for lvl in range(0, 64):
        parents = [node for node in interior if node[0] == lvl]
        if not parents:
            break
        for node in parents:
            kids = [(lvl + 1, 4 * node[1] + c) for c in range(4)]
            raw = np.stack([union[c] for c in kids])
            tot = raw.sum(axis=0)
            par = value[node]
            with np.errstate(divide="ignore", invalid="ignore"):
                scaled = np.where(tot > 0, raw * (par / np.where(tot > 0, tot, 1.0)), par / 4.0)
            for c, v in zip(kids, scaled):
                value[c] = v
    # Step 4: importances; Step 5: cut the least important interior quads whose children are leaves.
    wl = np.asarray(LUMINANCE_WEIGHTS)

    def imp(node):
        y = float(wl @ value[node])
        return (y if a == 1.0 else y ** a) * float(quad_solid_angle(node[0])) ** b

    k = splits_for(n)
    S = set(interior)

    def is_candidate(node):
        return node in S and all((node[0] + 1, 4 * node[1] + c) not in S for c in range(4))

    heap = [(imp(x), -x[0], -x[1]) for x in S if is_candidate(x)]
    heapq.heapify(heap)
    while len(S) > k:
        _, ml, mp = heapq.heappop(heap)
        node = (-ml, -mp)
        if not is_candidate(node):
            continue
        S.discard(node)
        if node[0] > 0:
            par = (node[0] - 1, node[1] // 4)
            if is_candidate(par):
                heapq.heappush(heap, (imp(par), -par[0], -par[1]))
    # Step 6: the leaves of the reduced tree, placed as the Q2-Tree places them.
    leaves = [x for x in value if x not in S and (x[0] == 0 or (x[0] - 1, x[1] // 4) in S)]
    L = max(x[0] for x in leaves)
    leaves.sort(key=lambda x: x[1] << (2 * (L - x[0])))
    cells = np.array(leaves, dtype=np.int64).reshape(-1, 2)
    power = np.stack([value[x] for x in leaves])
    return LightSet(place(cells, jitter), np.maximum(power, 0.0), "q2tree", solid_angle=quad_solid_angle(cells[:, 0]),
                    cells=cells)
