"""``rgbd-envmap sweep``: speed against error over a grid of pipeline settings, on one recorded log.

Each point of the grid replays the log with one setting changed from the defaults — one axis at a
time, so every row differs from its axis's default row in exactly one way. Capture axes replay with
rendering off (row ``default``):

- ``em_size``: 500×250, 1000×500, 1500×750, 2000×1000;
- ``bands``: 1 … 8 SH bands;
- ``hole_filling``: monroy2018 (eq. 1), telea, ip_basic, none;
- ``ccm``: least_squares (the paper's), ridge, Cheung 2004, Finlayson 2015, and correction off;
- ``translation``: the final map moved 10 cm along +x by the depth-aware warp and by Gardner's
  sphere operator, against the map fed the same data at the displaced origin (paper Fig. 9 protocol).

Rendering axes replay with rendering on (no video, one composite PNG), against the row
``render default`` (the render defaults; shared by both axes):

- ``lights``: the differential composite's light sampler (``render.light_method`` val, q2tree,
  pharr, hemigon) × light count (``render.lights`` 12, 48);
- ``composite``: the paper-003 composite; the differential one with the object shaded by its lights
  (``render.object_shading=lights``) instead of PRT; ``render.tau`` 0.1, 0.2, 0.5 and 0.8; the
  receivers' spacing ``render.receiver_spacing_m`` 8, 12 and 16 mm; the light grid's stride
  ``render.light_grid_stride`` 4 and 8 (each axis's default left out).

A rendering point is scored two ways. Against the run's reference frames (``reference/<timestamp>.npz``
of a simulated run, :mod:`apps.reference_frames`) when there are any: the point's composite at each
reference frame's colour timestamp is decoded from sRGB, divided by the frame's true gains and compared
over the reference's stored regions (object, shadow), pooled over the frames as ``simulate`` pools them
into accuracy.json (``composite_rel_rmse``, ``composite_object_rel_rmse``, ``composite_shadow_rel_rmse``);
the default point on the log's own run reproduces ``simulate``'s figures. And without references, for
the differential composite: ``lights_irradiance_rel_error``, the relative RMS over
:data:`IRRADIANCE_NORMALS` directions of the luminance of the irradiance the final lights plus the
indirect SH give, against the brute-force clamped-cosine convolution of the final map (every pixel,
its holes filled as the SH projection fills them), beside ``sh_irradiance_rel_error`` (the whole map's
SH alone against the same).

Points run in parallel over the cores (one process each, spawned), each on one thread (numba's
thread count set to 1, so the map update and the colour pairs take their one-thread kernels, with
the same results; points timed on two threads each would compete for the cores). Writes
``points/<name>/`` (a run folder per point), ``sweep.csv``, ``sweep.md`` (time and error side by
side) and ``pareto.png``.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from rgbd_envmap.errors import InvalidInputError

__all__ = ["SweepPoint", "grid", "run_sweep", "run_point", "AXES", "RENDER_AXES", "ReferenceScorer", "score_composites",
           "brute_force_irradiance", "lights_irradiance_error", "fibonacci_normals", "read_rows", "pareto", "default_reference",
           "IRRADIANCE_NORMALS"]

AXES = ("em_size", "bands", "hole_filling", "ccm", "translation", "lights", "composite")
#: the axes whose points replay with rendering on.
RENDER_AXES = ("lights", "composite")
TRANSLATION_OFFSET_M = (0.10, 0.0, 0.0)
#: normals at which the lights' irradiance is compared with the map's (Fibonacci sphere).
IRRADIANCE_NORMALS = 256
LIGHT_METHODS = ("val", "q2tree", "pharr", "hemigon")
TAUS = (0.1, 0.2, 0.5, 0.8)
#: the receivers' vertex spacing (metres) and the light grid's stride on the composite axis
RECEIVER_SPACINGS_M = (0.008, 0.012, 0.016)
LIGHT_GRID_STRIDES = (4, 8)
LIGHT_COUNTS = (12, 48)


@dataclass(frozen=True)
class SweepPoint:
    axis: str
    name: str
    overrides: tuple[str, ...]
    origin_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: replay with rendering on (the rendering axes).
    render: bool = False


def _render_default_name() -> str:
    from rgbd_envmap.pipeline import PipelineConfig

    rc = PipelineConfig().render
    if rc.composite != "differential":
        return f"render default ({rc.composite})"
    return f"render default ({rc.light_method} {rc.lights}, object {rc.object_shading}, tau {rc.tau:g})"


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
    if any(a in axes for a in RENDER_AXES):
        from rgbd_envmap.pipeline import PipelineConfig

        rc = PipelineConfig().render
        pts.append(SweepPoint("render_default", _render_default_name(), (), render=True))
        differential = rc.composite == "differential"
        if "lights" in axes:
            pts += [SweepPoint("lights", f"lights {m} {n}", ("render.composite=differential", f"render.light_method={m}",
                                                             f"render.lights={n}"), render=True)
                    for m in LIGHT_METHODS for n in LIGHT_COUNTS
                    if not (differential and m == rc.light_method and n == rc.lights)]
        if "composite" in axes:
            other = "paper003" if differential else "differential"
            pts.append(SweepPoint("composite", f"composite {other}", (f"render.composite={other}",), render=True))
            shading = "lights" if rc.object_shading == "prt" else "prt"
            pts.append(SweepPoint("composite", f"composite object {shading}",
                                  ("render.composite=differential", f"render.object_shading={shading}"), render=True))
            pts += [SweepPoint("composite", f"composite tau {t:g}", ("render.composite=differential", f"render.tau={t}"),
                               render=True) for t in TAUS if not (differential and t == rc.tau)]
            pts += [SweepPoint("composite", f"composite receivers {1000 * d:g} mm",
                               ("render.composite=differential", f"render.receiver_spacing_m={d}"), render=True)
                    for d in RECEIVER_SPACINGS_M if not (differential and d == rc.receiver_spacing_m)]
            pts += [SweepPoint("composite", f"composite light grid /{k}",
                               ("render.composite=differential", f"render.light_grid_stride={k}"), render=True)
                    for k in LIGHT_GRID_STRIDES if not (differential and k == rc.light_grid_stride)]
    return pts


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def run_point(log: str | Path, out: str | Path, point: SweepPoint, origin, *, reference: str | Path | None = None,
              base_overrides: tuple[str, ...] | list[str] = ()) -> dict:
    """Replay ``log`` into the run folder ``out`` with ``point``'s settings (after ``base_overrides``,
    applied to every point); returns the point's timing and accuracy. A rendering point is scored
    against the reference frames in ``reference`` (a folder of ``<timestamp>.npz``; None: not scored)
    and, for the differential composite, by ``lights_irradiance_rel_error``."""
    from apps.replay import ReplayOptions, run_replay, source_options
    from apps.report import timing_table
    from apps.run import RunOptions, run_pipeline
    from rgbd_envmap.config import apply_overrides
    from rgbd_envmap.pipeline import COLOUR_TOTAL, DEPTH_TOTAL, Pipeline, PipelineConfig
    from rgbd_envmap.sources.frames import detect_source_layout
    from rgbd_envmap.timing import read_records

    log, out = Path(log), Path(out)
    render = () if point.render else ("render.enabled=false",)
    cfg = apply_overrides(PipelineConfig(), [*base_overrides, *render, *point.overrides])
    o = np.asarray(origin, np.float64) + np.asarray(point.origin_offset)
    # no video; one composite PNG (the first); no progress bar
    opts = ReplayOptions(log, out, origin=tuple(o), config=cfg, video=False, progress=False, composite_every=10**9)
    t0 = time.perf_counter()
    extra_accuracy: dict = {}
    if not point.render:
        run_replay(opts)
    else:
        layout = detect_source_layout(log)
        src = layout.open(log, source_options(opts, layout))
        scorer = ReferenceScorer(reference) if reference is not None else None
        with Pipeline(cfg, src.calibration, o) as pipe:
            run_pipeline(pipe, src.with_truth(), len(src),
                         RunOptions(out, composite_every=opts.composite_every, video=False, progress=False),
                         groundtruth_envmap=src.truth, reference=scorer,
                         extra=lambda: {"source": "sweep", "log": str(log), "sweep_point": point.name, **src.info()})
            extra_accuracy = _lights_metrics(pipe)
    path = out / "accuracy.json"
    acc = json.loads(path.read_text())
    if extra_accuracy:
        acc.update(extra_accuracy)
        path.write_text(json.dumps(acc, indent=2) + "\n")
    table = timing_table(read_records(out / "stage_times.csv"))
    return {"axis": point.axis, "name": point.name, "out": str(out), "wall_s": time.perf_counter() - t0,
            "depth_total_median_ms": table[DEPTH_TOTAL]["median_ms"], "depth_total_p95_ms": table[DEPTH_TOTAL]["p95_ms"],
            "colour_total_median_ms": table[COLOUR_TOTAL]["median_ms"], "colour_total_p95_ms": table[COLOUR_TOTAL]["p95_ms"],
            "stages": {k: v["median_ms"] for k, v in table.items()}, "accuracy": acc}


def _run_point(log: str, out: str, point: SweepPoint, origin: list[float], reference: str | None,
               base_overrides: tuple[str, ...]) -> dict:
    """One point in a worker process."""
    return run_point(log, out, point, origin, reference=reference, base_overrides=base_overrides)


# --- scoring a rendering point ---------------------------------------------------------------------------


class ReferenceScorer:
    """Keeps a replay's composites at the colour timestamps of the reference frames in ``folder``
    (``<timestamp_ns>.npz`` written by :class:`apps.reference_frames.ReferenceRecorder`) and scores them
    at the run's end; the ``reference`` of :func:`apps.run.run_pipeline` (it sees every colour packet
    and composite)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.paths = {int(p.stem): p for p in sorted(self.folder.glob("*.npz")) if p.stem.isdigit()}
        self.images: dict[int, np.ndarray] = {}

    def on_colour(self, timestamp_ns: int, groundtruth: dict) -> None:
        pass

    def on_step(self, step, pipeline) -> None:
        if int(step.timestamp_ns) in self.paths and step.image is not None:
            self.images[int(step.timestamp_ns)] = np.array(step.image)

    def finish(self, pipeline, out: Path) -> tuple[dict, dict]:
        metrics = score_composites(self.images, self.paths)
        return metrics, {"reference_frames": metrics["composite_reference_frames"], "reference_folder": str(self.folder)}


def score_composites(images: dict[int, np.ndarray], references: dict[int, Path]) -> dict:
    """The pooled composite errors of the 8-bit sRGB composites ``images`` (timestamp → (H, W, 3)
    uint8) against the reference frames ``references`` (timestamp → npz path), as
    :meth:`apps.reference_frames.ReferenceRecorder.finish` pools them: the composite in the
    reference's linear space (sRGB decoded, divided by the frame's true ``gains``), over the regions
    the reference stored (``object_mask & valid``, ``shadow_mask``, their union), squared errors and
    squared references summed over all frames. A reference frame without a composite is counted in
    ``composite_reference_missing``; a region no frame had gives None."""
    from rgbd_envmap.colour import srgb8_to_linear_lut

    lut = srgb8_to_linear_lut()
    sums = {k: [0.0, 0.0] for k in ("object", "shadow", "all")}
    pixels = {"object": 0, "shadow": 0}
    frames = 0
    for ts, path in sorted(references.items()):
        image = images.get(ts)
        if image is None:
            continue
        with np.load(path) as z:
            ref = z["with_object"].astype(np.float64)
            gains = np.asarray(z["gains"], np.float64)
            valid = z["valid"]
            regions = {"object": z["object_mask"] & valid, "shadow": z["shadow_mask"] & valid}
        if image.shape != ref.shape:
            raise InvalidInputError(f"{path}: reference frame of shape {ref.shape}, composite of shape {image.shape}")
        ours = lut[image] / gains
        regions["all"] = regions["object"] | regions["shadow"]
        for k, m in regions.items():
            sums[k][0] += float(np.sum((ours[m] - ref[m]) ** 2))
            sums[k][1] += float(np.sum(ref[m] ** 2))
        pixels["object"] += int(regions["object"].sum())
        pixels["shadow"] += int(regions["shadow"].sum())
        frames += 1

    def pooled(k: str) -> float | None:
        num, den = sums[k]
        return math.sqrt(num / den) if den > 0 else None

    return {"composite_rel_rmse": pooled("all"), "composite_object_rel_rmse": pooled("object"),
            "composite_shadow_rel_rmse": pooled("shadow"), "composite_reference_frames": frames,
            "composite_reference_missing": len(references) - frames,
            "composite_object_pixels": pixels["object"], "composite_shadow_pixels": pixels["shadow"]}


def fibonacci_normals(m: int = IRRADIANCE_NORMALS) -> np.ndarray:
    """(m, 3) unit vectors spread evenly over the sphere (the Fibonacci lattice)."""
    k = np.arange(m) + 0.5
    z = 1.0 - 2.0 * k / m
    phi = np.pi * (1.0 + 5.0 ** 0.5) * k
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def brute_force_irradiance(radiance: np.ndarray, valid: np.ndarray, normals: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
    """(m, 3) float64 E(n) = Σ_p L_p Ω_p max(0, n · d_p) over the valid pixels p of an equirect map
    (``radiance`` (H, W, 3), ``valid`` (H, W) bool), at the (m, 3) unit ``normals``: the clamped-cosine
    convolution of the map, every pixel."""
    from rgbd_envmap.geometry import equirect_directions, equirect_solid_angles

    H, W = valid.shape
    idx = np.flatnonzero(valid)
    d = equirect_directions(H, W).reshape(-1, 3)[idx]
    lw = np.asarray(radiance, np.float64).reshape(-1, 3)[idx] * equirect_solid_angles(H, W).reshape(-1)[idx, None]
    nrm = np.asarray(normals, np.float64)
    out = np.zeros((len(nrm), 3))
    for s in range(0, len(idx), chunk):
        out += np.maximum(nrm @ d[s:s + chunk].T.astype(np.float64), 0.0) @ lw[s:s + chunk]
    return out


#: Rec. 709 luminance weights.
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def lights_irradiance_error(lights, coeffs: np.ndarray, radiance: np.ndarray, valid: np.ndarray,
                            normals: np.ndarray | None = None, *, truth: np.ndarray | None = None) -> float:
    """Relative RMS over ``normals`` (default :func:`fibonacci_normals`) of the luminance of the
    irradiance that ``lights`` (a :class:`rgbd_envmap.lights.LightSet`, as directional lights from the
    map's origin, or None) plus the SH ``coeffs`` ((n², 3) radiance coefficients) give, against
    ``truth`` ((m, 3) irradiance at the normals; default :func:`brute_force_irradiance` of the map,
    negative radiance counted as 0, as the light sampler sees it)."""
    from rgbd_envmap import sh
    from rgbd_envmap.lights import irradiance

    nrm = fibonacci_normals() if normals is None else np.asarray(normals, np.float64)
    if truth is None:
        truth = brute_force_irradiance(np.maximum(radiance, 0.0), valid, nrm)
    y = np.asarray(truth, np.float64) @ _LUMA
    got = sh.irradiance(coeffs, nrm)
    if lights is not None and len(lights):
        got = got + irradiance(lights, nrm)
    den = float(np.sqrt(np.mean(y ** 2)))
    return float(np.sqrt(np.mean((got @ _LUMA - y) ** 2)) / den) if den > 0 else math.nan


def _lights_metrics(pipe) -> dict:
    """Of a differential pipeline at its end (nothing for the paper-003 composite, which has no
    lights): ``lights_irradiance_rel_error``, the final lights + indirect SH against the brute-force
    convolution of the final map as its SH sees it (missing pixels filled as the SH projection fills
    them, :func:`rgbd_envmap.sh.fill_missing`); ``sh_irradiance_rel_error``, the whole map's SH alone
    (no lights) against the same; ``lights_count``."""
    from rgbd_envmap import sh

    coeffs = getattr(pipe, "coeffs_indirect", None)
    if pipe.config.render.composite != "differential" or coeffs is None:
        return {}
    em = pipe.capture.em
    filled, used = sh.fill_missing(np.where(em.valid[..., None], em.radiance, 0.0), em.valid)
    nrm = fibonacci_normals()
    truth = brute_force_irradiance(np.maximum(filled, 0.0), used, nrm)
    n = pipe.bands * pipe.bands
    return {"lights_irradiance_rel_error": lights_irradiance_error(pipe.lights, coeffs[:n], filled, used, nrm, truth=truth),
            "sh_irradiance_rel_error": lights_irradiance_error(None, pipe.coeffs[:n], filled, used, nrm, truth=truth),
            "lights_count": 0 if pipe.lights is None else len(pipe.lights)}


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


#: the error shown for each axis (first found in the point's accuracy) and the stage whose time it trades
#: (``depth_frame_total``: the depth frame's total, where the relight of the rendering axes runs).
AXIS_METRIC = {
    "default": ("em_ws_psnr_db", None), "em_size": ("em_ws_psnr_db", "Project sample to EM*"),
    "bands": ("irradiance_rel_error_vs_true", "Calculate SH coefficients*"),
    "hole_filling": ("em_coverage", "Hole filling RGB-D"),
    "ccm": ("em_ws_psnr_db", "Compute colour correction matrix"),
    "translation": ("translation_sphere_correlation", "EM translation"),
    "render_default": ("composite_rel_rmse", None),
    "lights": ("lights_irradiance_rel_error", "Lights from the map"),
    "composite": ("composite_rel_rmse", "depth_frame_total"),
}
#: the plot's panels: (axis, error, stage), the rendering axes' composite error against the depth frame too.
PANELS = tuple((a, *AXIS_METRIC[a]) for a in AXES[:5]) + (
    ("lights", "lights_irradiance_rel_error", "Lights from the map"), ("lights", "composite_rel_rmse", "depth_frame_total"),
    ("composite", "composite_rel_rmse", "depth_frame_total"))
COLUMNS = ("em_coverage", "em_ws_psnr_db", "hole_filling_depth_mae_m", "ccm_matrix_rel_error_median",
           "sh_coeff_rel_error", "irradiance_rel_error_mean", "irradiance_rel_error_vs_true", "translation_sphere_correlation", "translation_coverage")
#: the rendering axes' stages (median ms each) and errors.
RENDER_STAGES = ("Lights from the map", "Receiver geometry", "Shade receivers", "Shade object (PRT)", "Rasterise", "Composite")
RENDER_COLUMNS = ("lights_count", "lights_irradiance_rel_error", "sh_irradiance_rel_error", "composite_rel_rmse", "composite_object_rel_rmse",
                  "composite_shadow_rel_rmse", "composite_reference_frames")
_CSV_HEAD = ("axis", "setting", "depth_frame_total_median_ms", "depth_frame_total_p95_ms", "axis_stage", "axis_stage_median_ms",
             *COLUMNS, "colour_frame_total_median_ms", "colour_frame_total_p95_ms",
             *(f"{s} median_ms" for s in RENDER_STAGES), *RENDER_COLUMNS)


def _is_render(row: dict) -> bool:
    return row["axis"] in (*RENDER_AXES, "render_default")


def _fmt(v) -> str:
    return "—" if v is None or v == "" or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.4g}"


def _stage_ms(row: dict, stage: str | None) -> float:
    if stage is None:
        return math.nan
    if stage == "depth_frame_total":
        return row["depth_total_median_ms"]
    v = row["stages"].get(stage)
    return math.nan if v is None else v


def _write_outputs(out: Path, rows: list[dict], *, reference: str | None = None, noise_floor: float | None = None) -> Path:
    with open(out / "sweep.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(_CSV_HEAD)
        for r in rows:
            stage = AXIS_METRIC[r["axis"]][1]
            w.writerow([r["axis"], r["name"], r["depth_total_median_ms"], r["depth_total_p95_ms"], stage or "",
                        _stage_ms(r, stage) if stage else "", *(r["accuracy"].get(c, "") for c in COLUMNS),
                        r.get("colour_total_median_ms", ""), r.get("colour_total_p95_ms", ""),
                        *(r["stages"].get(s, "") if _is_render(r) else "" for s in RENDER_STAGES),
                        *(r["accuracy"].get(c, "") for c in RENDER_COLUMNS)])
    capture = [r for r in rows if not _is_render(r)]
    render = [r for r in rows if _is_render(r)]
    lines = ["# Speed against error", ""]
    if capture:
        lines += ["One axis changed at a time from the defaults (row `default`); times are medians on this machine, "
                  "errors are against the simulator's ground truth (accuracy.json of each point under points/).", "",
                  "| axis | setting | depth frame ms (median / p95) | stage ms (median) | " + " | ".join(COLUMNS) + " |",
                  "|---|---|---:|---:|" + "---:|" * len(COLUMNS)]
        for r in capture:
            stage = AXIS_METRIC[r["axis"]][1]
            st = f"{stage}: {_fmt(r['stages'].get(stage))}" if stage else ""
            lines.append(f"| {r['axis']} | {r['name']} | {_fmt(r['depth_total_median_ms'])} / {_fmt(r['depth_total_p95_ms'])} | {st} | "
                         + " | ".join(_fmt(r["accuracy"].get(c)) for c in COLUMNS) + " |")
        lines.append("")
    if render:
        where = (f"the reference frames in `{reference}`" if reference else "no reference frames (composite errors —)")
        floor = f"; the references' own noise, relative: {noise_floor:.3g}" if noise_floor is not None else ""
        lines += ["## Rendering axes", "",
                  "Rendering on (no video), one setting changed from the render defaults (row `render default`). "
                  "The relight (lights, receivers, shading) runs in the depth frame; rasterise and composite in each "
                  "colour frame. `lights_irradiance_rel_error`: the final lights + indirect SH against the brute-force "
                  f"cosine convolution of the final map at {IRRADIANCE_NORMALS} normals (luminance, relative RMS); "
                  f"composite errors pooled over {where}{floor}.", "",
                  "| axis | setting | depth frame ms (median / p95) | colour frame ms (median / p95) | "
                  + " | ".join(f"{s} ms" for s in RENDER_STAGES) + " | " + " | ".join(RENDER_COLUMNS) + " |",
                  "|---|---|---:|---:|" + "---:|" * (len(RENDER_STAGES) + len(RENDER_COLUMNS))]
        for r in render:
            lines.append(f"| {r['axis']} | {r['name']} | {_fmt(r['depth_total_median_ms'])} / {_fmt(r['depth_total_p95_ms'])} | "
                         f"{_fmt(r.get('colour_total_median_ms'))} / {_fmt(r.get('colour_total_p95_ms'))} | "
                         + " | ".join(_fmt(r["stages"].get(s)) for s in RENDER_STAGES) + " | "
                         + " | ".join(_fmt(r["accuracy"].get(c)) for c in RENDER_COLUMNS) + " |")
        lines.append("")
    lines += ["![Pareto plot](pareto.png)", ""]
    (out / "sweep.md").write_text("\n".join(lines))
    pareto(out / "pareto.png", rows)
    return out / "sweep.md"


def read_rows(path: str | Path) -> list[dict]:
    """The rows of a ``sweep.csv`` (this version's or the earlier one without the rendering columns),
    in the form :func:`pareto` plots: stage medians under ``stages``, errors under ``accuracy``."""
    def num(v: str | None):
        if v is None or v == "":
            return None
        try:
            return float(v)
        except ValueError:
            return v

    rows = []
    with open(path, newline="") as f:
        for rec in csv.DictReader(f):
            stages = {s: num(rec.get(f"{s} median_ms")) for s in RENDER_STAGES if num(rec.get(f"{s} median_ms")) is not None}
            if rec.get("axis_stage") and rec["axis_stage"] != "depth_frame_total":
                stages[rec["axis_stage"]] = num(rec["axis_stage_median_ms"])
            nan = float("nan")
            rows.append({"axis": rec["axis"], "name": rec["setting"],
                         "depth_total_median_ms": num(rec["depth_frame_total_median_ms"]) or nan,
                         "depth_total_p95_ms": num(rec["depth_frame_total_p95_ms"]) or nan,
                         "colour_total_median_ms": num(rec.get("colour_frame_total_median_ms")),
                         "colour_total_p95_ms": num(rec.get("colour_frame_total_p95_ms")), "stages": stages,
                         "accuracy": {c: num(rec.get(c)) for c in (*COLUMNS, *RENDER_COLUMNS) if num(rec.get(c)) is not None}})
    return rows


def pareto(path: str | Path, rows: list[dict]) -> None:
    """One panel per axis present in ``rows`` (two for ``lights``): each point's error against the
    time of the stage it trades, the axis's default row beside its points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [p for p in PANELS if any(r["axis"] == p[0] for r in rows)]
    n = max(len(panels), 1)
    ncols = min(n, 4)
    nrows = -(-n // ncols)
    fig, axs = plt.subplots(nrows, ncols, figsize=(4.2 * ncols, 3.8 * nrows), squeeze=False)
    default = next((r for r in rows if r["axis"] == "default"), None)
    render_default = next((r for r in rows if r["axis"] == "render_default"), None)
    for ax, (axis, metric, stage) in zip(axs.ravel(), panels):
        pts = [r for r in rows if r["axis"] == axis and r["name"] != "displaced origin (truth)"]
        base = render_default if axis in RENDER_AXES else (None if axis == "translation" else default)
        if base is not None:
            pts = [base, *pts]
        xs = [_stage_ms(r, stage) for r in pts]
        ys = [r["accuracy"].get(metric) for r in pts]
        ys = [math.nan if y is None else y for y in ys]
        ax.plot(xs, ys, "o")
        for x, y, r in zip(xs, ys, pts):
            label = "default" if r["axis"] in ("default", "render_default") else r["name"]
            for prefix in ("translate 10 cm: ", "lights ", "composite "):
                label = label.removeprefix(prefix)
            ax.annotate(label, (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel(f"{'depth frame total' if stage == 'depth_frame_total' else stage} median ms")
        ax.set_ylabel(metric)
        ax.set_title(axis)
        ax.grid(alpha=0.3)
    for ax in axs.ravel()[len(panels):]:
        ax.set_visible(False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _one_thread() -> None:
    """A sweep worker's initialiser: numba's parallel kernels on one thread."""
    import numba

    numba.set_num_threads(1)


def default_reference(log: str | Path) -> Path | None:
    """``LOG/../reference`` (a simulated run's reference frames) if it holds any, else None."""
    folder = Path(log).resolve().parent / "reference"
    return folder if folder.is_dir() and any(folder.glob("*.npz")) else None


def run_sweep(log: str | Path, out: str | Path, *, jobs: int | None = None, axes: list[str] | None = None,
              progress: bool = True, reference: str | Path | None = "auto", base_overrides: list[str] | tuple = ()) -> Path:
    """Run the grid on ``log``; returns the path of sweep.md. ``reference``: the folder of reference
    frames the rendering points are scored against ("auto": :func:`default_reference`; None: none).
    ``base_overrides``: ``KEY=VALUE`` settings applied to every point before its own."""
    from tqdm import tqdm

    from apps.progress import bar_disable

    from apps.replay import default_origin
    from rgbd_envmap.config import apply_overrides
    from rgbd_envmap.logs import SessionLog
    from rgbd_envmap.pipeline import PipelineConfig

    log, out = Path(log), Path(out)
    base = tuple(base_overrides)
    apply_overrides(PipelineConfig(), list(base))  # a bad setting fails here, not in every worker
    if reference == "auto":
        reference = default_reference(log)
    elif reference is not None:
        reference = Path(reference)
        if not reference.is_dir() or not any(reference.glob("*.npz")):
            raise InvalidInputError(f"reference: expected a folder of reference frames (<timestamp>.npz), got {reference}")
    origin = default_origin(SessionLog.open(log)).tolist()
    points = grid(axes)
    (out / "points").mkdir(parents=True, exist_ok=True)
    jobs = jobs or os.cpu_count() or 1
    results: dict[str, dict] = {}
    ref = None if reference is None else str(reference)
    order = sorted(points, key=lambda p: not p.render)  # the long (rendering) points first
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn"), initializer=_one_thread) as pool:
        futures = {pool.submit(_run_point, str(log), str(out / "points" / _slug(p.name)), p, origin,
                               ref if p.render else None, base): p for p in order}
        for fut in tqdm(as_completed(futures), total=len(futures), desc="sweep", unit="point", disable=bar_disable(progress)):
            results[futures[fut].name] = fut.result()
    rows = [results[p.name] for p in points]
    if "default" in results and "displaced origin (truth)" in results:
        rows = [r for r in rows if r["name"] != "displaced origin (truth)"] + _translation_rows(results["default"], results["displaced origin (truth)"])
    noise = None
    if reference is not None and (reference.parent / "accuracy.json").is_file():
        noise = json.loads((reference.parent / "accuracy.json").read_text()).get("composite_reference_noise_rel")
    return _write_outputs(out, rows, reference=ref, noise_floor=noise)
