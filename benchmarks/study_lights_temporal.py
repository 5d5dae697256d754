"""How the light samplers behave over time: lag after the lamp dims, flicker while nothing changes.

    python benchmarks/study_lights_temporal.py [--duration 20] [--counts 16,64] [--map-size 1000x500]
                                               [--colour-size 480x270] [--seed 0] [--json PATH]

One simulated session of the default scene (the lit office: the box goes at 6 s, the ceiling lamp
dims to 40 % at 8 s) runs through the pipeline; after every depth frame each method
(``pharr``, ``hemigon`` with its state, ``q2tree`` with its state, ``val`` with its warm-started
cluster centres) samples ``--counts`` lights from
two maps at the object position:

- the **true** map at that frame's time (rendered by the simulator; it changes only at the scene's
  steps): what the sampler itself adds, since its input changes exactly at 6 s and 8 s;
- the **captured** map, as the pipeline holds it after the frame: what a user of the pipeline sees,
  capture lag included (the map learns that the lamp dimmed only when the camera sees it again).

Per method, count and map, printed and written with ``--json``:

- ``lag_frames``: depth frames after the dimming until the lights' irradiance on an upward surface
  (the table's normal) has made 90 % of its final change (the mean over the last 10 frames), moving
  towards it; the true map's own irradiance makes all of it at the first frame after 8 s;
- ``drop``: that final change, relative (the true map's is the lamp's share of the upward light);
- ``flicker_dir_deg``: the frame-to-frame movement of the lights, the power-weighted mean angle from
  each light to the nearest light of the previous frame (median over the frames of a quiet span);
- ``flicker_irr``: the frame-to-frame relative change of the lights' irradiance over 26 normals
  (median over the quiet span);
- ``irr_error``: the relative error of the lights' irradiance against the brute-force cosine
  convolution of the same map (median over all frames), which tells lag and flicker from bias.

The quiet span is the true map's 10 s to the end (no scene step; the captured map still grows as the
camera explores, which is part of what a user sees as flicker). Results: docs/studies/lights_temporal.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from apps.process import configure_process  # noqa: E402

METHODS = ("pharr", "hemigon", "q2tree", "val")
UP = np.array([0.0, 0.0, 1.0])


def _normals() -> np.ndarray:
    """26 unit normals: the faces, edges and corners of a cube."""
    g = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)], float)
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def brute_irradiance(radiance: np.ndarray, valid: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, 3) Σ_pixels L cos⁺ Δω over the valid pixels: the clamped-cosine convolution of the map."""
    from rgbd_envmap.geometry import equirect_directions, equirect_solid_angles

    h, w = valid.shape
    d = equirect_directions(h, w).reshape(-1, 3)
    dw = equirect_solid_angles(h, w).reshape(-1)
    ok = valid.reshape(-1)
    L = radiance.reshape(-1, 3)[ok].astype(np.float64) * dw[ok, None]
    return np.maximum(normals @ d[ok].T, 0.0) @ L


def _dir_change(prev, cur) -> float:
    """Power-weighted mean angle (degrees) from each light of ``cur`` to the nearest of ``prev``."""
    cos = np.clip(cur.directions @ prev.directions.T, -1.0, 1.0).max(axis=1)
    wgt = cur.power.sum(axis=1)
    return float(np.degrees(np.arccos(cos)) @ wgt / max(wgt.sum(), 1e-30))


def _lag(t: np.ndarray, e_up: np.ndarray, t_step: float) -> int | None:
    """Frames after ``t_step`` until 90 % of the change from the last frame before it to the mean of
    the last 10 frames is made (None: never, or no change)."""
    before = np.flatnonzero(t < t_step)
    after = np.flatnonzero(t >= t_step)
    if not len(before) or len(after) < 10:
        return None
    e0, e1 = e_up[before[-1]], e_up[-10:].mean()
    if abs(e1 - e0) < 1e-3 * max(abs(e0), 1e-12):
        return None
    # towards the final value: a move the other way first (the map still learning the bright lamp
    # from a bracket) does not count
    done = np.flatnonzero((e_up[after] - e0) * np.sign(e1 - e0) >= 0.9 * abs(e1 - e0))
    return int(done[0]) + 1 if len(done) else None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--counts", default="16,64")
    ap.add_argument("--map-size", default="1000x500", help="WIDTHxHEIGHT of the captured and true maps")
    ap.add_argument("--colour-size", default="480x270")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    configure_process()

    import dataclasses

    from rgbd_envmap.lights import AreaLightState, HemigonState, Q2TreeState, irradiance, sample_lights
    from rgbd_envmap.pipeline import DepthStep, Pipeline, PipelineConfig
    from sim.colour_camera import ColourCameraConfig
    from sim.device import TangoDeviceConfig
    from sim.groundtruth import render_envmap
    from sim.scene import load_scene
    from sim.session import Simulator
    from sim.trajectory import load_trajectory

    mw, mh = (int(v) for v in args.map_size.lower().split("x"))
    cw, ch = (int(v) for v in args.colour_size.lower().split("x"))
    counts = [int(v) for v in args.counts.split(",")]
    scene = load_scene("office")
    sim = Simulator(scene, load_trajectory(scene.default_trajectory),
                    TangoDeviceConfig(colour=ColourCameraConfig(width=cw, height=ch)), seed=args.seed)
    origin = np.asarray(scene.virtual_object_position, np.float64)
    base = PipelineConfig()
    config = dataclasses.replace(base, capture=dataclasses.replace(base.capture, height=mh, width=mw),
                                 render=dataclasses.replace(base.render, enabled=False))
    steps = sorted({0.0, *scene.change_times(), *(t for o in scene.objects for t, _ in o.scale_steps)})
    dim_t = min(t for o in scene.objects for t, s in o.scale_steps if s < 1.0)
    truth = {}

    def true_map(t: float):
        key = max(s for s in steps if s <= t + 1e-9)
        if key not in truth:
            truth[key] = render_envmap(sim.raycaster, origin, mh, mw, key + 1e-3)
        return truth[key]

    normals = _normals()
    series = {(src, m, n): {"t": [], "e_up": [], "flicker_dir": [], "flicker_irr": [], "irr_err": [], "ms": []}
              for src in ("true", "captured") for m in METHODS for n in counts}
    kinds = {"hemigon": HemigonState, "q2tree": Q2TreeState, "val": AreaLightState}
    states = {k: kinds[k[1]]() if k[1] in kinds else None for k in series}
    previous = {}
    t0 = time.perf_counter()
    with Pipeline(config, sim.calibration, origin) as pipe:
        for sp in sim.run(args.duration):
            for step in pipe.feed(sp.packet):
                if not isinstance(step, DepthStep):
                    continue
                t = (step.timestamp_ns - sim.start_ns) * 1e-9
                em = pipe.capture.em
                gt = true_map(t)
                # the correction matrix can leave small negative values in a captured colour: clamped,
                # as the pipeline's own light split does
                maps = {"captured": (np.maximum(em.radiance, 0.0), em.valid.copy(), em.depth_m.copy()),
                        "true": (gt.radiance, gt.valid, gt.distance_m)}
                if not maps["captured"][1].any():
                    continue
                exact = {src: brute_irradiance(r, v, normals) for src, (r, v, _) in maps.items()}
                for key, s in series.items():
                    src, m, n = key
                    rad, valid, depth = maps[src]
                    c0 = time.perf_counter()
                    lights = sample_lights(rad, n, m, valid, depth_m=np.where(valid, depth, 1.0), origin=origin,
                                           state=states[key])
                    s["ms"].append((time.perf_counter() - c0) * 1e3)
                    e = irradiance(lights, normals)
                    ref = exact[src]
                    s["t"].append(t)
                    s["e_up"].append(float(irradiance(lights, UP[None])[0].sum()))
                    s["irr_err"].append(float(np.linalg.norm(e - ref) / max(np.linalg.norm(ref), 1e-30)))
                    if key in previous:
                        p_lights, p_e = previous[key]
                        s["flicker_dir"].append(_dir_change(p_lights, lights))
                        s["flicker_irr"].append(float(np.linalg.norm(e - p_e) / max(np.linalg.norm(p_e), 1e-30)))
                    else:
                        s["flicker_dir"].append(np.nan)
                        s["flicker_irr"].append(np.nan)
                    previous[key] = (lights, e)
        pipe.finish()
    print(f"session and sampling: {time.perf_counter() - t0:.0f} s", flush=True)

    rows = {}
    print(f"{'map':<9} {'method':<8} {'n':>5} {'lag frames':>10} {'drop':>6} {'flicker deg':>11} {'flicker irr':>11} "
          f"{'irr error':>9} {'ms median':>9}")
    for (src, m, n), s in series.items():
        t = np.asarray(s["t"])
        quiet = t >= 10.0
        fd = np.asarray(s["flicker_dir"])[quiet]
        fi = np.asarray(s["flicker_irr"])[quiet]
        e_up = np.asarray(s["e_up"])
        before = np.flatnonzero(t < dim_t)
        drop = float(e_up[-10:].mean() / e_up[before[-1]] - 1.0) if len(before) and e_up[before[-1]] > 0 else None
        row = {"lag_frames": _lag(t, e_up, dim_t), "drop": drop,
               "flicker_dir_deg": float(np.nanmedian(fd)) if np.isfinite(fd).any() else None,
               "flicker_irr": float(np.nanmedian(fi)) if np.isfinite(fi).any() else None,
               "irr_error": float(np.median(s["irr_err"])), "ms_median": float(np.median(s["ms"])),
               "frames": len(t)}
        rows[f"{src}/{m}/{n}"] = row
        fmt = lambda v, f: "–" if v is None else format(v, f)  # noqa: E731
        print(f"{src:<9} {m:<8} {n:>5} {fmt(row['lag_frames'], 'd'):>10} {fmt(row['drop'], '.3f'):>6} "
              f"{fmt(row['flicker_dir_deg'], '.2f'):>11} "
              f"{fmt(row['flicker_irr'], '.4f'):>11} {row['irr_error']:>9.4f} {row['ms_median']:>9.2f}")
    if args.json:
        args.json.write_text(json.dumps({"args": vars(args) | {"json": str(args.json)}, "rows": rows,
                                         "series": {"/".join(map(str, k)): v for k, v in series.items()}}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
