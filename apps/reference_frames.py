"""Reference composites of a simulated run: the ground truth of what the pipeline draws.

For chosen colour frames (in each window of ``every_s`` seconds from ``every_s`` on, the first
composited frame whose camera sees the virtual object: its bounding box projects into the image from
in front; a window in which the camera never faces the object gives no frame) the recorder keeps
the pipeline's composite, the frame's true pose and its true camera gains. When the session ends it renders each of those views twice
(:func:`sim.reference.render_reference_pair`): the real scene with the virtual object inserted (the
pipeline's mesh, at the pipeline's position, with its diffuse albedo) and without it, in linear
radiance before the camera's exposure, white balance and noise. The composite is brought into the
same space by decoding its sRGB codes and dividing by the frame's true gains, and compared where
the reference is valid: a path-traced pixel that meets a surface and that the camera does not clip
(reference × gains < :data:`CLIP_LEVEL` in every channel, with and without the object).
The default method ("gather") takes the frame without the object from the bake and traces only what
the object changes; "path" path-traces both (see :func:`sim.reference.render_reference_pair`).

:func:`rgbd_envmap.metrics.composite_errors` gives the object, shadow and combined errors per frame;
``accuracy.json`` gets them pooled over the frames (squared errors and squared references summed
over all frames' regions), as ``composite_object_rel_rmse``, ``composite_shadow_rel_rmse`` and
``composite_rel_rmse`` (null where no frame had such pixels), with ``composite_reference_noise_rel`` (the reference's own relative
standard error over the same pixels: the floor under which an error cannot be told from noise; per region
``composite_object_reference_noise_rel``, ``composite_shadow_reference_noise_rel``). ``*_rel_rmse_noise_corrected`` are the
same errors with the reference's noise taken out: √(max(Σ (ours − ref)² − Σ σ², 0) / Σ ref²), σ each pixel's standard error
(the expected squared difference is the squared error against the truth plus σ² when the reference is unbiased and its noise
independent of ours): an estimate of the error against the noise-free truth.

Written under ``DIR/reference/``: per frame ``<timestamp>.npz`` (``with_object``, ``without_object``
and ``ours`` as float16 linear radiance, the masks ``object_mask``, ``shadow_mask``, ``valid``,
``traced``, and ``gains``, ``T_world_from_colour``, ``t_s``, ``spp``) and ``<timestamp>.png``
(reference | ours | error, the references shown as the camera would have seen them), and
``frames.csv`` with each frame's figures.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rgbd_envmap.checks import check_method, check_number
from rgbd_envmap.colour import linear_to_srgb, srgb8_to_linear_lut
from rgbd_envmap.metrics import composite_errors

__all__ = ["ReferenceOptions", "ReferenceRecorder", "CLIP_LEVEL", "object_in_view"]

#: a reference pixel whose camera value (radiance × gains) reaches this in any channel is not compared:
#: the camera clips it (at 1), and so does the composite.
CLIP_LEVEL = 0.98


@dataclass(frozen=True)
class ReferenceOptions:
    """``every_s``: seconds between reference frames (0: none). ``method``: "gather" (the bake plus
    the object's change, traced) or "path" (both frames path-traced): :func:`sim.reference.render_reference_pair`.
    ``spp``: per pixel of the region, directions towards the object (gather) or paths (path);
    ``object_spp``: paths per object pixel (gather). ``radius_m``: the region around the object
    (None: the whole frame)."""

    every_s: float = 5.0
    method: str = "gather"
    spp: int = 64
    object_spp: int = 256
    radius_m: float | None = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        check_number(self.every_s, "reference.every_s", low=0.0)
        check_method(self.method, ("gather", "path"), "reference.method")
        check_number(self.spp, "reference.spp", low=2, high=1 << 16, integer=True)
        check_number(self.object_spp, "reference.object_spp", low=2, high=1 << 16, integer=True)
        if self.radius_m is not None:
            check_number(self.radius_m, "reference.radius_m", low=0.0, low_open=True, high=100.0)

    @property
    def enabled(self) -> bool:
        return self.every_s > 0


@dataclass(frozen=True)
class _Frame:
    timestamp_ns: int
    t_s: float
    pose: object  # RigidTransform, T_world_from_colour (true)
    gains: np.ndarray
    image: np.ndarray  # (H, W, 3) uint8 sRGB composite
    object_base: np.ndarray


class ReferenceRecorder:
    """Collects the chosen frames during a run (:meth:`on_colour`, :meth:`on_step`) and renders and
    scores them at its end (:meth:`finish`)."""

    def __init__(self, scene, raycaster, intrinsics, options: ReferenceOptions = ReferenceOptions()) -> None:
        self.scene = scene
        self.raycaster = raycaster
        self.intrinsics = intrinsics
        self.options = options
        self._next_t = options.every_s
        self._pending: dict[int, tuple[float, object, np.ndarray]] = {}
        self.frames: list[_Frame] = []

    def on_colour(self, timestamp_ns: int, groundtruth: dict) -> None:
        """A colour packet went in; ``groundtruth`` holds its ``t_s``, ``true_pose`` and ``gains``.
        Every colour frame of an open window is a candidate until one shows the object."""
        t = groundtruth.get("t_s")
        if not self.options.enabled or t is None or t + 1e-9 < self._next_t:
            return
        self._pending[int(timestamp_ns)] = (float(t), groundtruth["true_pose"], np.asarray(groundtruth["gains"], np.float64))
        while len(self._pending) > 64:  # candidates whose frame never came out (dropped): forget the oldest
            del self._pending[next(iter(self._pending))]

    def on_step(self, step, pipeline) -> None:
        """A composited frame came out of ``pipeline``; keep it if it is a candidate that shows the
        object, and close its window."""
        chosen = self._pending.pop(int(step.timestamp_ns), None)
        if chosen is None or step.image is None or pipeline.virtual_object is None:
            return
        t, pose, gains = chosen
        if t + 1e-9 < self._next_t:  # its window was closed by an earlier frame
            return
        base = np.array(pipeline.object_base, np.float64)
        if not object_in_view(np.asarray(pipeline.virtual_object.vertices, np.float64) + base, pose, self.intrinsics):
            return
        while self._next_t <= t + 1e-9:
            self._next_t += self.options.every_s
        self.frames.append(_Frame(int(step.timestamp_ns), t, pose, gains, np.array(step.image), base))

    def finish(self, pipeline, out: Path) -> tuple[dict, dict]:
        """Render and score the kept frames; write ``out/reference/``. Returns (metrics for
        accuracy.json, facts for run.json)."""
        from sim.mitsuba_scene import ExtraMesh
        from sim.reference import render_reference_pair

        if not self.frames:
            return {}, {"reference_frames": 0}
        folder = Path(out) / "reference"
        folder.mkdir(parents=True, exist_ok=True)
        obj = pipeline.virtual_object
        lut = srgb8_to_linear_lut()
        sums = {k: [0.0, 0.0] for k in ("object", "shadow", "all")}
        noise2 = {k: 0.0 for k in sums}
        rows, seconds = [], []
        for f in self.frames:
            mesh = ExtraMesh(obj.name, np.asarray(obj.vertices, np.float64) + f.object_base, obj.faces, obj.albedo)
            pair = render_reference_pair(self.scene, f.pose, self.intrinsics, f.t_s, mesh, spp=self.options.spp,
                                         radius_m=self.options.radius_m, raycaster=self.raycaster,
                                         seed=self.options.seed + len(rows), method=self.options.method,
                                         object_spp=self.options.object_spp)
            seconds.append(pair.seconds)
            ours = lut[f.image] / f.gains
            unclipped = ((pair.with_object * f.gains).max(-1) < CLIP_LEVEL) & \
                        ((pair.without_object * f.gains).max(-1) < CLIP_LEVEL)
            valid = pair.traced & pair.hit & unclipped
            e = composite_errors(ours, pair.with_object, pair.without_object, pair.object_mask, valid)
            regions = {"object": pair.object_mask & valid, "shadow": e["shadow_mask"]}
            regions["all"] = regions["object"] | regions["shadow"]
            for k, m in regions.items():
                sums[k][0] += float(np.sum((ours[m] - pair.with_object[m]) ** 2))
                sums[k][1] += float(np.sum(pair.with_object[m].astype(np.float64) ** 2))
            for k, m in regions.items():
                noise2[k] += float(np.sum(pair.noise_with[m].astype(np.float64) ** 2))
            rows.append({"timestamp_ns": f.timestamp_ns, "t_s": f.t_s, "object_pixels": e["object_pixels"],
                         "shadow_pixels": e["shadow_pixels"], "object_rel_rmse": e["object_rel_rmse"],
                         "shadow_rel_rmse": e["shadow_rel_rmse"], "rel_rmse": e["rel_rmse"],
                         "traced_fraction": float(pair.traced.mean()), "render_s": pair.seconds})
            np.savez_compressed(
                folder / f"{f.timestamp_ns}.npz", with_object=pair.with_object.astype(np.float16),
                without_object=pair.without_object.astype(np.float16), ours=ours.astype(np.float16),
                object_mask=pair.object_mask, shadow_mask=e["shadow_mask"], valid=valid, traced=pair.traced,
                gains=f.gains, T_world_from_colour=f.pose.matrix, t_s=np.float64(f.t_s), spp=np.int64(pair.spp))
            _write_sheet(folder / f"{f.timestamp_ns}.png", pair, ours, f, regions["all"])
        with open(folder / "frames.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            for r in rows:
                w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})

        def pooled(k: str) -> float | None:  # None (JSON null) for a region no frame had
            num, den = sums[k]
            return math.sqrt(num / den) if den > 0 else None

        def noise(k: str) -> float | None:
            return math.sqrt(noise2[k] / sums[k][1]) if sums[k][1] > 0 else None

        def corrected(k: str) -> float | None:
            # E[(ours − ref)²] = (ours − truth)² + σ² for a reference unbiased with standard error σ
            # independent of ours: the error against the truth, the reference's own noise taken out
            num, den = sums[k]
            return math.sqrt(max(num - noise2[k], 0.0) / den) if den > 0 else None

        metrics = {
            "composite_rel_rmse": pooled("all"),
            "composite_object_rel_rmse": pooled("object"),
            "composite_shadow_rel_rmse": pooled("shadow"),
            "composite_reference_noise_rel": noise("all"),
            "composite_object_reference_noise_rel": noise("object"),
            "composite_shadow_reference_noise_rel": noise("shadow"),
            "composite_rel_rmse_noise_corrected": corrected("all"),
            "composite_object_rel_rmse_noise_corrected": corrected("object"),
            "composite_shadow_rel_rmse_noise_corrected": corrected("shadow"),
            "composite_reference_frames": len(rows),
            "composite_object_pixels": int(sum(r["object_pixels"] for r in rows)),
            "composite_shadow_pixels": int(sum(r["shadow_pixels"] for r in rows)),
        }
        facts = {"reference_frames": len(rows), "reference_method": self.options.method,
                 "reference_spp": self.options.spp, "reference_object_spp": self.options.object_spp,
                 "reference_radius_m": self.options.radius_m, "reference_render_s": float(np.sum(seconds))}
        return metrics, facts


def object_in_view(vertices: np.ndarray, T_world_from_cam, intrinsics) -> bool:
    """The object's bounding-box centre is in front of the camera and its box, projected through the
    pinhole (distortion left out: a margin of a few pixels), overlaps the image."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    cam = T_world_from_cam.inverse().apply(np.vstack([corners, 0.5 * (lo + hi)]))
    if cam[-1, 2] <= 0.0:
        return False
    front = cam[:-1][cam[:-1, 2] > 1e-6]
    u = intrinsics.fx * front[:, 0] / front[:, 2] + intrinsics.cx
    v = intrinsics.fy * front[:, 1] / front[:, 2] + intrinsics.cy
    return bool(u.max() >= 0 and u.min() <= intrinsics.width - 1 and v.max() >= 0 and v.min() <= intrinsics.height - 1)


def _camera_view(radiance: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """What the camera would have recorded, noise-free: radiance × gains, clipped, sRGB, 8 bit."""
    return np.round(255.0 * linear_to_srgb(np.clip(radiance * gains, 0.0, 1.0))).astype(np.uint8)


def _write_sheet(path: Path, pair, ours: np.ndarray, frame: _Frame, region: np.ndarray) -> None:
    """reference | ours | |ours − reference| / reference over the compared region (0 … 50 %, inferno)."""
    ref_img = _camera_view(pair.with_object, frame.gains)
    rel = np.linalg.norm(ours - pair.with_object, axis=-1) / np.maximum(np.linalg.norm(pair.with_object, axis=-1), 1e-6)
    heat = cv2.applyColorMap(np.round(255 * np.clip(rel / 0.5, 0, 1)).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1]
    heat = np.where(region[..., None], heat, (0.25 * ref_img).astype(np.uint8))
    sheet = np.concatenate([ref_img, frame.image, heat], axis=1)
    if not cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
        raise OSError(f"{path}: could not write PNG")
