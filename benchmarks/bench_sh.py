"""Time the SH stage (paper 003 §7.1; docs/design/overview.md, stage 8) on 2000×1000 maps, beside a baseline.

    python benchmarks/bench_sh.py [--repeats N] [--json PATH] [--figure PATH]

Every case is timed round-robin (one call of each case per round, ``--repeats`` rounds after two
warm-up calls), so load from other processes on this shared machine hits all cases alike; the table
gives the median, p95 and minimum per call. BLAS and numba are held to one thread (the environment
variables are set before numpy is imported).

Cases:

- ``project_equirect`` of a float32 (H, W, 3) C-contiguous map and of the (H, W, 3) view of planar
  (3, H, W) storage (``EnvironmentMap.radiance``), and ``project_planar``; beside each a baseline
  ("old": a BLAS formulation over a filled copy of the map, kept below).
- With missing pixels (the stage-8 fill): 3 % missing in blobs and thin cracks (``realistic_mask``),
  the same plus a missing polar cap (the top 15 % of rows, ceiling never seen), and 5 % i.i.d.
- The fill alone (``fill_missing``; the new one builds a filled copy only for this function, the
  projection fills row by row) and the new fill plan alone.
- The separable projection with BLAS on planar storage, (3H, W) @ (W, 2n − 1) float32 (no fill).
- The projection at 1 … 8 bands; ``basis`` and ``irradiance`` of 35k normals; ``select_bands`` for
  35k vertices × 8 bands from the raw float32 transfer and from a precomputed ``TransferGram``.

Target: median ≤ 3 ms for the all-valid projection at 5 bands.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import cv2
import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rgbd_envmap import sh
from rgbd_envmap.envmap import EnvironmentMap
from rgbd_envmap.geometry import equirect_solid_angles

H, W = 1000, 2000
N_NORMALS = 35_000


# --- the previous implementation (commit 3cae7f7), for side-by-side timing only ----------------------

@numba.njit(cache=True)
def _old_fill_kernel(radiance, valid, radius):  # pragma: no cover - compiled
    Hh, Ww, C = radiance.shape
    out = np.empty((Hh, Ww, C), dtype=np.float32)
    used = np.ones((Hh, Ww), dtype=np.bool_)
    for v in range(Hh):
        for u in range(Ww):
            if valid[v, u]:
                for c in range(C):
                    out[v, u, c] = radiance[v, u, c]
                continue
            sv = -1
            su = -1
            for dist in range(1, radius + 1):
                if v - dist >= 0 and valid[v - dist, u]:
                    sv, su = v - dist, u
                elif v + dist < Hh and valid[v + dist, u]:
                    sv, su = v + dist, u
                elif valid[v, (u - dist) % Ww]:
                    sv, su = v, (u - dist) % Ww
                elif valid[v, (u + dist) % Ww]:
                    sv, su = v, (u + dist) % Ww
                if sv >= 0:
                    break
            if sv >= 0:
                for c in range(C):
                    out[v, u, c] = radiance[sv, su, c]
            else:
                used[v, u] = False
                for c in range(C):
                    out[v, u, c] = 0.0
    return out, used


@lru_cache(maxsize=8)
def _old_tables(height: int, width: int, bands: int):
    n = bands
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    m = np.arange(-(n - 1), n)
    trig = np.where(m[:, None] < 0, np.sin(np.abs(m)[:, None] * phi), np.cos(m[:, None] * phi))
    K = np.kron(trig.T, np.eye(3)).astype(np.float32)
    leg = sh.legendre(np.cos(theta), n)
    m_of_k = np.concatenate([np.arange(-l, l + 1) for l in range(n)])
    leg *= np.sin(theta)[:, None] ** np.abs(m_of_k)[None, :]
    row_w = leg * equirect_solid_angles(height, width)[:, :1]
    return K, row_w, m_of_k + (n - 1)


def old_project_equirect(rad: np.ndarray, valid: np.ndarray | None = None, bands: int = 5) -> np.ndarray:
    Hh, Ww = rad.shape[:2]
    if valid is not None and valid.all():
        valid = None
    if valid is None:
        work = np.ascontiguousarray(rad, dtype=np.float32)
    else:
        work, _ = _old_fill_kernel(rad, np.ascontiguousarray(valid), sh.FILL_RADIUS_PX)
    K, row_w, col_index = _old_tables(Hh, Ww, bands)
    rows = (work.reshape(Hh, 3 * Ww) @ K).reshape(Hh, 2 * bands - 1, 3).astype(np.float64)
    return np.einsum("vk,vkc->kc", row_w, rows[:, col_index, :])


@lru_cache(maxsize=8)
def _blas_tables(height: int, width: int, bands: int):
    n = bands
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    m = np.arange(-(n - 1), n)
    trig = np.where(m[:, None] < 0, np.sin(np.abs(m)[:, None] * phi), np.cos(m[:, None] * phi))
    _, row_w, col_index = _old_tables(height, width, bands)
    return np.ascontiguousarray(trig.T, dtype=np.float32), row_w, col_index


def blas_planar_project(planes: np.ndarray, bands: int = 5) -> np.ndarray:
    """The separable formulation on planar storage with BLAS: (3H, W) @ (W, 2n − 1) float32, then the
    Legendre row weights (no fill). The alternative the issue measured at about 3 ms."""
    C, Hh, Ww = planes.shape
    T, row_w, col_index = _blas_tables(Hh, Ww, bands)
    rows = (planes.reshape(C * Hh, Ww) @ T).reshape(C, Hh, 2 * bands - 1)
    return np.einsum("vk,cvk->kc", row_w, rows[:, :, col_index])


# --- inputs --------------------------------------------------------------------------------------------

def realistic_mask(height: int = H, width: int = W, missing: float = 0.03, seed: int = 0,
                   cap_fraction: float = 0.0) -> np.ndarray:
    """(H, W) bool valid mask: 40 thin cracks (polylines of 3–7 segments of ~60 px, 1–2 px wide), then
    discs of radius 2–25 px until ``missing`` of the pixels are gone; optionally the top
    ``cap_fraction`` of the rows missing too (a ceiling the device never saw)."""
    rng = np.random.default_rng(seed)
    miss = np.zeros((height, width), np.uint8)
    for _ in range(40):
        pts = np.cumsum(rng.normal(0, 60, (int(rng.integers(3, 8)), 2)), 0) + rng.uniform([0, 0], [width, height])
        cv2.polylines(miss, [pts.astype(np.int32).reshape(-1, 1, 2)], False, 1, int(rng.integers(1, 3)))
    while miss.mean() < missing:
        c = rng.uniform([0, 0], [width, height]).astype(int)
        cv2.circle(miss, (int(c[0]), int(c[1])), int(rng.integers(2, 26)), 1, -1)
    miss[: round(cap_fraction * height)] = 1
    return miss == 0


def round_robin(cases: dict[str, Callable[[], object]], repeats: int, warmup: int = 2) -> dict[str, dict]:
    """Median / p95 / min ms per call, one call of each case per round."""
    for fn in cases.values():
        for _ in range(warmup):
            fn()
    ms: dict[str, list[float]] = {k: [] for k in cases}
    for _ in range(repeats):
        for k, fn in cases.items():
            t0 = time.perf_counter()
            fn()
            ms[k].append((time.perf_counter() - t0) * 1e3)
    out = {}
    for k, a in ms.items():
        a = np.asarray(a)
        out[k] = {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)),
                  "min_ms": float(a.min()), "n": len(a)}
    return out


def _print(rows: dict[str, dict]) -> None:
    """``print_table`` plus the minimum (the least disturbed call on a shared machine)."""
    width = max(len(k) for k in rows)
    print(f"{'case':<{width}}  {'median ms':>10}  {'p95 ms':>10}  {'min ms':>10}  {'n':>4}")
    for name, r in rows.items():
        print(f"{name:<{width}}  {r['median_ms']:>10.2f}  {r['p95_ms']:>10.2f}  {r['min_ms']:>10.2f}  {r['n']:>4}")


def _figure(rows: dict[str, dict], band_rows: dict[int, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = [("all valid\n(H, W, 3)", "old: all valid (H,W,3)", "new: all valid (H,W,3)"),
             ("all valid\nEM planar view", "old: all valid, EM view", "new: all valid, EM view"),
             ("3 % missing\nblobs + cracks", "old: 3% blobs+cracks, EM view", "new: 3% blobs+cracks, EM view"),
             ("+ polar cap\n(15 % rows)", "old: 3% + polar cap, EM view", "new: 3% + polar cap, EM view"),
             ("5 % missing\ni.i.d.", "old: 5% iid, EM view", "new: 5% iid, EM view")]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [2.2, 1]})
    x = np.arange(len(pairs))
    for off, idx, label, colour in ((-0.2, 1, "previous (BLAS kron + full fill)", "#bbbbbb"),
                                    (0.2, 2, "new (folded numba + row fill)", "#3070b0")):
        med = [rows[p[idx]]["median_ms"] for p in pairs]
        p95 = [rows[p[idx]]["p95_ms"] for p in pairs]
        ax.bar(x + off, med, 0.38, color=colour, label=label)
        ax.errorbar(x + off, med, yerr=[np.zeros(len(med)), np.subtract(p95, med)], fmt="none", ecolor="k", lw=0.8)
    ax.axhline(3.0, color="r", lw=0.8, ls="--", label="target 3 ms (all valid)")
    ax.set_yscale("log")
    ax.set_ylim(1, None)
    ax.set_xticks(x, [p[0] for p in pairs], fontsize=8)
    ax.set_ylabel("ms per call (median, line to p95)")
    ax.set_title("project_equirect, 2000×1000, 5 bands, one thread", fontsize=9)
    ax.legend(fontsize=7)
    b = sorted(band_rows)
    bx.plot(b, [band_rows[k]["median_ms"] for k in b], "o-", color="#3070b0", label="median")
    bx.plot(b, [band_rows[k]["min_ms"] for k in b], "s--", color="#80a0d0", label="min")
    bx.legend(fontsize=7)
    bx.set_xlabel("bands n (n² coefficients)")
    bx.set_ylabel("ms")
    bx.set_ylim(bottom=0)
    bx.set_title("new projection vs bands (all valid, planar)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=40)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--figure", type=Path, default=None, help="write the old-vs-new bar chart here")
    args = parser.parse_args()
    r = args.repeats

    rng = np.random.default_rng(0)
    radiance = rng.uniform(0, 2, (H, W, 3)).astype(np.float32)
    em = EnvironmentMap(H, W)
    em.radiance_planes[:] = np.moveaxis(radiance, -1, 0)
    em_view = em.radiance  # (H, W, 3) view of the planar storage, as the pipeline passes it
    masks = {
        "3% blobs+cracks": realistic_mask(),
        "3% + polar cap": realistic_mask(cap_fraction=0.15),
        "5% iid": rng.uniform(size=(H, W)) >= 0.05,
    }
    for name, m in masks.items():
        print(f"mask {name}: {100 * (1 - m.mean()):.1f} % missing, rows with gaps {int((~m).any(1).sum())}")

    # correctness guard: the new and old projections agree before anything is timed
    for m in (None, *masks.values()):
        a, b = old_project_equirect(radiance, m), sh.project_equirect(em_view, m)
        assert np.abs(a - b).max() <= 1e-5 * np.abs(a).max(), "old and new projections disagree"
    a = blas_planar_project(em.radiance_planes)
    assert np.abs(a - sh.project_equirect(radiance)).max() <= 1e-5 * np.abs(a).max()

    cases = {
        "old: all valid (H,W,3)": lambda: old_project_equirect(radiance),
        "new: all valid (H,W,3)": lambda: sh.project_equirect(radiance),
        "old: all valid, EM view": lambda: old_project_equirect(em_view),
        "new: all valid, EM view": lambda: sh.project_equirect(em_view),
        "new: project_planar all valid": lambda: sh.project_planar(em.radiance_planes),
        "alt: BLAS sgemm (3H,W)@(W,9), planar": lambda: blas_planar_project(em.radiance_planes),
    }
    for name, m in masks.items():
        cases[f"old: {name}, EM view"] = lambda m=m: old_project_equirect(em_view, m)
        cases[f"new: {name}, EM view"] = lambda m=m: sh.project_equirect(em_view, m)
        cases[f"new: {name}, (H,W,3)"] = lambda m=m: sh.project_equirect(radiance, m)
    real = masks["3% blobs+cracks"]
    cases["old: fill_missing 3%"] = lambda: _old_fill_kernel(radiance, real, sh.FILL_RADIUS_PX)
    cases["new: fill_missing 3%"] = lambda: sh.fill_missing(radiance, real)
    for name, m in masks.items():
        cases[f"new: fill plan only, {name}"] = lambda m=m: sh.fill_plan(m, sh.FILL_RADIUS_PX)
    rows = round_robin(cases, r)
    print(f"\n2000×1000, 5 bands, one thread; {r} round-robin rounds after 2 warm-up calls")
    _print(rows)

    band_rows = round_robin({n: (lambda n=n: sh.project_planar(em.radiance_planes, bands=n)) for n in range(1, 9)}, r)
    print("\nnew project_planar, all valid, by bands")
    _print({f"bands {n} ({n * n} coeffs)": v for n, v in band_rows.items()})

    normals = rng.normal(size=(N_NORMALS, 3))
    coeffs = sh.project_equirect(radiance)
    coeffs8 = sh.project_equirect(radiance, bands=8)
    a = sh.lambertian_band_factors(8)[np.repeat(np.arange(8), 2 * np.arange(8) + 1)]
    transfer = (sh.basis(normals, 8) * a).astype(np.float32)  # unshadowed PRT transfer, (35k, 64)
    gram = sh.transfer_gram(transfer)
    other = round_robin({
        "basis 35k normals, 5 bands": lambda: sh.basis(normals, 5),
        "irradiance 35k normals, 5 bands": lambda: sh.irradiance(coeffs, normals),
        "select_bands 35k x 8 bands, raw float32 transfer": lambda: sh.select_bands(coeffs8, transfer),
        "select_bands 35k x 8 bands, TransferGram": lambda: sh.select_bands(coeffs8, gram),
        "transfer_gram 35k x 64 (once per object)": lambda: sh.transfer_gram(transfer),
    }, r)
    print()
    _print(other)
    if args.json:
        args.json.write_text(json.dumps({"projection": rows, "bands": {str(k): v for k, v in band_rows.items()},
                                         "other": other}, indent=2))
    if args.figure:
        _figure(rows, band_rows, args.figure)
    assert math.isfinite(rows["new: all valid (H,W,3)"]["median_ms"])


if __name__ == "__main__":
    main()
