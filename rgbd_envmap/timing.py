"""Per-stage wall-clock timing of the pipeline (the model is paper 003's Table 1).

A :class:`StageTimer` records one row per stage execution: which packet (a running frame number and
its kind), the stage name, and the elapsed milliseconds (``time.perf_counter``). Summaries give the
count, median and 95th percentile per stage; derived totals (all stages of one frame) are summed per
frame first, then summarised, so a total's median is the median frame's total, not a sum of medians.

References:
    Monroy, Hudon, Smolic (2018), §8, Table 1.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd_envmap.errors import LogFormatError

__all__ = ["StageRecord", "StageTimer", "stage_stats", "summarise", "frame_totals", "read_records", "write_records"]


@dataclass(frozen=True)
class StageRecord:
    """One stage execution: ``frame`` (running packet number), ``kind`` ("depth" / "colour"),
    ``stage`` name, ``ms`` elapsed milliseconds."""

    frame: int
    kind: str
    stage: str
    ms: float


class StageTimer:
    """Collects :class:`StageRecord` rows; ``with timer.stage("name"): ...`` times one execution."""

    def __init__(self) -> None:
        self.records: list[StageRecord] = []
        self._frame = -1
        self._next = 0
        self._kind = ""

    def begin(self, kind: str) -> int:
        """Start a new frame of ``kind``; returns its running number."""
        self._frame = self._next
        self._next += 1
        self._kind = kind
        return self._frame

    def resume(self, frame: int, kind: str) -> None:
        """Attribute the next records to an earlier frame again (after interleaving another frame)."""
        self._frame = frame
        self._kind = kind

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.records.append(StageRecord(self._frame, self._kind, name, (time.perf_counter() - t0) * 1e3))

    def add(self, name: str, ms: float) -> None:
        """Record a stage timed elsewhere."""
        self.records.append(StageRecord(self._frame, self._kind, name, float(ms)))


def stage_stats(ms: Iterable[float]) -> dict:
    a = np.asarray(list(ms), dtype=np.float64)
    if a.size == 0:
        return {"count": 0, "median_ms": float("nan"), "p95_ms": float("nan")}
    return {"count": int(a.size), "median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95))}


def frame_totals(records: Iterable[StageRecord], kind: str, exclude: Iterable[str] = ()) -> list[float]:
    """Per frame of ``kind``, the sum of its stages' milliseconds (stages in ``exclude`` left out)."""
    excluded = set(exclude)
    totals: dict[int, float] = {}
    for r in records:
        if r.kind == kind and r.stage not in excluded:
            totals[r.frame] = totals.get(r.frame, 0.0) + r.ms
    return list(totals.values())


def summarise(records: Iterable[StageRecord]) -> dict[str, dict]:
    """``{stage: {"count", "median_ms", "p95_ms"}}`` in first-seen order."""
    by_stage: dict[str, list[float]] = {}
    for r in records:
        by_stage.setdefault(r.stage, []).append(r.ms)
    return {name: stage_stats(ms) for name, ms in by_stage.items()}


_FIELDS = ("frame", "kind", "stage", "ms")


def write_records(path: str | Path, records: Iterable[StageRecord]) -> None:
    """Write the raw rows as CSV (``frame,kind,stage,ms``)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(_FIELDS)
        for r in records:
            w.writerow((r.frame, r.kind, r.stage, f"{r.ms:.6f}"))


def read_records(path: str | Path) -> list[StageRecord]:
    """Read rows written by :func:`write_records`; errors name the file and line."""
    path = Path(path)
    if not path.is_file():
        raise LogFormatError(f"{path}: no such file (the raw stage timings of a run)")
    out = []
    with open(path, newline="") as f:
        rows = csv.reader(f)
        header = next(rows, None)
        if header is None or tuple(header) != _FIELDS:
            raise LogFormatError(f"{path}:1: expected the header {','.join(_FIELDS)}, got {header}")
        for line, row in enumerate(rows, start=2):
            try:
                frame, kind, stage, ms = row
                rec = StageRecord(int(frame), kind, stage, float(ms))
            except ValueError:
                raise LogFormatError(f"{path}:{line}: expected frame,kind,stage,ms, got {row}") from None
            if not np.isfinite(rec.ms) or rec.ms < 0:
                raise LogFormatError(f"{path}:{line}: stage time must be finite and ≥ 0, got {rec.ms}")
            out.append(rec)
    return out

