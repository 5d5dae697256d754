"""Reports of a run folder, regenerated from its raw files (``rgbd-envmap report RUN``).

Reads ``stage_times.csv`` (and ``accuracy.json`` / ``run.json`` / ``config.yaml`` when present) and
writes ``timing.csv`` (``stage,count,median_ms,p95_ms``, plus the rows ``depth_frame_total`` and
``colour_frame_total``), ``timing.md`` (our figures beside the paper's Table 1, what dominates, and
every stage's error) and ``timing.png`` (per-stage times over the session).
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np

from rgbd_envmap.errors import LogFormatError
from rgbd_envmap.pipeline import COLOUR_TOTAL, DEPTH_TOTAL, PAPER_TABLE1_MS, RENDER_STAGES, STAGES
from rgbd_envmap.timing import StageRecord, stage_stats, frame_totals, read_records, summarise

__all__ = ["write_reports", "timing_table"]

#: which accuracy metric belongs to which stage (for the error column of timing.md).
STAGE_ERRORS = {
    "Point cloud to RGB-D": ["ingest_depth_mae_m", "ingest_depth_rmse_m"],
    "Hole filling RGB-D": ["hole_filling_depth_mae_m", "hole_filling_depth_rmse_m", "hole_filling_depth_median_abs_m"],
    "Compute colour correction matrix": ["ccm_matrix_rel_error_median", "ccm_matrix_rel_error_p95"],
    "Project sample to EM*": ["em_coverage", "em_ws_psnr_db", "em_sphere_correlation", "em_depth_median_abs_m"],
    "Calculate SH coefficients*": ["sh_coeff_rel_error", "irradiance_rel_error_mean", "irradiance_rel_error_vs_true"],
    "Shade object (PRT)": ["shading_rel_rmse"],
    "Composite": ["composite_rel_rmse", "composite_object_rel_rmse", "composite_shadow_rel_rmse",
                  "composite_rel_rmse_noise_corrected"],
}


def timing_table(records: list[StageRecord]) -> dict[str, dict]:
    """Per stage (pipeline order, then any others) plus the two per-frame totals."""
    per = summarise(records)
    ordered = {name: per[name] for name in STAGES if name in per}
    ordered.update({k: v for k, v in per.items() if k not in ordered})
    ordered[DEPTH_TOTAL] = stage_stats(frame_totals(records, "depth", exclude=RENDER_STAGES))
    ordered[COLOUR_TOTAL] = stage_stats(frame_totals(records, "colour"))
    return ordered


def _fmt(v: float) -> str:
    return "—" if v is None or not np.isfinite(v) else f"{v:.2f}"


def _write_csv(path: Path, table: dict[str, dict]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["stage", "count", "median_ms", "p95_ms"])
        for name, s in table.items():
            w.writerow([name, s["count"], f"{s['median_ms']:.4f}", f"{s['p95_ms']:.4f}"])


def _markdown(run: Path, table: dict[str, dict], accuracy: dict, info: dict) -> str:
    # A run is written into ".<name>.partial-<pid>" beside its --out and renamed when complete.
    name = re.fullmatch(r"\.(.+)\.partial-\d+", run.name)
    lines = [f"# Run report: {name.group(1) if name else run.name}", ""]
    if info:
        lines += [
            f"{info.get('depth_packets', '?')} depth and {info.get('colour_packets', '?')} colour packets; "
            f"{info.get('depth_frames_processed', '?')} depth frames processed, "
            f"{info.get('depth_packets_dropped', 0)} depth packets without a colour frame. "
            f"Pipeline wall time {info.get('pipeline_wall_s', float('nan')):.1f} s.", "",
        ]
    lines += [
        "## Time per stage (this machine's CPU) beside the paper's Table 1 (Adreno 510 GPU)", "",
        "| stage | count | median ms | p95 ms | paper ms | error against ground truth |",
        "|---|---:|---:|---:|---:|---|",
    ]
    paper = dict(PAPER_TABLE1_MS)
    for name, s in table.items():
        if name in (DEPTH_TOTAL, COLOUR_TOTAL):
            continue
        ref = paper.get(name)
        errs = ", ".join(f"{k} = {accuracy[k]:.4g}" for k in STAGE_ERRORS.get(name, [])
                         if isinstance(accuracy.get(k), (int, float)))
        lines.append(f"| {name} | {s['count']} | {_fmt(s['median_ms'])} | {_fmt(s['p95_ms'])} | {_fmt(ref)} | {errs} |")
    if "Calculate MSE" not in table:
        lines.append("| Calculate MSE | | (in the matrix stage) | | 2.69 | |")
    lines.append("| Transfer data to GPU | | (none: CPU) | | 10.02 | |")
    d, c = table[DEPTH_TOTAL], table[COLOUR_TOTAL]
    lines += [
        f"| **{DEPTH_TOTAL}** (every stage of a depth packet except rendering) | {d['count']} | **{_fmt(d['median_ms'])}** | "
        f"{_fmt(d['p95_ms'])} | 33.52 | |",
        f"| **{COLOUR_TOTAL}** (decode + rasterise + composite of a colour frame) | {c['count']} | **{_fmt(c['median_ms'])}** | "
        f"{_fmt(c['p95_ms'])} | 20.7 | |",
        "",
        "The paper's 33.52 ms is its Table 1 total (54.22) less rendering (20.7); its render time is per frame. "
        "Stages marked * run only while the EM is being recorded. Shading (PRT transfer × SH coefficients) "
        "runs once per new set of coefficients, so it is counted in the depth frame that produced them. "
        "Totals are per-frame sums, then their median / p95.",
        "",
    ]
    depth_stages = {k: v for k, v in table.items() if k not in RENDER_STAGES and k not in (DEPTH_TOTAL, COLOUR_TOTAL)}
    if depth_stages:
        # per depth frame, the share of the total: median time × count / frames
        n = max(d["count"], 1)
        shares = {k: v["median_ms"] * v["count"] / n for k, v in depth_stages.items() if np.isfinite(v["median_ms"])}
        top = sorted(shares.items(), key=lambda kv: -kv[1])[:3]
        lines += ["What dominates a depth frame (median × executions per frame): "
                  + ", ".join(f"{k} {v:.2f} ms" for k, v in top) + ".", ""]
    if accuracy:
        lines += ["## Accuracy against ground truth (accuracy.json)", "", "| metric | value |", "|---|---:|"]
        lines += [f"| {k} | {v:.6g} |" if isinstance(v, float) else f"| {k} | {v} |" for k, v in accuracy.items()]
        lines.append("")
    lines += ["![per-stage times over the session](timing.png)", ""]
    return "\n".join(lines)


def _plot(path: Path, records: list[StageRecord]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    by_stage: dict[str, list[tuple[int, float]]] = {}
    for r in records:
        by_stage.setdefault(r.stage, []).append((r.frame, r.ms))
    for name, pts in by_stage.items():
        a = np.asarray(pts)
        ax = axes[1] if name in RENDER_STAGES else axes[0]
        ax.plot(a[:, 0], a[:, 1], ".", ms=3, label=name)
    axes[0].set_title("depth-frame stages")
    axes[1].set_title("colour-frame stages")
    for ax in axes:
        ax.set_ylabel("ms")
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, ncol=3, loc="upper right")
    axes[1].set_xlabel("packet number in the session")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_reports(run: str | Path) -> dict[str, dict]:
    """(Re)generate timing.csv, timing.md and timing.png of a run folder; returns the timing table."""
    run = Path(run)
    if not run.is_dir():
        raise LogFormatError(f"{run}: not a run folder")
    records = read_records(run / "stage_times.csv")
    table = timing_table(records)
    accuracy = _read_json(run / "accuracy.json")
    info = _read_json(run / "run.json")
    _write_csv(run / "timing.csv", table)
    (run / "timing.md").write_text(_markdown(run, table, accuracy, info))
    _plot(run / "timing.png", records)
    return table


def _read_json(path: Path) -> dict:
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise LogFormatError(f"{path}, line {exc.lineno}: invalid JSON ({exc.msg})") from None
