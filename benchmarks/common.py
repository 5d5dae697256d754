"""Timing helpers shared by the benchmark scripts."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np


def time_it(fn: Callable[[], object], repeats: int, warmup: int = 1) -> dict:
    """Run ``fn`` ``warmup`` times untimed, then ``repeats`` times; return median / p95 / min in ms."""
    for _ in range(warmup):
        fn()
    ms = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ms.append((time.perf_counter() - t0) * 1e3)
    a = np.asarray(ms)
    return {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)), "min_ms": float(a.min()), "n": len(a)}


def print_table(rows: dict[str, dict]) -> None:
    width = max(len(k) for k in rows)
    print(f"{'case':<{width}}  {'median ms':>10}  {'p95 ms':>10}  {'n':>4}")
    for name, r in rows.items():
        print(f"{name:<{width}}  {r['median_ms']:>10.2f}  {r['p95_ms']:>10.2f}  {r['n']:>4}")
