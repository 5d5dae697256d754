"""Time the colour-correction and environment-map stages on realistic data (paper Table 1 rows
"Collect paired samples", "Compute colour correction matrix", "Calculate MSE", "Project sample to EM"
and the §6.2 translation).

    python benchmarks/bench_envmap.py [--repeats N] [--recorded PATH] [--recorded-rounds R] [--threads T]
                                      [--translation-rounds N] [--json PATH]
                                      [--only-recorded | --only-translation | --update-parts
                                       | --one-thread-kernels | --baseline REF]

Without a mode:

1. One frame: a 4.2 s capture of the default scene warms the map up; the timed frame is the next.
   Pairs + matrix + MSE over every known point and over the reliable ones, the stage "Collect
   paired samples" as the capture runs it (``frame_pair_sums``) and the fit from its sums
   (``ccm_from_sums``), the frame's world points, the map update (footprints, and one pixel per
   sample), the projected mask.
2. The recorded session (``--recorded``, default ``runs/default/session``, written by ``bash
   scripts/main.sh``; skipped when missing): the capture inputs of every depth frame as the pipeline
   makes them, replayed ``--recorded-rounds`` times through ``EnvironmentCapture``; the stages
   "Collect paired samples", "Compute colour correction matrix" and "Project sample to EM*" as
   ``capture.process`` times them, and the ``update`` call alone, per frame.
3. Translation by 10 cm of the 4.2 s map, of the recorded session's final map and of the ray-cast
   true map: the depth warp, with ``out=`` (the output map of the previous call overwritten), on
   two threads beside one when ``--threads 2``, and Gardner's warp (``--translation-rounds`` each,
   default ``max(5, repeats // 5)``).

Modes (each runs alone):

- ``--only-recorded``: part 2 only.
- ``--only-translation``: part 3 for the recorded session's final map and the true map only.
- ``--update-parts``: every ``update`` call of the recorded session with one part of the update
  switched off at a time (:data:`UPDATE_PARTS`: footprints clamped, colour averaging, carving,
  footprints, all three), each setting on a map of its own, alternately frame by frame,
  ``--recorded-rounds`` passes: what each part costs per frame, and how many map pixels it touches
  and takes.
- ``--baseline REF``: another version of the library, the ``rgbd_envmap`` tree of the git ref REF
  (a commit, a branch) exported and imported as ``rgbd_envmap_baseline``, called through its
  public API (``envmap.update``, ``envmap.translate``). Every ``update`` call of the recorded session
  runs in both on maps of their own that record changes, frame by frame alternately (which goes
  first alternates), ``--recorded-rounds`` passes from empty maps; after every frame the maps, the
  ``UpdateStats`` and the change logs must be identical. Median / p95 ms of the call, and of each
  frame's fastest pass (less sensitive to a noisy machine). Then the translation of the session's
  final map and of the true map by both, alternately, with the count of pixels that differ (with
  ``--only-translation``: the translations only).
- ``--one-thread-kernels``: the two-thread translation kernel run on one numba thread against the
  one-thread kernel (``translate_kernel_2t`` / ``translate_kernel``) on the session's final map and
  the true map, ``--translation-rounds`` (at least 21): what the two-thread structure costs where
  only one core is free. (The map update and the colour-pair sums have one kernel each, which
  runs on one thread or two.) The kernels are called through ``translate`` (its argument
  preparation), whose ``usable_threads`` is patched to choose the kernel; each call of the kernel
  itself is timed. Prints a table: kernel, median / p95 ms of each, the ratio of the medians, the
  median of the per-call ratios (each pair of calls back to back) and whether the results are
  identical bit for bit.

Rows that are compared are timed alternately in the same run, the order reversed every round (the
machine is shared and noisy). ``--threads`` is numba's thread count and the ``threads`` argument of
the library's calls (default 1: the serial kernels; the pipeline's default is 2).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import json
import math
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import rgbd_envmap.envmap.translation as translation_module  # noqa: E402
import rgbd_envmap.pipeline.capture as capture_module  # noqa: E402
from apps.replay import default_origin  # noqa: E402
from benchmarks.eval_envmap import ingested_frames  # noqa: E402
from rgbd_envmap._kernels.parallel import configure_threading_layer, usable_threads  # noqa: E402
from rgbd_envmap.colour import DEFAULT_MAX_CONDITION, DEFAULT_RIDGE, apply_ccm, ccm_from_sums, estimate_ccm  # noqa: E402
from rgbd_envmap.envmap import (  # noqa: E402
    EnvironmentMap,
    UpdateConfig,
    collect_pairs,
    frame_pair_sums,
    frame_points,
    translate,
    update,
)
from rgbd_envmap.logs import SessionLog  # noqa: E402
from rgbd_envmap.pipeline import CaptureConfig, EnvironmentCapture, Pipeline, PipelineConfig  # noqa: E402
from rgbd_envmap.timing import StageTimer  # noqa: E402
from sim.colour_camera import ColourCameraConfig  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402
from sim.groundtruth import render_envmap  # noqa: E402
from sim.scene import load_scene  # noqa: E402
from sim.session import Simulator  # noqa: E402
from sim.trajectory import load_trajectory  # noqa: E402

OFFSET = np.array([0.1, 0.0, 0.0])  # every translation row moves the map by 10 cm


def _stats(ms, cpu_ms=None) -> dict:
    a = np.asarray(ms, np.float64)
    out = {"median_ms": float(np.median(a)), "p95_ms": float(np.percentile(a, 95)), "min_ms": float(a.min()), "n": len(a)}
    if cpu_ms is not None:  # thread CPU time: less inflated than wall time when other jobs share the cores
        out["cpu_median_ms"] = float(np.median(cpu_ms))
    return out


def time_alternating(fns: dict, repeats: int, warmup: int = 1) -> dict[str, dict]:
    """Like common.time_it for several functions, called in turn (order reversed every round)."""
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    ms = {k: [] for k in fns}
    cpu = {k: [] for k in fns}
    keys = list(fns)
    for i in range(repeats):
        for k in keys if i % 2 else keys[::-1]:
            t0, c0 = time.perf_counter(), time.thread_time()
            fns[k]()
            cpu[k].append((time.thread_time() - c0) * 1e3)
            ms[k].append((time.perf_counter() - t0) * 1e3)
    return {k: _stats(ms[k], cpu[k]) for k in fns}


def print_rows(rows: dict[str, dict]) -> None:
    """common.print_table plus the median thread CPU time where measured."""
    width = max(len(k) for k in rows)
    print(f"{'case':<{width}}  {'median ms':>10}  {'p95 ms':>10}  {'cpu med ms':>10}  {'n':>4}")
    for name, r in rows.items():
        cpu = f"{r['cpu_median_ms']:>10.2f}" if "cpu_median_ms" in r else f"{'':>10}"
        print(f"{name:<{width}}  {r['median_ms']:>10.2f}  {r['p95_ms']:>10.2f}  {cpu}  {r['n']:>4}")


def _maps_differ(a, b) -> int:
    """Pixels whose validity, depth or radiance differ, bit for bit (maps of either library)."""
    return int(((a.valid != b.valid) | (a.depth_m.view(np.uint32) != b.depth_m.view(np.uint32))
                | (a.radiance_planes.view(np.uint32) != b.radiance_planes.view(np.uint32)).any(0)).sum())


def _same_changes(ca, cb) -> bool:
    """Two change logs (``take_changes``) list the same pixels with the same previous state."""
    if ca is None or cb is None:
        return ca is cb
    return ((ca.complete, ca.updates) == (cb.complete, cb.updates) and np.array_equal(ca.index, cb.index)
            and np.array_equal(ca.was_valid, cb.was_valid)
            and np.array_equal(ca.old_radiance.view(np.uint32), cb.old_radiance.view(np.uint32)))


# --- inputs ----------------------------------------------------------------------------------------


def make_sim() -> Simulator:
    return Simulator(load_scene("office"), load_trajectory("orbit"),
                     TangoDeviceConfig(colour=ColourCameraConfig(width=640, height=360)), seed=0)


def true_map(sim: Simulator) -> EnvironmentMap:
    """The ray-cast true map at the virtual object's position (2000×1000, everything covered)."""
    origin = sim.scene.virtual_object_position
    gt = render_envmap(sim.raycaster, origin, 1000, 2000, 0.0)
    return EnvironmentMap.from_arrays(gt.radiance, gt.distance_m, gt.valid, origin)


def _open_session(root: Path):
    """(log, pipeline config with rendering off, default origin) of the recorded session at ``root``;
    None when there is none (``bash scripts/main.sh`` writes ``runs/default/session``)."""
    if not (root / "calibration.json").is_file():
        return None
    log = SessionLog.open(root)
    cfg = PipelineConfig()
    return log, dataclasses.replace(cfg, render=dataclasses.replace(cfg.render, enabled=False)), default_origin(log)


_CAPTURE_INPUTS: dict[Path, tuple] = {}


def capture_inputs(root: Path) -> tuple[np.ndarray, CaptureConfig, list] | None:
    """Every ``EnvironmentCapture.process`` call of the recorded session at ``root``, replayed through
    the pipeline (rendering off): (origin, capture config, [(raw, reliable, filled, across_edges)]);
    None when there is no session. Kept for the process (each mode needs them once)."""
    root = Path(root)
    if root in _CAPTURE_INPUTS:
        return _CAPTURE_INPUTS[root]
    opened = _open_session(root)
    if opened is None:
        return None
    log, cfg, origin = opened
    pipe = Pipeline(cfg, log.calibration, origin)
    calls = []
    real = EnvironmentCapture.process

    def record(self, raw, reliable, filled, *, across_edges=None, timer=None):
        calls.append((raw, reliable.copy(), filled, across_edges))
        return real(self, raw, reliable, filled, across_edges=across_edges, timer=timer)

    EnvironmentCapture.process = record
    try:
        for packet in log:
            pipe.feed(packet)
    finally:
        EnvironmentCapture.process = real
    _CAPTURE_INPUTS[root] = (origin, pipe.capture.config, calls)
    return _CAPTURE_INPUTS[root]


def replay_capture(root: Path, threads: int = 1, on_update=None, on_pair_sums=None) -> EnvironmentMap | None:
    """One replay of the recorded session's capture inputs through a fresh ``EnvironmentCapture``;
    ``on_update`` / ``on_pair_sums`` replace the capture's ``update`` / ``frame_pair_sums`` (called
    with the same arguments, the real function passed first). Returns the final map."""
    data = capture_inputs(root)
    if data is None:
        return None
    origin, cfg, calls = data
    real_update, real_sums = capture_module.update, capture_module.frame_pair_sums
    if on_update is not None:
        capture_module.update = lambda *a, **k: on_update(real_update, *a, **k)
    if on_pair_sums is not None:
        capture_module.frame_pair_sums = lambda *a, **k: on_pair_sums(real_sums, *a, **k)
    try:
        cap = EnvironmentCapture(origin, cfg, threads=threads)
        for raw, reliable, filled, across in calls:
            cap.process(raw, reliable, filled, across_edges=across)
    finally:
        capture_module.update, capture_module.frame_pair_sums = real_update, real_sums
    return cap.em


def recorded_update_calls(root: Path) -> tuple[np.ndarray, int, int, list, EnvironmentMap] | None:
    """The arguments of every ``update`` call of the recorded session at ``root``: (origin, map height,
    width, [(points, colours, device, focal, config, fill_only, seen)], the final map); None when
    there is no session."""
    calls = []

    def record(real, em, pts, col, dev, focal, config, fill_only=None, seen=None, **kw):
        calls.append((pts.copy(), col.copy(), np.array(dev), focal, config,
                      None if fill_only is None else fill_only.copy(), seen))
        return real(em, pts, col, dev, focal, config, fill_only, seen, **kw)

    em = replay_capture(root, on_update=record)
    if em is None:
        return None
    return em.origin, em.height, em.width, calls, em


def _no_session(root: Path) -> None:
    print(f"recorded session: none at {root} (bash scripts/main.sh writes it); skipped")


# --- default run -----------------------------------------------------------------------------------


def one_frame(sim, frames, r: int, rows: dict, threads: int) -> EnvironmentMap:
    cap = EnvironmentCapture(sim.scene.virtual_object_position, CaptureConfig(), threads=threads)
    for res in frames[:-1]:
        cap.process(res.frame, res.reliable, res.filled, across_edges=res.across_edges)
    res = frames[-1]
    raw, filled = res.frame, res.filled
    em, cfg = cap.em, cap.config
    # Pairs over the whole cloud (every known pixel, as the paper's 38,528-point figure), and over
    # the reliable pixels the pipeline actually uses.
    pts_all = frame_points(raw.depth_m, raw.known, raw.intrinsics, raw.T_world_from_cam)
    col_all = raw.rgb[raw.known]
    pts_rel = frame_points(raw.depth_m, res.reliable, raw.intrinsics, raw.T_world_from_cam)
    col_rel = raw.rgb[res.reliable]
    src, dst = collect_pairs(em, pts_all, col_all)
    mask = cap.projected_mask(raw, filled, res.across_edges)
    pts_proj = frame_points(filled.depth_m, mask, filled.intrinsics, filled.T_world_from_cam)
    col_proj = apply_ccm(filled.rgb[mask], cap.matrix)
    dev = filled.T_world_from_cam.translation
    focal = 0.5 * (filled.intrinsics.fx + filled.intrinsics.fy)
    work = em.copy()
    print(f"map coverage before the timed frame: {em.valid.mean():.3f}")

    def pmm(p, c):
        s, d = collect_pairs(em, p, c)
        return estimate_ccm(s, d, method="ridge")

    def pair_sums():
        return frame_pair_sums(em, raw.depth_m, res.reliable, raw.intrinsics, raw.T_world_from_cam, raw.rgb,
                               cfg.pair_max_depth_diff_m, threads=threads)

    def fit(sums):
        return ccm_from_sums(*sums, cfg.ccm_method, max_mse=cfg.max_mse, min_pairs=cfg.min_pairs,
                             max_condition=DEFAULT_MAX_CONDITION, noise_std=None, ridge=DEFAULT_RIDGE)

    *sums, _ = pair_sums()
    n_all, n_rel = len(pts_all), len(pts_rel)
    rows.update(time_alternating({
        f"pairs+matrix+mse, all {n_all} known pts ({len(src)} pairs)": lambda: pmm(pts_all, col_all),
        f"pairs+matrix+mse, {n_rel} reliable pts": lambda: pmm(pts_rel, col_rel),
        f"Collect paired samples as capture runs it (frame_pair_sums, {n_rel} reliable px)": pair_sums,
        "Compute colour correction matrix from the sums (ccm_from_sums)": lambda: fit(sums),
    }, r))
    rows.update(time_alternating({
        "  of which collect_pairs (all pts)": lambda: collect_pairs(em, pts_all, col_all),
        "  of which estimate_ccm ridge": lambda: estimate_ccm(src, dst, method="ridge"),
        "world points of a frame (frame_points)": lambda: frame_points(filled.depth_m, mask, filled.intrinsics,
                                                                       filled.T_world_from_cam),
    }, r))
    point = UpdateConfig(splat=False)
    rows.update(time_alternating({
        f"EM update 2000x1000, {len(pts_proj)} samples, splat": lambda: update(work, pts_proj, col_proj, dev, focal,
                                                                               threads=threads),
        f"EM update 2000x1000, {len(pts_proj)} samples, one pixel each": lambda: update(work, pts_proj, col_proj, dev, focal,
                                                                                        point, threads=threads),
    }, r))
    rows["projected mask (filled pixels, across-edge test)"] = time_alternating(
        {"m": lambda: cap.projected_mask(raw, filled, res.across_edges)}, r)["m"]
    return em


def recorded_session(root: Path, rows: dict, rounds: int, threads: int) -> EnvironmentMap | None:
    """The capture stages per depth frame of the recorded session, as ``capture.process`` times them
    inside the pipeline ("Collect paired samples", "Compute colour correction matrix", "Project
    sample to EM*"), and the ``update`` call alone; ``rounds`` replays of the session."""
    data = capture_inputs(root)
    if data is None:
        _no_session(root)
        return None
    origin, cfg, calls = data
    stages = ("Collect paired samples", "Compute colour correction matrix", "Project sample to EM*")
    ms = {k: [] for k in (*stages, "pairs+fit", "update")}
    real_update = capture_module.update
    updates: list[float] = []

    def timed_update(*a, **k):
        t0 = time.perf_counter()
        out = real_update(*a, **k)
        updates.append((time.perf_counter() - t0) * 1e3)
        return out

    capture_module.update = timed_update
    try:
        for _ in range(rounds):
            cap = EnvironmentCapture(origin, cfg, threads=threads)
            timer = StageTimer()
            updates.clear()
            for raw, reliable, filled, across in calls:
                timer.begin("depth")
                cap.process(raw, reliable, filled, across_edges=across, timer=timer)
            by_stage = {s: [rec.ms for rec in timer.records if rec.stage == s] for s in stages}
            ms[stages[0]] += by_stage[stages[0]]
            ms[stages[1]] += by_stage[stages[1]]
            ms["pairs+fit"] += [a + b for a, b in zip(by_stage[stages[0]], by_stage[stages[1]])]
            # The reference frame (into an empty map) is left out of the projection rows.
            ms[stages[2]] += by_stage[stages[2]][1:]
            ms["update"] += updates[1:]
    finally:
        capture_module.update = real_update
    n = len(calls)
    rows[f"recorded session ({n} frames, {rounds} rounds): Collect paired samples per frame"] = _stats(ms[stages[0]])
    rows["recorded session: Compute colour correction matrix per frame"] = _stats(ms[stages[1]])
    rows["recorded session: pairs + matrix + MSE per frame (Collect + Compute stages)"] = _stats(ms["pairs+fit"])
    rows["recorded session: Project sample to EM* per frame"] = _stats(ms[stages[2]])
    rows["recorded session: of which update()"] = _stats(ms["update"])
    print(f"recorded session {root}: {n} depth frames, final map coverage {cap.em.valid.mean():.3f}")
    return cap.em


def translations(maps: dict[str, EnvironmentMap], r: int, rows: dict, threads: int, gardner: bool = True) -> None:
    for name, em in maps.items():
        fns = {f"translate 2000x1000 by 10 cm, {name} (depth)": lambda em=em: translate(em, OFFSET, threads=1)}
        if threads >= 2 and usable_threads(2) >= 2:
            diff = _maps_differ(translate(em, OFFSET, threads=1), translate(em, OFFSET, threads=2))
            print(f"translate {name}: {diff} of {em.height * em.width} pixels differ on two threads")
            fns[f"  two threads, {name}"] = lambda em=em: translate(em, OFFSET, threads=2)
        # A caller translating every frame can pass last frame's result as out= (no fresh 34 MB).
        reused = EnvironmentMap(em.height, em.width)
        diff = _maps_differ(translate(em, OFFSET, threads=1), translate(em, OFFSET, out=reused, threads=1))
        print(f"translate {name}: {diff} of {em.height * em.width} pixels differ with out=")
        fns[f"  out= (the output map reused), {name}"] = lambda em=em, reused=reused: translate(em, OFFSET, out=reused,
                                                                                                threads=1)
        if gardner:
            fns[f"  gardner, {name}"] = lambda em=em: translate(em, OFFSET, "gardner")
        rows.update(time_alternating(fns, r))


# --- --update-parts --------------------------------------------------------------------------------

#: ``--update-parts``: the update with one part of it switched off at a time (name, UpdateConfig fields).
UPDATE_PARTS = (
    ("defaults", {}),
    ("footprints clamped to 8 rows (max_splat_px=8)", {"max_splat_px": 8}),
    ("colour replaced, not averaged (colour_average=1)", {"colour_average": 1}),
    ("no free-space carving (carve=False)", {"carve": False}),
    ("one pixel per sample (splat=False)", {"splat": False}),
    ("viewpoint rule off (view_ratio=inf)", {"view_ratio": math.inf}),
    ("the paper's update: one pixel, no carving, colour replaced", {"splat": False, "carve": False, "colour_average": 1}),
)


def update_parts(root: Path, rounds: int, rows: dict, threads: int) -> None:
    """What each part of ``update`` costs: the recorded session's update calls run with each setting
    of :data:`UPDATE_PARTS` on a map of its own (so each map evolves as a capture with that setting
    would), alternately frame by frame (the order rotating), ``rounds`` passes from empty maps, every
    map recording changes as the pipeline's does. Per setting: median / p95 ms per frame, and the
    median map pixels touched and taken a frame (printed). The first frame is left out of the times."""
    data = recorded_update_calls(root)
    if data is None:
        _no_session(root)
        return
    origin, h, w, calls, _ = data
    names = [name for name, _ in UPDATE_PARTS]
    ms = {name: [] for name in names}
    touched = {name: [] for name in names}
    taken = {name: [] for name in names}
    for r in range(rounds):
        maps = {name: EnvironmentMap(h, w, origin) for name in names}
        for em in maps.values():
            em.record_changes()
        for j, (pts, col, dev, focal, config, fill_only, seen) in enumerate(calls):
            shift = (j + r) % len(UPDATE_PARTS)
            for name, fields in UPDATE_PARTS[shift:] + UPDATE_PARTS[:shift]:
                cfg = dataclasses.replace(config, **fields)
                t0 = time.perf_counter()
                stats = update(maps[name], pts, col, dev, focal, cfg, fill_only, seen, threads=threads)
                if j > 0:
                    ms[name].append((time.perf_counter() - t0) * 1e3)
                    touched[name].append(stats.touched)
                    taken[name].append(stats.taken)
                maps[name].take_changes()
    print(f"update on {len(calls) - 1} recorded frames (the first left out), {rounds} rounds, {threads} thread(s), "
          f"each setting on its own map:")
    for name in names:
        print(f"  {name}: median {np.median(touched[name]):.0f} map pixels touched, {np.median(taken[name]):.0f} taken a frame")
        rows[f"update per frame, {name}"] = _stats(ms[name])


# --- --baseline REF --------------------------------------------------------------------------------


def load_baseline(ref: str):
    """The library at git ref ``ref`` as the package ``rgbd_envmap_baseline``: its ``rgbd_envmap``
    tree exported (``git archive``) into the temporary directory, under a folder named by the
    commit (kept, so numba's cache of its kernels serves later runs), every ``rgbd_envmap`` name in
    its .py files rewritten, the folder put on ``sys.path``. Returns its ``envmap`` module."""
    def git(*args: str, **kw) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *args], cwd=REPO, check=True, capture_output=True, **kw)

    try:
        sha = git("rev-parse", "--verify", f"{ref}^{{commit}}", text=True).stdout.strip()
    except subprocess.CalledProcessError as e:
        raise SystemExit(f"--baseline {ref}: not a commit ({e.stderr.strip()})") from None
    root = Path(tempfile.gettempdir()) / f"rgbd_envmap_baseline-{sha[:12]}"
    pkg = root / "rgbd_envmap_baseline"
    if not (root / ".complete").is_file():
        shutil.rmtree(root, ignore_errors=True)
        root.mkdir(parents=True)
        subprocess.run(["tar", "-x", "-C", str(root)], input=git("archive", sha, "rgbd_envmap").stdout, check=True)
        (root / "rgbd_envmap").rename(pkg)
        for path in pkg.rglob("*.py"):
            text = path.read_text()
            path.write_text(re.sub(r"\brgbd_envmap\b", "rgbd_envmap_baseline", text))
        (root / ".complete").write_text(sha + "\n")
    sys.path.insert(0, str(root))
    envmap = importlib.import_module("rgbd_envmap_baseline.envmap")
    print(f"baseline: {ref} = {sha[:12]}, imported from {pkg}")
    return envmap


def _to_baseline(obj, modules):
    """A dataclass of the current library (UpdateConfig, SeenDepth, Intrinsics, RigidTransform, …)
    rebuilt as the baseline's class of the same name, field by field (fields the baseline lacks are
    dropped); anything else as it is."""
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        return obj
    name = type(obj).__name__
    cls = next((getattr(m, name) for m in modules if hasattr(m, name)), None)
    if cls is None:
        raise SystemExit(f"baseline: no class {name}")
    return cls(**{f.name: _to_baseline(getattr(obj, f.name), modules)
                  for f in dataclasses.fields(cls) if f.init and hasattr(obj, f.name)})


class Baseline:
    """The baseline's ``update`` and ``translate`` called as the current library's are, whichever
    signature they have (``threads=`` or ``UpdateConfig.threads``)."""

    def __init__(self, envmap) -> None:
        self.envmap = envmap
        self.modules = (envmap, importlib.import_module("rgbd_envmap_baseline.types"))
        self.update_threads_kw = "threads" in inspect.signature(envmap.update).parameters
        self.translate_threads_kw = "threads" in inspect.signature(envmap.translate).parameters
        self.config_threads = "threads" in {f.name for f in dataclasses.fields(envmap.UpdateConfig)}

    def map(self, em: EnvironmentMap):
        return self.envmap.EnvironmentMap.from_arrays(em.radiance, em.depth_m, em.valid, em.origin)

    def update_args(self, config, seen, threads: int):
        """The baseline's config and seen depth for a call on ``threads``, and its keyword arguments."""
        cfg = _to_baseline(config, self.modules)
        if not self.update_threads_kw and self.config_threads:
            cfg = dataclasses.replace(cfg, threads=threads)
        return cfg, _to_baseline(seen, self.modules), ({"threads": threads} if self.update_threads_kw else {})

    def translate(self, em, offset, threads: int):
        return self.envmap.translate(em, offset, **({"threads": threads} if self.translate_threads_kw else {}))


def update_against_baseline(root: Path, base: Baseline, rounds: int, rows: dict, threads: int) -> EnvironmentMap | None:
    """``update`` of the library and of the baseline on the recorded session's update calls, each on a
    map of its own, alternately frame by frame; identical maps, stats and change logs asserted after
    every frame. The first frame (into an empty map) is left out of the times. Returns the current
    library's final map of the session."""
    data = recorded_update_calls(root)
    if data is None:
        _no_session(root)
        return None
    origin, h, w, calls, final = data
    print(f"baseline: update() {'threads=' if base.update_threads_kw else 'UpdateConfig.threads'}, "
          f"translate() {'threads=' if base.translate_threads_kw else 'without threads'}")
    converted = [base.update_args(c[4], c[6], threads) for c in calls]
    ms = {k: np.zeros((rounds, len(calls) - 1)) for k in ("current", "baseline")}
    for r in range(rounds):
        maps = {"current": EnvironmentMap(h, w, origin), "baseline": base.envmap.EnvironmentMap(h, w, origin)}
        for em in maps.values():
            em.record_changes()
        for j, ((pts, col, dev, focal, config, fill_only, seen), (b_cfg, b_seen, b_kw)) in enumerate(zip(calls, converted)):
            fns = {"current": lambda: update(maps["current"], pts, col, dev, focal, config, fill_only, seen, threads=threads),
                   "baseline": lambda: base.envmap.update(maps["baseline"], pts, col, dev, focal, b_cfg, fill_only, b_seen,
                                                          **b_kw)}
            stats = {}
            for k in (("current", "baseline") if (j + r) % 2 == 0 else ("baseline", "current")):
                t0 = time.perf_counter()
                stats[k] = fns[k]()
                if j > 0:
                    ms[k][r, j - 1] = (time.perf_counter() - t0) * 1e3
            a, b = maps["current"], maps["baseline"]
            same = (dataclasses.astuple(stats["current"]) == dataclasses.astuple(stats["baseline"])
                    and _maps_differ(a, b) == 0 and _same_changes(a.take_changes(), b.take_changes()))
            if not same:
                raise SystemExit(f"update: the baseline differs at frame {j} of round {r}")
    print(f"update on {len(calls)} recorded frames, {rounds} rounds, {threads} thread(s): maps, stats and change logs "
          f"identical to the baseline after every frame")
    n = len(calls) - 1
    rows[f"recorded session ({n} frames): update() per frame, {threads} thread(s)"] = _stats(ms["current"].ravel())
    rows["  baseline"] = _stats(ms["baseline"].ravel())
    rows[f"recorded session: update(), each frame's fastest round, {threads} thread(s)"] = _stats(ms["current"].min(0))
    rows["  baseline "] = _stats(ms["baseline"].min(0))
    return final


def translations_against_baseline(maps: dict[str, EnvironmentMap], base: Baseline, r: int, rows: dict,
                                  threads: int) -> None:
    """``translate`` of each map by the library and by the baseline (the same map in its own class),
    alternately, with the pixels whose result differs."""
    for name, em in maps.items():
        bem = base.map(em)
        diff = _maps_differ(translate(em, OFFSET, threads=threads), base.translate(bem, OFFSET, threads))
        print(f"translate {name}: {diff} of {em.height * em.width} pixels differ from the baseline")
        rows.update(time_alternating({
            f"translate 2000x1000 by 10 cm, {name}, {threads} thread(s)": lambda em=em: translate(em, OFFSET, threads=threads),
            f"  baseline, {name}": lambda bem=bem: base.translate(bem, OFFSET, threads),
        }, r))


# --- --one-thread-kernels --------------------------------------------------------------------------


class KernelClock:
    """Stands in for a kernels module inside an API module: attribute access passes through, and the
    calls of the kernels named in ``timed`` are timed (``last`` holds the kernel's name and ms)."""

    def __init__(self, module, timed: tuple[str, ...]) -> None:
        self._module, self._timed, self.last = module, timed, None

    def __getattr__(self, name):
        attr = getattr(self._module, name)
        if name not in self._timed:
            return attr

        def timed(*args):
            t0 = time.perf_counter()
            out = attr(*args)
            self.last = (name, (time.perf_counter() - t0) * 1e3)
            return out

        return timed


class KernelChoice:
    """Patches an API module (``kernels`` → a :class:`KernelClock`, ``usable_threads`` → the chosen
    count) so that a call with ``threads=2`` runs the one-thread kernel (``threads = 1``) or the
    two-thread one (``threads = 2``) whatever numba's thread count."""

    def __init__(self, module, kernel_1t: str, kernel_2t: str) -> None:
        self.module, self.names = module, {1: kernel_1t, 2: kernel_2t}
        self.clock = KernelClock(module.kernels, (kernel_1t, kernel_2t))
        self.threads = 1

    def __enter__(self) -> "KernelChoice":
        self.saved = self.module.kernels, self.module.usable_threads
        self.module.kernels, self.module.usable_threads = self.clock, lambda requested: self.threads
        return self

    def __exit__(self, *exc) -> None:
        self.module.kernels, self.module.usable_threads = self.saved

    def run(self, threads: int, fn):
        """``fn()`` with the kernel for ``threads``; returns (its result, the kernel's ms)."""
        self.threads, self.clock.last = threads, None
        out = fn()
        name, ms = self.clock.last
        if name != self.names[threads]:
            raise SystemExit(f"expected {self.names[threads]} to run, got {name}")
        return out, ms


def _kernel_row(name: str, ms1, ms2, identical: bool) -> dict:
    """A table row; ``paired_ratio``: the median over calls of the two kernels' ratio on the same
    input, timed back to back (less moved by load that changes between calls than the medians)."""
    paired = float(np.median(np.asarray(ms2) / np.asarray(ms1)))
    return {"kernel": name, "one_thread": _stats(ms1), "two_thread_on_one": _stats(ms2), "paired_ratio": paired,
            "identical": identical}


def one_thread_kernels(root: Path, rounds: int, t_rounds: int, sim: Simulator) -> list[dict] | None:
    """The two-thread translation kernel on one numba thread against the one-thread kernel (see the
    module docstring); the rows of the table."""
    if numba.get_num_threads() != 1 or usable_threads(2) != 1:
        raise SystemExit("--one-thread-kernels: numba must have one thread")
    data = recorded_update_calls(root)
    if data is None:
        _no_session(root)
        return None
    origin, h, w, calls, final = data
    print(f"numba threads {numba.get_num_threads()}, usable_threads(2) = {usable_threads(2)}")
    table = []

    # translate_kernel / translate_kernel_2t: the session's final map and the true map.
    with KernelChoice(translation_module, "translate_kernel", "translate_kernel_2t") as choice:
        for name, em in (("session's final map", final), ("true map", true_map(sim))):
            outs = {t: EnvironmentMap(em.height, em.width) for t in (1, 2)}
            ms = {1: [], 2: []}
            for i in range(t_rounds + 1):
                for t in ((1, 2) if i % 2 == 0 else (2, 1)):
                    _, k_ms = choice.run(t, lambda t=t: translate(em, OFFSET, out=outs[t], threads=2))
                    if i > 0:  # the first round warms up
                        ms[t].append(k_ms)
            table.append(_kernel_row(f"translate_kernel, {name} ({t_rounds} rounds)", ms[1], ms[2],
                                     _maps_differ(outs[1], outs[2]) == 0))

    return table


def print_kernel_table(table: list[dict]) -> None:
    width = max(len(row["kernel"]) for row in table)
    print(f"{'kernel':<{width}}  {'1t median':>9}  {'1t p95':>7}  {'2t@1 median':>11}  {'2t@1 p95':>8}  "
          f"{'ratio':>6}  {'paired':>6}  identical")
    for row in table:
        a, b = row["one_thread"], row["two_thread_on_one"]
        print(f"{row['kernel']:<{width}}  {a['median_ms']:>9.3f}  {a['p95_ms']:>7.3f}  {b['median_ms']:>11.3f}  "
              f"{b['p95_ms']:>8.3f}  {b['median_ms'] / a['median_ms']:>6.3f}  {row['paired_ratio']:>6.3f}  "
              f"{'yes' if row['identical'] else 'NO'}")
    print("ms per call of the kernel (2t@1: the two-thread kernel on one numba thread); ratio: 2t@1 median / 1t "
          "median; paired: median of 2t@1 / 1t over the calls, each pair timed back to back")


# --- main ------------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=50, help="repeats of each one-frame row")
    parser.add_argument("--recorded", type=Path, default=Path("runs/default/session"),
                        help="recorded session for the session rows (skipped when missing)")
    parser.add_argument("--recorded-rounds", type=int, default=2, help="replays of the recorded session (0: skip them)")
    parser.add_argument("--translation-rounds", type=int, default=None,
                        help="repeats per translation row (default max(5, repeats // 5); --one-thread-kernels: 21)")
    parser.add_argument("--threads", type=int, default=1,
                        help="numba's thread count and the library calls' threads (default 1; the pipeline's is 2)")
    modes = parser.add_mutually_exclusive_group()
    modes.add_argument("--only-recorded", action="store_true", help="the recorded-session rows only")
    modes.add_argument("--update-parts", action="store_true",
                       help="what each part of update() costs on the recorded session (--recorded-rounds passes)")
    modes.add_argument("--one-thread-kernels", action="store_true",
                       help="each two-thread kernel on one numba thread against its one-thread kernel")
    modes.add_argument("--baseline", metavar="REF", default=None,
                       help="a git ref whose rgbd_envmap is timed against the current one: update() on the recorded "
                            "session, then translation (with --only-translation: translation only)")
    parser.add_argument("--only-translation", action="store_true",
                        help="the translation rows only, for the recorded session's final map and the true map")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if args.only_translation and (args.only_recorded or args.update_parts or args.one_thread_kernels):
        parser.error("--only-translation goes alone or with --baseline")

    threads = 1 if args.one_thread_kernels else max(1, args.threads)
    configure_threading_layer()  # the library's choice of threading layer, before numba starts it
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    threads = numba.get_num_threads()
    t_rounds = args.translation_rounds or max(5, args.repeats // 5)
    rows: dict = {}

    def done(out=rows) -> None:
        if args.json:
            args.json.write_text(json.dumps(out, indent=2) + "\n")

    if args.one_thread_kernels:
        table = one_thread_kernels(args.recorded, max(3, args.recorded_rounds), max(21, args.translation_rounds or 21),
                                   make_sim())
        if table:
            print_kernel_table(table)
            done(table)
        return
    if args.update_parts:
        update_parts(args.recorded, max(1, args.recorded_rounds), rows, threads)
    elif args.only_recorded:
        recorded_session(args.recorded, rows, max(1, args.recorded_rounds), threads)
    elif args.baseline:
        base = Baseline(load_baseline(args.baseline))
        maps = {}
        if args.only_translation:
            final = replay_capture(args.recorded, threads)
        else:
            final = update_against_baseline(args.recorded, base, max(1, args.recorded_rounds), rows, threads)
        if final is not None:
            maps["recorded session's final map"] = final
        maps["true map"] = true_map(make_sim())
        translations_against_baseline(maps, base, t_rounds, rows, threads)
    elif args.only_translation:
        maps = {}
        final = replay_capture(args.recorded, threads)
        if final is not None:
            maps["recorded session's final map"] = final
        else:
            _no_session(args.recorded)
        maps["true map"] = true_map(make_sim())
        translations(maps, t_rounds, rows, threads, gardner=False)
    else:
        sim = make_sim()
        frames = [res for _, res in ingested_frames(sim, 4.2)]
        maps = {"4.2 s map": one_frame(sim, frames, args.repeats, rows, threads)}
        if args.recorded_rounds > 0:
            final = recorded_session(args.recorded, rows, args.recorded_rounds, threads)
            if final is not None:
                maps["recorded session's final map"] = final
        maps["true map"] = true_map(sim)
        translations(maps, t_rounds, rows, threads)
    if rows:
        print_rows(rows)
    done()


if __name__ == "__main__":
    main()
