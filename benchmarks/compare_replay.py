"""Replay one recorded session with two versions of the project, alternately, and compare.

    python benchmarks/compare_replay.py --log runs/default/session --baseline REF [--rounds 3] [--out DIR]

``REF`` is a git ref (commit, branch, tag) of this repository: its tree is exported into a
temporary folder (``git archive``) and run with the same Python and packages, the current working
tree beside it. Each round replays the log once with each version, the order alternating, so that
both see the same spells of a shared machine. Each replay writes a run folder under ``--out``;
the script prints, per version, the median over rounds of each replay's ``depth_frame_total`` and
``colour_frame_total`` medians (from ``timing.csv``), the per-round figures, and whether the final
maps (``envmap.npz``: radiance, depth, valid, origin) are identical between the versions.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def export_tree(ref: str, dest: Path) -> Path:
    """The repository's tree at ``ref`` in ``dest`` (without its git history)."""
    dest.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", ref], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def replay(tree: Path, log: Path, out: Path, extra: list[str]) -> None:
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, "-m", "apps.cli", "replay", str(log), "--out", str(out), "--quiet", *extra]
    if out.exists():
        shutil.rmtree(out)
    subprocess.run(cmd, cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL)


def stage_medians(run: Path) -> dict[str, float]:
    with open(run / "timing.csv", newline="") as f:
        return {row["stage"]: float(row["median_ms"]) for row in csv.DictReader(f)}


def same_map(a: Path, b: Path) -> bool:
    with np.load(a / "envmap.npz") as x, np.load(b / "envmap.npz") as y:
        return set(x.files) == set(y.files) and all(np.array_equal(x[k], y[k]) for k in x.files)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", type=Path, default=ROOT / "runs" / "default" / "session")
    ap.add_argument("--baseline", required=True, metavar="REF", help="git ref of the other version")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None, help="where the run folders go (default: a temporary folder)")
    ap.add_argument("--no-render", action="store_true", help="replay without rendering (capture stages only)")
    args = ap.parse_args()
    work = Path(args.out or tempfile.mkdtemp(prefix="compare-replay-"))
    trees = {"baseline": export_tree(args.baseline, work / "baseline-tree"), "current": ROOT}
    extra = ["--no-video"] + (["--no-render"] if args.no_render else [])
    figures: dict[str, list[dict[str, float]]] = {k: [] for k in trees}
    for i in range(args.rounds):
        order = list(trees) if i % 2 == 0 else list(trees)[::-1]
        for name in order:
            run = work / f"{name}-{i}"
            replay(trees[name], args.log.resolve(), run, extra)
            figures[name].append(stage_medians(run))
            print(f"round {i} {name:>8}: depth_frame_total {figures[name][-1]['depth_frame_total']:.2f} ms", flush=True)
    print(f"\n{'version':>8}  {'depth_frame_total':>18}  {'colour_frame_total':>19}  per round (depth)")
    for name, rows in figures.items():
        depth = [r["depth_frame_total"] for r in rows]
        colour = [r.get("colour_frame_total", float("nan")) for r in rows]
        print(f"{name:>8}  {np.median(depth):>15.2f} ms  {np.median(colour):>16.2f} ms  "
              + " ".join(f"{d:.2f}" for d in depth))
    print(f"final maps identical: {same_map(work / 'baseline-0', work / 'current-0')}")
    print(f"run folders: {work}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
