"""Where the composite's error comes from: a ladder of composites against the reference composite.

For a few reference frames of a simulated session (the frames the main job scores: the first colour
frame at or after every ``--every`` seconds) the pipeline's composite is compared with the reference
(:func:`sim.reference.render_reference_pair`, method "gather") in linear radiance, as
``apps/reference_frames.py`` does, and so is a ladder of composites that each remove one cause of
error. Each rung is scored with the regions of :func:`rgbd_envmap.metrics.composite_errors`; the
difference between two neighbouring rungs is what that cause costs.

Object pixels (the pixels that see the virtual object in the reference):

  O1  ours: the pipeline's composite (8-bit sRGB decoded, the frame's true gains undone);
  O2  ours, shading only: the pipeline's per-vertex colours (ccm⁻¹, clipped, gains undone)
      interpolated at the reference's object pixels (true pose): O1 − O2 is coverage, pose, 8 bits;
  O3  the captured map (through ccm⁻¹ and the gains into the composite's radiance units) with the
      pixels of the emitters (lamp, window, screens: what an 8-bit camera clips) taken from the true
      map (the simulator's map at the EM origin at the frame's time, the EM's size), SH at the
      pipeline's bands, the pipeline's PRT transfer: O2 − O3 is the emitters' error (clipping);
  O4  the true map: O3 − O4 is the rest of the map's error (holes, geometry, colour, staleness);
  O5  no SH: the same true map integrated per vertex by brute force with the object's
      self-visibility (distant light): O4 − O5 is SH truncation (and PRT quadrature);
  O6  local light: per vertex, the scene's radiance as seen from the vertex itself, not from the EM
      origin (still no light bounced by the object): O5 − O6 is the distant-light assumption;
  O7  O6 per pixel with the interpolated normal: O6 − O7 is the Gouraud interpolation;
  O8  O7 with the triangle's own normal, as the reference's mesh is shaded (Mitsuba, no vertex
      normals): O7 − O8 is the shading-normal convention;
  ref the reference: O8 − ref is the light the object bounces onto itself and back from the room
      (interreflection), plus the reference's own noise (reported, and taken out of the variance).

Shadow pixels (off the object, where the object changes the reference by more than 2 %):

  S1  ours; S2 the same alpha over the reference's background instead of the camera frame (camera
      noise, 8 bits); S3 shadow grey 0 instead of ``render.shadow_grey``; S4 alpha from the SH of the
      captured map with the emitters from the true map; S5 of the true map; S6 alpha by brute force
      on the plane (no SH: the lamp's hard shadow), distant light; S7 the same at the true receiving
      surface point and normal (the plane model); S8 local light, the object a black occluder: the
      background minus the light it hides; ref the reference: S8 − ref is the light the object
      bounces onto its surroundings.

Brute-force irradiance uses a control variate: the unoccluded distant irradiance is an exact sum over
a 512 × 256 equirect render of the true map; only the blocked part and the local − distant difference
are sampled (a Fibonacci lattice, randomly rotated per point, or uniform directions in the cone of the
object's bounding sphere), with common directions between neighbouring rungs. Each rung's error is
reported as measured and with the reference's noise variance subtracted (its two halves give an
unbiased estimate of it); the brute force's own noise is measured by running it twice.

Usage:
    python benchmarks/study_composite.py --scene office --scene office_dark --figure docs/figures/composite_study.png

References:
    Sloan, Kautz, Snyder (2002), Precomputed radiance transfer for real-time rendering in dynamic,
    low-frequency lighting environments (the PRT the pipeline uses).
    Debevec (1998), Rendering synthetic objects into real scenes (differential rendering).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rgbd_envmap.geometry import equirect_directions, equirect_solid_angles  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])
OBJECT_RUNGS = ("O1", "O2", "O3", "O4", "O5", "O6", "O7", "O8")
SHADOW_RUNGS = ("S1", "S2", "S3", "S4", "S5", "S6", "S7", "S8")
RUNG_NAMES = {
    "O1": "ours (the composite)",
    "O2": "ours' shading, true-pose coverage, no 8 bits",
    "O3": "captured map, emitters' pixels from the true map",
    "O4": "true map (HDR), SH 5 bands, PRT",
    "O5": "true map, brute force (no SH), distant",
    "O6": "local light per vertex (no SH, not distant)",
    "O7": "local light per pixel, interpolated normal",
    "O8": "local light per pixel, face normal",
    "S1": "ours (the composite)",
    "S2": "ours' alpha over the reference background",
    "S3": "shadow grey 0",
    "S4": "alpha from the captured map with true emitters",
    "S5": "alpha from the true map's SH (HDR)",
    "S6": "alpha by brute force on the plane (no SH), distant",
    "S7": "brute force at the true receiver, distant",
    "S8": "local light, object a black occluder",
    "ref": "the reference",
}
STEP_CAUSE = {
    ("O1", "O2"): "coverage + 8 bits",
    ("O2", "O3"): "the emitters in the map (clipped capture)",
    ("O3", "O4"): "the rest of the map (holes, geometry, colour chain, staleness)",
    ("O4", "O5"): "SH truncation",
    ("O5", "O6"): "distant-light assumption",
    ("O6", "O7"): "Gouraud interpolation",
    ("O7", "O8"): "shading normal (smooth vs faceted)",
    ("O8", "ref"): "interreflection",
    ("S1", "S2"): "camera noise, 8 bits",
    ("S2", "S3"): "shadow grey",
    ("S3", "S4"): "the emitters in the map (clipped capture)",
    ("S4", "S5"): "the rest of the map",
    ("S5", "S6"): "SH truncation (missing hard shadow)",
    ("S6", "S7"): "plane model (receiver position, normal)",
    ("S7", "S8"): "distant-light assumption",
    ("S8", "ref"): "light bounced by the object",
}


# --- helpers (tested in tests/benchmarks/test_study_composite.py) ------------------------------------

def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) float64 unit directions of a spherical Fibonacci lattice (equal area 4π / n each)."""
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    phi = 2.0 * np.pi * i / ((1.0 + math.sqrt(5.0)) / 2.0)
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def random_rotations(k: int, rng: np.random.Generator) -> np.ndarray:
    """(k, 3, 3) rotation matrices, uniform (QR of Gaussian matrices with the sign fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(k, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    det = np.linalg.det(q)
    q[:, :, 0] *= det[:, None]
    return q


def exact_irradiance(radiance: np.ndarray, normals: np.ndarray, chunk: int = 64) -> np.ndarray:
    """E(n) = Σ_p L_p max(n·d_p, 0) Ω_p over every pixel of an (H, W, 3) equirect radiance map, for
    (N, 3) unit normals: (N, 3) float64."""
    h, w = radiance.shape[:2]
    d = equirect_directions(h, w).reshape(-1, 3).astype(np.float32)
    lw = (radiance.reshape(-1, 3).astype(np.float64) * equirect_solid_angles(h, w).reshape(-1, 1)).astype(np.float32)
    normals = np.asarray(normals, np.float32).reshape(-1, 3)
    out = np.empty((len(normals), 3))
    for s in range(0, len(normals), chunk):
        cos = np.maximum(normals[s:s + chunk] @ d.T, 0.0)
        out[s:s + chunk] = cos @ lw
    return out


def barycentric(values: np.ndarray, faces: np.ndarray, prim: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Values (V, C) interpolated at ray hits on triangles ``prim`` with open3d's barycentrics
    ``uv`` (point = (1 − u − v) v0 + u v1 + v v2)."""
    f = faces[prim]
    u, v = uv[:, :1], uv[:, 1:2]
    return (1.0 - u - v) * values[f[:, 0]] + u * values[f[:, 1]] + v * values[f[:, 2]]


def plane_alpha_at_rays(origin: np.ndarray, dirs: np.ndarray, base: np.ndarray, size_m: float,
                        alpha: np.ndarray) -> np.ndarray:
    """Alpha of the shadow plane where each ray (from ``origin`` along (N, 3) ``dirs``) crosses it:
    the plane is z = base_z, a square of side ``size_m`` centred on ``base``, ``alpha`` its (R, R)
    vertex grid (row j: y, column i: x, as :func:`rgbd_envmap.prt.plane_grid`), bilinear between
    vertices; 0 where the ray misses the square or meets the plane behind the origin."""
    res = alpha.shape[0]
    dz = dirs[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (base[2] - origin[2]) / dz
    ok = np.isfinite(s) & (s > 0)
    p = origin + dirs * np.where(ok, s, 0.0)[:, None] - base
    gi = (p[:, 0] + size_m / 2) / size_m * (res - 1)
    gj = (p[:, 1] + size_m / 2) / size_m * (res - 1)
    ok &= (gi >= 0) & (gi <= res - 1) & (gj >= 0) & (gj <= res - 1)
    i0 = np.clip(np.floor(gi), 0, res - 2).astype(int)
    j0 = np.clip(np.floor(gj), 0, res - 2).astype(int)
    fi, fj = np.clip(gi - i0, 0, 1), np.clip(gj - j0, 0, 1)
    a = (alpha[j0, i0] * (1 - fi) * (1 - fj) + alpha[j0, i0 + 1] * fi * (1 - fj)
         + alpha[j0 + 1, i0] * (1 - fi) * fj + alpha[j0 + 1, i0 + 1] * fi * fj)
    return np.where(ok, a, 0.0)


def cone_directions(axis: np.ndarray, cos_max: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
    """(N, m, 3) unit directions in the cone of half-angle acos(cos_max) (N,) about (N, 3) ``axis``,
    uniform in solid angle when ``uniforms`` (N, m, 2) are uniform in [0, 1)."""
    cos_t = 1.0 - uniforms[..., 0] * (1.0 - cos_max[:, None])
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * uniforms[..., 1]
    helper = np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(axis, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(axis, t1)
    return ((sin_t * np.cos(phi))[..., None] * t1[:, None] + (sin_t * np.sin(phi))[..., None] * t2[:, None]
            + cos_t[..., None] * axis[:, None])


# --- ray casting ------------------------------------------------------------------------------------

class ObjectCaster:
    """The virtual object alone, in world coordinates (open3d)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        import open3d as o3d

        self._o3d = o3d
        self.rc = o3d.t.geometry.RaycastingScene()
        self.rc.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)),
                              o3d.core.Tensor(np.asarray(faces, np.uint32)))

    def _rays(self, origins, dirs):
        rays = np.concatenate([np.broadcast_to(np.asarray(origins, np.float32), dirs.shape),
                               np.asarray(dirs, np.float32)], axis=1)
        return self._o3d.core.Tensor(np.ascontiguousarray(rays))

    def cast(self, origins, dirs) -> dict:
        ans = self.rc.cast_rays(self._rays(origins, dirs))
        return {"t": ans["t_hit"].numpy(), "prim": ans["primitive_ids"].numpy().astype(np.int64),
                "uv": ans["primitive_uvs"].numpy().astype(np.float64),
                "normal": ans["primitive_normals"].numpy().astype(np.float64)}

    def occluded(self, origins, dirs) -> np.ndarray:
        return self.rc.test_occlusions(self._rays(origins, dirs)).numpy().astype(bool)


def brute_irradiance(points, normals, *, object_caster, raycaster, em_origin, t_s, e0, n_dirs, rotations,
                     local: bool, batch: int = 256, eps: float = 1e-4) -> dict:
    """Irradiance (N, 3) at ``points`` with ``normals`` by the control variate of the module docstring:
    ``distant`` = E0(n) − Σ (1 − V) L_map cos ΔΩ, and with ``local`` also
    ``local`` = distant + Σ V (L_scene(x) − L_map) cos ΔΩ (common directions). ``rotations``: (N, 3, 3),
    the lattice's rotation at each point (the same rotations give the same directions: common random
    numbers between two estimates)."""
    lattice = fibonacci_sphere(n_dirs)
    w0 = 4.0 * np.pi / n_dirs
    n = len(points)
    blocked = np.zeros((n, 3))
    diff = np.zeros((n, 3))
    for s in range(0, n, batch):
        p, nn = points[s:s + batch], normals[s:s + batch]
        rot = rotations[s:s + batch]
        d = np.einsum("ij,pkj->pik", lattice, rot)  # (P, n_dirs, 3)
        cos = np.einsum("pik,pk->pi", d, nn)
        pi, di = np.nonzero(cos > 0)
        dirs = d[pi, di]
        org = p[pi] + eps * nn[pi]
        occ = object_caster.occluded(org, dirs)
        l_map = raycaster.cast(em_origin, dirs.astype(np.float32), t_s, normals=False).radiance.astype(np.float64)
        wc = (cos[pi, di] * w0)[:, None]
        np.add.at(blocked, s + pi[occ], l_map[occ] * wc[occ])
        if local:
            free = ~occ
            l_loc = raycaster.cast(org[free], dirs[free].astype(np.float32), t_s, normals=False).radiance
            np.add.at(diff, s + pi[free], (l_loc.astype(np.float64) - l_map[free]) * wc[free])
    distant = e0 - blocked
    return {"distant": distant, "local": distant + diff if local else None}


def shadow_change(points, normals, *, object_caster, raycaster, em_origin, centre, radius, t_s, uniforms,
                  local: bool, batch: int = 256, eps: float = 1e-4) -> dict:
    """The irradiance the object hides at each point (N, 3): directions uniform in the cone of its
    bounding sphere (solid angle Ω; estimate Ω · mean(blocked · L · cos)). ``distant``: L from the map
    (cast from the EM origin), blocked where the object is hit; ``local``: L the scene behind the
    object seen from the point, blocked where the object is nearer than the scene. ``uniforms``:
    (N, m, 2) numbers in [0, 1) that place the m directions of each point in its cone."""
    m = uniforms.shape[1]
    n = len(points)
    out_d, out_l = np.zeros((n, 3)), np.zeros((n, 3))
    for s in range(0, n, batch):
        x, nn = points[s:s + batch] + eps * normals[s:s + batch], normals[s:s + batch]
        to_c = centre - x
        dc = np.linalg.norm(to_c, axis=1)
        inside = dc <= radius
        cos_max = np.where(inside, -1.0, np.sqrt(np.maximum(0.0, 1.0 - (radius / np.maximum(dc, 1e-12)) ** 2)))
        axis = to_c / np.maximum(dc, 1e-12)[:, None]
        omega = 2.0 * np.pi * (1.0 - cos_max)
        d = cone_directions(axis, cos_max, uniforms[s:s + batch])
        cos = np.einsum("pmk,pk->pm", d, nn).ravel()
        org = np.repeat(x, m, axis=0)
        flat = d.reshape(-1, 3)
        t_o = object_caster.cast(org, flat)["t"]
        hit = np.isfinite(t_o) & (cos > 0)
        k = np.flatnonzero(hit)
        contrib_d = np.zeros((len(flat), 3))
        contrib_l = np.zeros((len(flat), 3))
        if len(k):
            l_map = raycaster.cast(em_origin, flat[k].astype(np.float32), t_s, normals=False).radiance
            contrib_d[k] = l_map * cos[k, None]
            if local:
                behind = raycaster.cast(org[k], flat[k].astype(np.float32), t_s, normals=False)
                front = ~behind.hit | (t_o[k] < behind.distance_m)
                contrib_l[k[front]] = behind.radiance[front] * cos[k[front], None]
        factor = omega[:, None] / m
        out_d[s:s + batch] = factor * contrib_d.reshape(len(x), m, 3).sum(axis=1)
        out_l[s:s + batch] = factor * contrib_l.reshape(len(x), m, 3).sum(axis=1)
    return {"distant": out_d, "local": out_l if local else None}


# --- the session --------------------------------------------------------------------------------------

@dataclass
class Frame:
    t_s: float
    timestamp_ns: int
    pose: object  # true RigidTransform (T_world_from_colour)
    gains: np.ndarray
    image: np.ndarray  # composite, uint8 sRGB
    colours: np.ndarray  # (V, 3) pipeline shading, reference colour space
    plane_alpha: np.ndarray
    coeffs: np.ndarray
    bands: int
    matrix: np.ndarray  # current colours -> reference colours
    object_base: np.ndarray
    em_origin: np.ndarray
    min_gains: np.ndarray  # per channel, the lowest gains of any colour frame so far (the least clipping)
    em_radiance: np.ndarray  # the captured map (reference colour space), float32
    em_valid: np.ndarray


def run_session(scene_name: str, *, start_s: float, every_s: float, frames: int, size: tuple[int, int], seed: int,
                cache_dir):
    """Simulate until the last chosen frame (the first colour frames at or after ``start_s``,
    ``start_s + every_s``, ...; ``frames`` of them) and keep the pipeline's state at those frames."""
    from rgbd_envmap.logs import as_logged
    from rgbd_envmap.pipeline import Pipeline, PipelineConfig
    from sim.colour_camera import ColourCameraConfig
    from sim.device import TangoDeviceConfig
    from sim.scene import load_scene
    from sim.session import Simulator
    from sim.trajectory import load_trajectory

    scene = load_scene(scene_name)
    traj = load_trajectory(scene.default_trajectory)
    colour = replace(ColourCameraConfig(), width=size[0], height=size[1])
    sim = Simulator(scene, traj, TangoDeviceConfig(colour=colour), seed=seed)
    origin = np.asarray(scene.virtual_object_position, np.float64)
    config = PipelineConfig()
    pipe = Pipeline(config, sim.calibration, origin, cache_dir=cache_dir)
    kept: list[Frame] = []
    next_t = start_s
    min_gains = np.full(3, np.inf)
    with pipe:
        for sp in sim.run(start_s + every_s * (frames - 1) + 0.2):
            if sp.packet.kind == "colour":
                min_gains = np.minimum(min_gains, np.asarray(sp.groundtruth["gains"], np.float64))
            chosen = False
            if sp.packet.kind == "colour" and sp.t_s + 1e-9 >= next_t:
                chosen = True
                while next_t <= sp.t_s + 1e-9:
                    next_t += every_s
            steps = pipe.feed(as_logged(sp.packet))
            if not chosen:
                continue
            img = [s for s in steps if hasattr(s, "image") and s.image is not None]
            if not img or pipe.virtual_object is None:
                continue
            kept.append(Frame(float(sp.t_s), int(sp.packet.timestamp_ns), sp.true_pose,
                              np.asarray(sp.groundtruth["gains"], np.float64), np.array(img[-1].image),
                              np.array(pipe.colours, np.float64), np.array(pipe.plane_alpha, np.float64),
                              np.array(pipe.coeffs, np.float64), int(pipe.bands), np.array(pipe.capture.matrix),
                              np.array(pipe.object_base, np.float64), np.array(pipe.capture.em.origin, np.float64),
                              min_gains.copy(), np.array(pipe.capture.em.radiance, np.float32),
                              np.array(pipe.capture.em.valid, bool)))
        pipe.finish()
    return scene, sim, pipe, config, kept


def cached_session(name: str, args, size):
    """:func:`run_session`, its frames pickled under ``args.work`` (reused when present)."""
    import pickle

    key = f"{name}_{size[0]}x{size[1]}_s{args.seed}_t{args.start:g}_e{args.every:g}_f{args.frames}_v3"
    path = args.work / f"{key}.pkl" if args.work else None
    if path is not None and path.exists():
        from rgbd_envmap.pipeline import Pipeline, PipelineConfig
        from sim.colour_camera import ColourCameraConfig
        from sim.device import TangoDeviceConfig
        from sim.scene import load_scene
        from sim.session import Simulator
        from sim.trajectory import load_trajectory

        scene = load_scene(name)
        colour = replace(ColourCameraConfig(), width=size[0], height=size[1])
        sim = Simulator(scene, load_trajectory(scene.default_trajectory), TangoDeviceConfig(colour=colour),
                        seed=args.seed)
        config = PipelineConfig()
        pipe = Pipeline(config, sim.calibration, np.asarray(scene.virtual_object_position, np.float64),
                        cache_dir=args.cache_dir)
        return scene, sim, pipe, config, pickle.loads(path.read_bytes())
    out = run_session(name, start_s=args.start, every_s=args.every, frames=args.frames, size=size, seed=args.seed,
                      cache_dir=args.cache_dir)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(pickle.dumps(out[4]))
    return out


# --- one frame ----------------------------------------------------------------------------------------

def analyse_frame(f: Frame, *, scene, sim, config, obj, transfer, plane, em_size, args, rng) -> dict:
    from rgbd_envmap import prt, sh
    from rgbd_envmap.colour import srgb8_to_linear_lut
    from rgbd_envmap.metrics import composite_errors
    from sim.groundtruth import render_envmap
    from sim.mitsuba_scene import ExtraMesh
    from sim.reference import camera_rays, render_reference_pair

    clip_level = 0.98  # apps.reference_frames.CLIP_LEVEL
    intr = sim.calibration.colour
    h, w = intr.height, intr.width
    verts_w = np.asarray(obj.vertices, np.float64) + f.object_base
    mesh = ExtraMesh(obj.name, verts_w, obj.faces, obj.albedo)
    t0 = time.perf_counter()
    pair_path = (args.work / f"pair_{scene.name}_{w}x{h}_s{args.seed}_{f.timestamp_ns}_{args.spp}_{args.object_spp}.pkl"
                 if args.work else None)
    if pair_path is not None and pair_path.exists():
        import pickle

        pair = pickle.loads(pair_path.read_bytes())
    else:
        pair = render_reference_pair(scene, f.pose, intr, f.t_s, mesh, spp=args.spp, object_spp=args.object_spp,
                                     radius_m=0.5, raycaster=sim.raycaster, seed=args.seed + int(f.t_s * 10),
                                     method="gather")
        if pair_path is not None:
            import pickle

            pair_path.write_bytes(pickle.dumps(pair))
    ref_s = time.perf_counter() - t0
    lut = srgb8_to_linear_lut()
    ours = (lut[f.image] / f.gains).astype(np.float64)
    unclipped = (((pair.with_object * f.gains).max(-1) < clip_level)
                 & ((pair.without_object * f.gains).max(-1) < clip_level))
    valid = pair.traced & pair.hit & unclipped
    e = composite_errors(ours, pair.with_object, pair.without_object, pair.object_mask, valid)
    obj_m = pair.object_mask & valid
    sh_m = e["shadow_mask"]
    ref = pair.with_object.astype(np.float64).reshape(-1, 3)
    bg = pair.without_object.astype(np.float64).reshape(-1, 3)
    origin, dirs = camera_rays(f.pose, intr)
    oc = ObjectCaster(verts_w, obj.faces)
    albedo = np.asarray(obj.albedo, np.float64)
    n = f.bands * f.bands
    t1 = time.perf_counter()

    # --- the true map at the EM origin at the frame's time
    gt = render_envmap(sim.raycaster, f.em_origin, em_size[0], em_size[1], f.t_s)
    coeffs_true = sh.project_equirect(gt.radiance, gt.valid, bands=f.bands)
    # The captured map in the composite's radiance units (shading is linear in the map, so the map's
    # pixels go through ccm⁻¹ and the gains as the object's colours do), and the same map with the
    # pixels of the emitters (lamp, window, screens: what an 8-bit camera clips) from the true map.
    ccm_inv = np.linalg.inv(f.matrix)
    cap = (f.em_radiance.astype(np.float64) @ ccm_inv.T / f.gains).astype(np.float32)
    emissive = np.array([o.emission is not None or o.emission_texture is not None for o in scene.objects] + [False])
    emit = gt.valid & emissive[np.where(gt.object_index >= 0, gt.object_index, len(scene.objects))]
    coeffs_cap = sh.project_equirect(cap, f.em_valid, bands=f.bands)
    coeffs_clip = sh.project_equirect(np.where(emit[..., None], gt.radiance, cap).astype(np.float32),
                                      f.em_valid | emit, bands=f.bands)
    light = gt.radiance @ LUMA * equirect_solid_angles(*gt.valid.shape)
    emit_share = float(light[emit].sum() / max(light.sum(), 1e-12))
    cap_l = np.where(f.em_valid, cap @ LUMA, 0.0) * equirect_solid_angles(*gt.valid.shape)
    emit_captured = float(cap_l[emit].sum() / max(light[emit].sum(), 1e-12))
    gt_small = render_envmap(sim.raycaster, f.em_origin, 256, 512, f.t_s)
    radiance_small = np.where(gt_small.valid[..., None], gt_small.radiance, 0.0)

    # --- object
    oi = np.flatnonzero(obj_m.ravel())
    print(f"  t={f.t_s:.2f}: object mask {int(pair.object_mask.sum())} px, valid {int(obj_m.sum())}, traced "
          f"{int(pair.traced.sum())}, shadow {int(sh_m.sum())}", flush=True)
    if not len(oi):
        raise RuntimeError(f"t={f.t_s:.2f} s: no valid object pixel in the reference")
    rungs_o: dict[str, np.ndarray] = {"O1": ours.reshape(-1, 3)[oi]}
    hit = oc.cast(np.broadcast_to(origin, (len(oi), 3)), dirs[oi])
    assert np.isfinite(hit["t"]).all(), "an object pixel's ray missed the object"
    prim, uv = hit["prim"], hit["uv"]
    x_pix = origin + dirs[oi] * hit["t"][:, None].astype(np.float64)
    recon = barycentric(verts_w, obj.faces, prim, uv)
    assert np.abs(recon - x_pix).max() < 1e-3, "open3d barycentrics are not (1-u-v, u, v)"
    used = np.unique(obj.faces[prim].ravel())
    colours = np.maximum(f.colours, 0.0)
    o2 = np.clip(barycentric(colours, obj.faces, prim, uv) @ ccm_inv.T, 0.0, 1.0) / f.gains
    rungs_o["O2"] = o2
    shaded_true = prt.shade(transfer[:, :n], coeffs_true[:n], obj.albedo).astype(np.float64)
    # check: the captured map re-projected here shades the object as the pipeline did (same radiance units)
    shaded_cap = prt.shade(transfer[:, :n], coeffs_cap[:n], obj.albedo).astype(np.float64)
    o2_check = barycentric(np.maximum(shaded_cap, 0.0), obj.faces, prim, uv)
    reproj = float(np.sqrt(np.sum((np.clip(o2_check, 0, 1 / f.gains) - o2) ** 2) / np.sum(o2 ** 2)))
    shaded_clip = prt.shade(transfer[:, :n], coeffs_clip[:n], obj.albedo).astype(np.float64)
    rungs_o["O3"] = barycentric(np.maximum(shaded_clip, 0.0), obj.faces, prim, uv)
    rungs_o["O4"] = barycentric(np.maximum(shaded_true, 0.0), obj.faces, prim, uv)
    vn = np.asarray(obj.normals, np.float64)
    common = dict(object_caster=oc, raycaster=sim.raycaster, em_origin=f.em_origin, t_s=f.t_s, n_dirs=args.dirs)
    e_vert = np.zeros((len(obj.vertices), 3))
    e_vert_loc = np.zeros((len(obj.vertices), 3))
    bi = brute_irradiance(verts_w[used], vn[used], e0=exact_irradiance(radiance_small, vn[used]),
                          rotations=random_rotations(len(used), rng), local=True, **common)
    e_vert[used], e_vert_loc[used] = bi["distant"], bi["local"]
    rungs_o["O5"] = albedo / np.pi * barycentric(e_vert, obj.faces, prim, uv)
    rungs_o["O6"] = albedo / np.pi * barycentric(e_vert_loc, obj.faces, prim, uv)
    n_smooth = barycentric(vn, obj.faces, prim, uv)
    n_smooth /= np.linalg.norm(n_smooth, axis=1, keepdims=True)
    n_face = hit["normal"]
    n_face /= np.linalg.norm(n_face, axis=1, keepdims=True)
    # the mesh winds outwards, so the face normal faces the camera; flip any that do not
    n_face *= np.where(np.einsum("ij,ij->i", n_face, dirs[oi]) > 0, -1.0, 1.0)[:, None]
    rot = random_rotations(len(oi), rng)  # the same directions for O7 and O8
    for key, nrm in (("O7", n_smooth), ("O8", n_face)):
        bp = brute_irradiance(x_pix, nrm, e0=exact_irradiance(radiance_small, nrm), rotations=rot, local=True, **common)
        rungs_o[key] = albedo / np.pi * bp["local"]
    # the brute force's own noise: O8 again with other directions
    bp = brute_irradiance(x_pix, n_face, e0=exact_irradiance(radiance_small, n_face),
                          rotations=random_rotations(len(oi), rng), local=True, **common)
    mc_o = [float(np.sum((albedo / np.pi * bp["local"] - rungs_o["O8"]) ** 2) / 2.0)]
    ratio = {k: (np.sum(v, axis=0) / np.sum(ref[oi], axis=0)).round(3).tolist() for k, v in rungs_o.items()}
    ref_o = ref[oi]

    # --- shadow
    si = np.flatnonzero(sh_m.ravel())
    rungs_s: dict[str, np.ndarray] = {"S1": ours.reshape(-1, 3)[si]}
    res = plane.resolution
    a_ours = plane_alpha_at_rays(origin, dirs[si], f.object_base, plane.size_m,
                                 f.plane_alpha.reshape(res, res))[:, None]
    grey = (ccm_inv @ np.full(3, config.render.shadow_grey)) / f.gains
    bg_s = bg[si]
    rungs_s["S2"] = (1 - a_ours) * bg_s + a_ours * grey
    rungs_s["S3"] = (1 - a_ours) * bg_s
    for key, c in (("S4", coeffs_clip), ("S5", coeffs_true)):
        alpha_c = prt.shadow_alpha(plane, c[:n]).astype(np.float64)
        a_c = plane_alpha_at_rays(origin, dirs[si], f.object_base, plane.size_m, alpha_c.reshape(res, res))[:, None]
        rungs_s[key] = (1 - a_c) * bg_s
    centre = 0.5 * (verts_w.min(axis=0) + verts_w.max(axis=0))
    radius = float(np.max(np.linalg.norm(verts_w - centre, axis=1)))
    sc = dict(object_caster=oc, raycaster=sim.raycaster, em_origin=f.em_origin, centre=centre, radius=radius,
              t_s=f.t_s)
    uni = rng.random((len(si), args.shadow_dirs, 2))  # the same directions for S6, S7 and S8
    # S6: on the plane (where the camera ray crosses z = base, inside the square), normal +z
    dz = dirs[si, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s_plane = (f.object_base[2] - origin[2]) / dz
    q = origin + dirs[si] * np.where(np.isfinite(s_plane) & (s_plane > 0), s_plane, 0.0)[:, None]
    on_plane = (np.isfinite(s_plane) & (s_plane > 0) & (np.abs(q[:, 0] - f.object_base[0]) <= plane.size_m / 2)
                & (np.abs(q[:, 1] - f.object_base[1]) <= plane.size_m / 2))
    up = np.tile([0.0, 0.0, 1.0], (len(si), 1))
    e0_up = exact_irradiance(radiance_small, up[:1])[0]
    a5 = np.zeros(len(si))
    if on_plane.any():
        ch = shadow_change(q[on_plane], up[on_plane], uniforms=uni[on_plane], local=False, **sc)["distant"]
        a5[on_plane] = np.clip((ch @ LUMA) / max(float(e0_up @ LUMA), 1e-12), 0.0, 1.0)
    rungs_s["S6"] = (1 - a5[:, None]) * bg_s
    surf = sim.raycaster.surface_hits(origin, dirs[si].astype(np.float32), f.t_s)
    x_s = origin + dirs[si] * surf.distance_m.astype(np.float64)[:, None]
    n_s = surf.face_normal.astype(np.float64)
    n_s *= np.where(np.einsum("ij,ij->i", n_s, dirs[si]) > 0, -1.0, 1.0)[:, None]
    rho = surf.albedo.astype(np.float64)
    ch = shadow_change(x_s, n_s, uniforms=uni, local=True, **sc)
    ch2 = shadow_change(x_s, n_s, uniforms=rng.random(uni.shape), local=True, **sc)  # its own noise
    mc_s = [float(np.sum((rho / np.pi * (ch2["local"] - ch["local"])) ** 2) / 2.0)]
    nk, inv = np.unique(np.round(n_s, 4), axis=0, return_inverse=True)
    e0_s = exact_irradiance(radiance_small, nk / np.linalg.norm(nk, axis=1, keepdims=True))[inv.ravel()]
    a6 = np.clip((ch["distant"] @ LUMA) / np.maximum(e0_s @ LUMA, 1e-12), 0.0, 1.0)
    rungs_s["S7"] = (1 - a6[:, None]) * bg_s
    rungs_s["S8"] = bg_s - rho / np.pi * ch["local"]
    ref_s_ = ref[si]
    ladder_s = time.perf_counter() - t1

    def sums(rungs, target):
        out = {k: [float(np.sum((v - target) ** 2)), float(np.sum(target ** 2))] for k, v in rungs.items()}
        keys = list(rungs) + ["ref"]
        for a, b in zip(keys[:-1], keys[1:]):
            vb = target if b == "ref" else rungs[b]
            out[f"{a}->{b}"] = [float(np.sum((rungs[a] - vb) ** 2)), float(np.sum(target ** 2))]
        return out

    noise_o = float(np.sum(pair.noise_with.astype(np.float64).reshape(-1, 3)[oi] ** 2))
    noise_s = float(np.sum(pair.noise_with.astype(np.float64).reshape(-1, 3)[si] ** 2))
    return {
        "t_s": f.t_s, "object_pixels": int(len(oi)), "shadow_pixels": int(len(si)),
        "composite_errors": {k: e[k] for k in ("object_rel_rmse", "shadow_rel_rmse", "rel_rmse")},
        "object": sums(rungs_o, ref_o), "shadow": sums(rungs_s, ref_s_),
        "noise": {"object": [noise_o, float(np.sum(ref_o ** 2))], "shadow": [noise_s, float(np.sum(ref_s_ ** 2))]},
        "mc_noise": {"object": [mc_o[0], float(np.sum(ref_o ** 2))], "shadow": [mc_s[0], float(np.sum(ref_s_ ** 2))]},
        "ref_render_s": ref_s, "ladder_s": ladder_s, "bands": f.bands, "object_mean_ratio_rgb": ratio,
        "reprojection_check": reproj, "emitter_share_of_light": emit_share, "emitters_captured": emit_captured,
        "sheet": {"ref": pair.with_object, "gains": f.gains, "ours": f.image, "ours_lin": ours,
                  "region": obj_m | sh_m, "object": obj_m, "traced": pair.traced, "valid": valid},
    }


def pooled(results: list[dict], region: str, key: str) -> float:
    num = sum(r[region][key][0] for r in results)
    den = sum(r[region][key][1] for r in results)
    return math.sqrt(num / den) if den > 0 else float("nan")


def pooled_noise(results: list[dict], region: str, kind: str = "noise") -> float:
    """The reference's (``noise``) or the brute force's (``mc_noise``) relative standard error."""
    num = sum(r[kind][region][0] for r in results)
    den = sum(r[kind][region][1] for r in results)
    return math.sqrt(num / den) if den > 0 else float("nan")


def pooled_debiased(results: list[dict], region: str, key: str) -> float:
    """The rung's error against the reference with the reference's noise variance taken out:
    sqrt(max(0, Σ (x − ref)² − Σ σ_ref²) / Σ ref²) (σ_ref² from the two halves of its samples is an
    unbiased estimate of its variance, and the rung's own noise is independent of it)."""
    num = sum(r[region][key][0] - r["noise"][region][0] for r in results)
    den = sum(r[region][key][1] for r in results)
    return math.sqrt(max(0.0, num) / den) if den > 0 else float("nan")


def table(scene: str, results: list[dict]) -> str:
    lines = [f"### {scene}: {len(results)} frames at t = " + ", ".join(f"{r['t_s']:.2f}" for r in results) + " s; "
             f"{sum(r['object_pixels'] for r in results)} object px, "
             f"{sum(r['shadow_pixels'] for r in results)} shadow px",
             "", "| rung | composite | rel RMSE vs ref | same, ref noise removed | step to next "
             "| what the step removes |",
             "|---|---|---:|---:|---:|---|"]
    for region, rungs in (("object", OBJECT_RUNGS), ("shadow", SHADOW_RUNGS)):
        keys = list(rungs) + ["ref"]
        for a, b in zip(keys[:-1], keys[1:]):
            step = (pooled_debiased(results, region, f"{a}->{b}") if b == "ref"
                    else pooled(results, region, f"{a}->{b}"))
            lines.append(f"| {a} | {RUNG_NAMES[a]} | {100 * pooled(results, region, a):.1f} % | "
                         f"{100 * pooled_debiased(results, region, a):.1f} % | {100 * step:.1f} % | "
                         f"{STEP_CAUSE[(a, b)]} |")
        lines.append(f"| | noise ({region}): reference {100 * pooled_noise(results, region):.1f} %, brute force "
                     f"{100 * pooled_noise(results, region, 'mc_noise'):.1f} % | | | | |")
    return "\n".join(lines)


def write_figure(path: Path, per_scene: dict[str, list[dict]], rows_per_scene: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import TwoSlopeNorm

    from rgbd_envmap.colour import linear_to_srgb

    picks = []
    for scene, res in per_scene.items():
        idx = np.unique(np.linspace(0, len(res) - 1, min(rows_per_scene, len(res))).round().astype(int))
        picks += [(scene, res[i]) for i in idx]
    fig, axes = plt.subplots(len(picks), 3, figsize=(11, 2.6 * len(picks)), squeeze=False,
                             gridspec_kw={"width_ratios": [1, 1, 1.18]})
    norm = TwoSlopeNorm(vmin=-0.5, vcenter=0.0, vmax=0.5)
    for row, (scene, r) in enumerate(picks):
        s = r["sheet"]
        tr = np.argwhere(s["object"])
        (r0, c0), (r1, c1) = tr.min(axis=0), tr.max(axis=0) + 1
        pad = int(1.2 * max(r1 - r0, c1 - c0)) + 4
        r0, c0 = max(0, r0 - pad), max(0, c0 - pad)
        r1, c1 = min(s["traced"].shape[0], r1 + pad), min(s["traced"].shape[1], c1 + pad)
        crop = (slice(r0, r1), slice(c0, c1))
        cam = linear_to_srgb(np.clip(s["ref"] * s["gains"], 0.0, 1.0))
        ref_y = s["ref"].astype(np.float64) @ LUMA
        diff = (s["ours_lin"] @ LUMA - ref_y) / np.maximum(ref_y, 1e-6)
        shown = np.where(s["region"], diff, np.nan)
        axes[row, 0].imshow(cam[crop])
        axes[row, 1].imshow(s["ours"][crop])
        axes[row, 2].imshow(0.35 * cam[crop].mean(axis=-1), cmap="gray", vmin=0, vmax=1)
        im = axes[row, 2].imshow(shown[crop], cmap="RdBu_r", norm=norm)
        fig.colorbar(im, ax=axes[row, 2], fraction=0.046, pad=0.02, label="(ours − ref) / ref, luminance")
        axes[row, 0].set_ylabel(f"{scene}\nt = {r['t_s']:.1f} s", fontsize=9)
        for c, title in enumerate(("reference (as the camera sees it)", "ours (the composite)",
                                   "difference over object + shadow")):
            axes[row, c].set_xticks([])
            axes[row, c].set_yticks([])
            if row == 0:
                axes[row, c].set_title(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", action="append", help="scene name (repeatable; default: office and office_dark)")
    ap.add_argument("--frames", type=int, default=3, help="reference frames per scene (default 3)")
    ap.add_argument("--start", type=float, default=11.0,
                    help="session time of the first reference frame (default 11 s: the orbit faces the object "
                         "from 11 s on)")
    ap.add_argument("--every", type=float, default=3.0, help="seconds between reference frames (default 3)")
    ap.add_argument("--size", default="320x180", help="colour camera WxH (default 320x180)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--spp", type=int, default=256, help="reference: gather directions per pixel (default 256)")
    ap.add_argument("--object-spp", type=int, default=2048, help="reference: paths per object pixel (default 2048)")
    ap.add_argument("--dirs", type=int, default=4096,
                    help="brute-force lattice directions on the sphere (default 4096)")
    ap.add_argument("--shadow-dirs", type=int, default=2048,
                    help="brute-force cone directions per shadow pixel (default 2048)")
    ap.add_argument("--figure", type=Path, help="write the reference | ours | difference figure here")
    ap.add_argument("--figure-rows", type=int, default=2, help="frames per scene in the figure (default 2)")
    ap.add_argument("--json", type=Path, help="write the pooled figures here")
    ap.add_argument("--cache-dir", default=None)
    ap.add_argument("--work", type=Path, help="keep each session's frames and reference pairs here and reuse them")
    args = ap.parse_args(argv)
    scenes = args.scene or ["office", "office_dark"]
    size = tuple(int(v) for v in args.size.lower().split("x"))
    from rgbd_envmap import prt

    per_scene: dict[str, list[dict]] = {}
    summary: dict = {}
    for name in scenes:
        t0 = time.perf_counter()
        scene, sim, pipe, config, frames = cached_session(name, args, size)
        sim_s = time.perf_counter() - t0
        obj = pipe.virtual_object
        oc = config.object
        bands = pipe.sh_bands_computed
        transfer = prt.load_or_compute(obj, bands, n_dirs=oc.prt_dirs, cache_dir=args.cache_dir)
        plane = prt.shadow_plane(obj, size_m=oc.plane_size_m, resolution=oc.plane_resolution, bands=bands,
                                 n_dirs=oc.prt_dirs, cache_dir=args.cache_dir)
        em_size = pipe.capture.em.radiance.shape[:2]
        rng = np.random.default_rng(args.seed)
        results = []
        for f in frames:
            r = analyse_frame(f, scene=scene, sim=sim, config=config, obj=obj, transfer=transfer, plane=plane,
                              em_size=em_size, args=args, rng=rng)
            results.append(r)
            print(f"{name} t={r['t_s']:.2f}s: object {r['object_pixels']} px, shadow {r['shadow_pixels']} px, "
                  f"composite_errors {json.dumps({k: round(v, 4) for k, v in r['composite_errors'].items()})}, "
                  f"reference {r['ref_render_s']:.0f} s, ladder {r['ladder_s']:.0f} s; re-projected map vs the "
                  f"pipeline's shading {100 * r['reprojection_check']:.2f} %; emitters: "
                  f"{100 * r['emitter_share_of_light']:.0f} % "
                  f"of the true map's light, captured at {100 * r['emitters_captured']:.0f} % of it", flush=True)
        per_scene[name] = results
        print(f"({name}: session + pipeline {sim_s:.0f} s)\n")
        print(table(name, results) + "\n", flush=True)
        summary[name] = {
            "frames": [r["t_s"] for r in results],
            "object": {k: pooled(results, "object", k) for k in results[0]["object"]},
            "shadow": {k: pooled(results, "shadow", k) for k in results[0]["shadow"]},
            "object_debiased": {k: pooled_debiased(results, "object", k) for k in OBJECT_RUNGS},
            "shadow_debiased": {k: pooled_debiased(results, "shadow", k) for k in SHADOW_RUNGS},
            "noise": {k: pooled_noise(results, k) for k in ("object", "shadow")},
            "brute_force_noise": {k: pooled_noise(results, k, "mc_noise") for k in ("object", "shadow")},
            "object_pixels": sum(r["object_pixels"] for r in results),
            "shadow_pixels": sum(r["shadow_pixels"] for r in results),
            "object_mean_ratio_rgb": [r["object_mean_ratio_rgb"] for r in results],
            "reprojection_check": [r["reprojection_check"] for r in results],
            "emitter_share_of_light": [r["emitter_share_of_light"] for r in results],
            "emitters_captured": [r["emitters_captured"] for r in results],
        }
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2) + "\n")
    if args.figure:
        write_figure(args.figure, per_scene, args.figure_rows)
        print(f"wrote {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
