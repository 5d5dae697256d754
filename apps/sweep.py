"""``rgbd-envmap sweep``: speed against error over a grid of pipeline settings, on one recorded log.

Each point of the grid replays the log (no rendering, no video) with one setting changed from the
defaults — one axis at a time, so every row differs from the default row in exactly one way:

- ``em_size``: 500×250, 1000×500, 1500×750, 2000×1000;
- ``bands``: 1 … 8 SH bands;
- ``hole_filling``: monroy2018 (eq. 1), telea, ip_basic, none;
- ``ccm``: least_squares (the paper's), ridge, Cheung 2004, Finlayson 2015, and correction off;
- ``translation``: the final map moved 10 cm along +x by the depth-aware warp and by Gardner's
  sphere operator, against the map fed the same data at the displaced origin (paper Fig. 9 protocol).

Points run in parallel over the cores (one process each, spawned), each on one thread (numba's
thread count set to 1, so the map update and the colour pairs take their one-thread kernels, with
the same results; points timed on two threads each would compete for the cores). Writes
``points/<name>/`` (a run folder per point), ``sweep.csv``, ``sweep.md`` (time and error side by
side) and ``pareto.png``.
"""

from __future__ import annotations

import csv
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from rgbd_envmap.errors import InvalidInputError

__all__ = ["SweepPoint", "grid", "run_sweep", "AXES"]

AXES = ("em_size", "bands", "hole_filling", "ccm", "translation")
TRANSLATION_OFFSET_M = (0.10, 0.0, 0.0)


@dataclass(frozen=True)
class SweepPoint:
    axis: str
    name: str
    overrides: tuple[str, ...]
    origin_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


def grid(axes: list[str] | None = None) -> list[SweepPoint]:
    """The points of the requested axes (all by default), the default setting first."""
    axes = list(axes or AXES)
    unknown = [a for a in axes if a not in AXES]
    if unknown:
        raise InvalidInputError(f"axes: unknown {unknown}; valid: {list(AXES)}")
    pts = [SweepPoint("default", "default", ())]
    if "em_size" in axes:
        pts += [SweepPoint("em_size", f"em {2 * h}x{h}", (f"capture.width={2 * h}", f"capture.height={h}")) for h in (250, 500, 750)]
    if "bands" in axes:
        pts += [SweepPoint("bands", f"bands {b}", (f"shading.bands={b}",)) for b in range(1, 9) if b != 5]
    if "hole_filling" in axes:
        pts += [SweepPoint("hole_filling", f"fill {m}", (f"ingest.fill_method={m}",)) for m in ("telea", "ip_basic")]
        pts.append(SweepPoint("hole_filling", "fill none", ("ingest.fill_method=none",)))
    if "ccm" in axes:
        pts += [SweepPoint("ccm", f"ccm {m}", (f"capture.ccm_method={m}",)) for m in ("least_squares", "Cheung 2004", "Finlayson 2015")]
        pts.append(SweepPoint("ccm", "ccm off", ("capture.colour_correction=false",)))
    if "translation" in axes:
        pts.append(SweepPoint("translation", "displaced origin (truth)", (), TRANSLATION_OFFSET_M))
    return pts


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def _run_point(log: str, out: str, point: SweepPoint, origin: list[float]) -> dict:
    """One replay (in a worker process); returns the point's timing and accuracy."""
    from apps.replay import ReplayOptions, run_replay
    from apps.report import timing_table
    from rgbd_envmap.config import apply_overrides
    from rgbd_envmap.pipeline import DEPTH_TOTAL, PipelineConfig
    from rgbd_envmap.timing import read_records

    cfg = apply_overrides(PipelineConfig(), ["render.enabled=false", *point.overrides])
    o = np.asarray(origin) + np.asarray(point.origin_offset)
    t0 = time.perf_counter()
    run_replay(ReplayOptions(Path(log), Path(out), origin=tuple(o), config=cfg, video=False, progress=False,
                             composite_every=10**9))
    table = timing_table(read_records(Path(out) / "stage_times.csv"))
    acc = json.loads((Path(out) / "accuracy.json").read_text())
    return {"axis": point.axis, "name": point.name, "out": out, "wall_s": time.perf_counter() - t0,
            "depth_total_median_ms": table[DEPTH_TOTAL]["median_ms"], "depth_total_p95_ms": table[DEPTH_TOTAL]["p95_ms"],
            "stages": {k: v["median_ms"] for k, v in table.items()}, "accuracy": acc}


def _translation_rows(default: dict, truth: dict) -> list[dict]:
    from rgbd_envmap import metrics
    from rgbd_envmap.envmap import EnvironmentMap, translate

    def load(run: dict) -> EnvironmentMap:
        with np.load(Path(run["out"]) / "envmap.npz") as z:
            return EnvironmentMap.from_arrays(z["radiance"], z["depth_m"], z["valid"], z["origin"])

    src, ref = load(default), load(truth)
    rows = []
    for method in ("depth", "gardner"):
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            moved = translate(src, np.asarray(TRANSLATION_OFFSET_M), method, threads=1)  # the sweep times one thread
            times.append((time.perf_counter() - t0) * 1e3)
        both = moved.valid & ref.valid
        rows.append({
            "axis": "translation", "name": f"translate 10 cm: {method}",
            "depth_total_median_ms": float("nan"), "depth_total_p95_ms": float("nan"),
            "stages": {"EM translation": float(np.median(times))},
            "accuracy": {"translation_sphere_correlation": metrics.sphere_correlation(moved.radiance, ref.radiance, both),
                         "translation_coverage": metrics.coverage_of(moved.valid, ref.valid)},
        })
    return rows


#: the error shown for each axis (first found in the point's accuracy) and the stage whose time it trades.
AXIS_METRIC = {
    "default": ("em_ws_psnr_db", None), "em_size": ("em_ws_psnr_db", "Project sample to EM*"),
    "bands": ("irradiance_rel_error_vs_true", "Calculate SH coefficients*"),
    "hole_filling": ("em_coverage", "Hole filling RGB-D"),
    "ccm": ("em_ws_psnr_db", "Compute colour correction matrix"),
    "translation": ("translation_sphere_correlation", "EM translation"),
}
COLUMNS = ("em_coverage", "em_ws_psnr_db", "hole_filling_depth_mae_m", "ccm_matrix_rel_error_median",
           "sh_coeff_rel_error", "irradiance_rel_error_mean", "irradiance_rel_error_vs_true", "translation_sphere_correlation", "translation_coverage")


def _fmt(v) -> str:
    return "—" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.4g}"


def _write_outputs(out: Path, rows: list[dict]) -> Path:
    with open(out / "sweep.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["axis", "setting", "depth_frame_total_median_ms", "depth_frame_total_p95_ms", "axis_stage", "axis_stage_median_ms", *COLUMNS])
        for r in rows:
            stage = AXIS_METRIC[r["axis"]][1]
            w.writerow([r["axis"], r["name"], r["depth_total_median_ms"], r["depth_total_p95_ms"], stage or "",
                        r["stages"].get(stage, float("nan")) if stage else "", *(r["accuracy"].get(c, "") for c in COLUMNS)])
    lines = ["# Speed against error", "",
             "One axis changed at a time from the defaults (row `default`); times are medians on this machine, "
             "errors are against the simulator's ground truth (accuracy.json of each point under points/).", "",
             "| axis | setting | depth frame ms (median / p95) | stage ms (median) | " + " | ".join(COLUMNS) + " |",
             "|---|---|---:|---:|" + "---:|" * len(COLUMNS)]
    for r in rows:
        stage = AXIS_METRIC[r["axis"]][1]
        st = f"{stage}: {_fmt(r['stages'].get(stage))}" if stage else ""
        lines.append(f"| {r['axis']} | {r['name']} | {_fmt(r['depth_total_median_ms'])} / {_fmt(r['depth_total_p95_ms'])} | {st} | "
                     + " | ".join(_fmt(r["accuracy"].get(c)) for c in COLUMNS) + " |")
    lines += ["", "![Pareto plot](pareto.png)", ""]
    (out / "sweep.md").write_text("\n".join(lines))
    _pareto(out / "pareto.png", rows)
    return out / "sweep.md"


def _pareto(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes_present = [a for a in AXES if any(r["axis"] == a for r in rows)]
    fig, axs = plt.subplots(1, max(len(axes_present), 1), figsize=(4.2 * max(len(axes_present), 1), 3.8))
    axs = np.atleast_1d(axs)
    default = next((r for r in rows if r["axis"] == "default"), None)
    for ax, axis in zip(axs, axes_present):
        metric, stage = AXIS_METRIC[axis]
        pts = [r for r in rows if r["axis"] == axis and r["name"] != "displaced origin (truth)"]
        if axis != "translation" and default is not None:
            pts = [default, *pts]
        xs = [r["stages"].get(stage, np.nan) for r in pts]
        ys = [r["accuracy"].get(metric, np.nan) for r in pts]
        ax.plot(xs, ys, "o")
        for x, y, r in zip(xs, ys, pts):
            ax.annotate(r["name"].replace("translate 10 cm: ", ""), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel(f"{stage} median ms")
        ax.set_ylabel(metric)
        ax.set_title(axis)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _one_thread() -> None:
    """A sweep worker's initialiser: numba's parallel kernels on one thread."""
    import numba

    numba.set_num_threads(1)


def run_sweep(log: str | Path, out: str | Path, *, jobs: int | None = None, axes: list[str] | None = None,
              progress: bool = True) -> Path:
    """Run the grid on ``log``; returns the path of sweep.md."""
    from tqdm import tqdm

    from apps.progress import bar_disable

    from apps.replay import default_origin
    from rgbd_envmap.logs import SessionLog

    log, out = Path(log), Path(out)
    origin = default_origin(SessionLog.open(log)).tolist()
    points = grid(axes)
    (out / "points").mkdir(parents=True, exist_ok=True)
    jobs = jobs or os.cpu_count() or 1
    results: dict[str, dict] = {}
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn"), initializer=_one_thread) as pool:
        futures = {pool.submit(_run_point, str(log), str(out / "points" / _slug(p.name)), p, origin): p for p in points}
        for fut in tqdm(as_completed(futures), total=len(futures), desc="sweep", unit="point", disable=bar_disable(progress)):
            results[futures[fut].name] = fut.result()
    rows = [results[p.name] for p in points]
    if "default" in results and "displaced origin (truth)" in results:
        rows = [r for r in rows if r["name"] != "displaced origin (truth)"] + _translation_rows(results["default"], results["displaced origin (truth)"])
    return _write_outputs(out, rows)
