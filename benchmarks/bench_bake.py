"""Time the bake (sim/bake.py) of a lit scene, phase by phase: median and p95 over runs.

    python benchmarks/bench_bake.py [--runs N] [--scene office] [--set spp=8 ...]
                                    [--baseline OLD_BAKE.py] [--json PATH]

Every run bakes from scratch (no cache). The phases are those ``bake_scene(..., timings=...)``
reports: the lattice, the live-side probes of each visibility state (s0, s1, ...), the first pass of
each state × emitter group (g0, g1, ...) with its two parts, the indirect light traced by Mitsuba and
the direct light (emitter area sampling and open3d shadow rays), and the final gather of each state;
"total" is the whole call. ``--set key=value`` changes a ``BakeConfig`` field (repeatable).

``--baseline PATH`` loads another version of sim/bake.py (e.g. ``git show REF:sim/bake.py >
/tmp/bake_old.py``) as a separate module and times its bake at its own defaults, alternating with
this one run by run, so the load from other processes on this shared machine hits both alike (the
baseline reports only its total unless it takes ``timings``).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import inspect
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from sim import bake  # noqa: E402
from sim.scene import load_scene  # noqa: E402


def _parse_set(items: list[str]) -> dict:
    fields = {f.name: f.type for f in dataclasses.fields(bake.BakeConfig)}
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        if key not in fields:
            raise SystemExit(f"--set: unknown BakeConfig field {key!r} (fields: {', '.join(fields)})")
        out[key] = float(value) if "float" in str(fields[key]) else int(value)
    return out


def _load_baseline(path: str):
    # A private copy: numba's on-disk cache next to the file would otherwise name another module.
    copy = Path(tempfile.mkdtemp(prefix="bench_bake_")) / "bake_baseline.py"
    shutil.copyfile(path, copy)
    spec = importlib.util.spec_from_file_location("bake_baseline", copy)
    module = importlib.util.module_from_spec(spec)
    sys.modules["bake_baseline"] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _run(module, scene, config) -> dict:
    timings: dict = {}
    kwargs = {"use_cache": False}
    if "timings" in inspect.signature(module.bake_scene).parameters:
        kwargs["timings"] = timings
    start = time.perf_counter()
    module.bake_scene(scene, config, **kwargs)
    timings["total"] = time.perf_counter() - start
    return timings


def _table(name: str, runs: list[dict]) -> dict:
    phases = list(runs[0])
    rows = {}
    for p in phases:
        v = np.array([r.get(p, 0.0) for r in runs])
        rows[p] = {"median_s": float(np.median(v)), "p95_s": float(np.percentile(v, 95)), "n": len(v)}
    width = max(len(p) for p in phases)
    print(f"\n{name}")
    print(f"{'phase':<{width}}  {'median s':>9}  {'p95 s':>8}  {'n':>3}")
    for p, r in rows.items():
        print(f"{p:<{width}}  {r['median_s']:>9.2f}  {r['p95_s']:>8.2f}  {r['n']:>3}")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2, help="bakes per version (median and p95 over them)")
    ap.add_argument("--scene", default="office")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a BakeConfig field")
    ap.add_argument("--baseline", help="another sim/bake.py, timed at its defaults alternately with this one")
    ap.add_argument("--json", help="write the tables here")
    args = ap.parse_args()
    scene = load_scene(args.scene)
    config = bake.BakeConfig(**_parse_set(args.set))
    lattice = bake.build_lattice(scene, config.texel_m)
    print(f"{args.scene}: {lattice.size:,} lattice points, {len(bake.visibility_states(scene))} visibility states, "
          f"{len(bake.emitter_groups(scene))} emitter groups; {config}")
    versions = {"this": (bake, config)}
    if args.baseline:
        old = _load_baseline(args.baseline)
        versions["baseline"] = (old, old.BakeConfig())
    results: dict[str, list[dict]] = {k: [] for k in versions}
    for r in range(args.runs):
        for name, (module, cfg) in (versions.items() if r % 2 == 0 else reversed(versions.items())):
            results[name].append(_run(module, scene, cfg))
            print(f"run {r + 1}/{args.runs} {name}: {results[name][-1]['total']:.1f} s", flush=True)
    tables = {name: _table(f"{name} ({args.baseline if name == 'baseline' else 'sim/bake.py'})", runs)
              for name, runs in results.items()}
    if args.json:
        Path(args.json).write_text(json.dumps({"scene": args.scene, "config": str(config), "tables": tables}, indent=1))


if __name__ == "__main__":
    main()
