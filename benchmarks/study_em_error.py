"""Why the captured environment map of the default session stops near 25 dB WS-PSNR: an error
budget, a resolution bound, and prototype fixes measured side by side (docs/studies/em_error_study.md).

    python benchmarks/study_em_error.py [--duration 20] [--colour-size 960x540] [--em-height 1000]
                                        [--cache /tmp/em_study] [--out /tmp/em_study/results.md]
                                        [--figures docs/figures]

``--out`` writes every table the run prints (Markdown); docs/studies/em_error_study.md is written by hand
from them (do not point ``--out`` at it). The cache is ~320 MB for the default session.

One simulated session (the default orbit, seed 0, as ``benchmarks/eval_envmap.py``) is ingested once
and kept under ``--cache`` (frames, colour images, per-pixel ground truth of the ToF rays); every
capture below replays those frames. The map update is a copy of ``rgbd_envmap.envmap.map_update``'s
kernel (the committed version) with instrumentation (which frame, rule and frame pixel last wrote
each map pixel) and the prototype options; the first table checks that the copy reproduces the
library's map.

Scores as ``eval_envmap.em_scores``: coverage of the true map's solid angle and WS-PSNR on pixels
valid in both maps, both clipped to [0, 1], against ``sim.groundtruth.render_envmap`` at the last
frame's time ``t_end``.
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse
import math
import pickle
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from rgbd_envmap.colour import apply_ccm, estimate_ccm, srgb8_to_linear_lut
from rgbd_envmap.depth.reliability import discontinuity_test, mark_reliable
from rgbd_envmap.geometry import equirect_directions, equirect_solid_angles, pixel_rays
from rgbd_envmap.ingest.tango import colour_at_points, decode_colour, ingest_tango
from rgbd_envmap.metrics import coverage_of, ws_psnr
from rgbd_envmap.types import Intrinsics, RigidTransform
from sim.colour_camera import ColourCameraConfig
from sim.device import TangoDeviceConfig
from sim.groundtruth import render_envmap
from sim.scene import load_scene
from sim.session import Simulator
from sim.trajectory import load_trajectory

# ------------------------------------------------------------------------------------------------
# 1. One simulated session, ingested once and cached
# ------------------------------------------------------------------------------------------------

def make_sim(args) -> Simulator:
    w, h = (int(x) for x in args.colour_size.split("x"))
    return Simulator(load_scene("office"), load_trajectory("orbit"),
                     TangoDeviceConfig(colour=ColourCameraConfig(width=w, height=h)), seed=args.seed)


def simulate(args) -> list[dict]:
    """Every depth packet paired with the same-time colour frame (as ``eval_envmap.ingested_frames``),
    ingested, with the colour image and the ground truth of the ToF rays kept."""
    sim = make_sim(args)
    out = []
    pending = None
    for sp in sim.run(args.duration):
        if sp.packet.kind == "depth":
            pending = sp
            continue
        if pending is None or sp.packet.timestamp_ns != pending.packet.timestamp_ns:
            continue
        srgb8 = decode_colour(sp.packet)
        res = ingest_tango(pending.packet, srgb8, sp.packet.T_world_from_colour, sim.calibration)
        gt = pending.groundtruth
        out.append({
            "t_s": pending.t_s, "timestamp_ns": res.frame.timestamp_ns,
            "raw_rgb": res.frame.rgb, "raw_depth": res.frame.depth_m, "raw_known": res.frame.known,
            "reliable": res.reliable,
            "rgb": res.filled.rgb, "depth": res.filled.depth_m, "known": res.filled.known,
            "T_world_from_depth": res.frame.T_world_from_cam.matrix,
            "T_world_from_colour": sp.packet.T_world_from_colour.matrix,
            "T_colour_from_depth": res.T_colour_from_depth.matrix,
            "srgb8": srgb8, "gains": np.asarray(sp.groundtruth["gains"], np.float64),
            "true_depth": gt["true_depth_m"], "true_valid": gt["true_valid"],
            "object_index": gt["object_index"], "mixed": gt["mixed"],
            "true_T_world_from_depth": pending.true_pose.matrix,
        })
        pending = None
    return out


def load_or_simulate(args) -> list[dict]:
    path = Path(args.cache) / f"frames_{args.duration:g}s_{args.colour_size}_seed{args.seed}.pkl"
    if path.is_file():
        with open(path, "rb") as f:
            return pickle.load(f)
    t0 = time.perf_counter()
    frames = simulate(args)
    print(f"simulated and ingested {len(frames)} frames in {time.perf_counter() - t0:.0f} s", flush=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump(frames, f, protocol=pickle.HIGHEST_PROTOCOL)
    return frames


# ------------------------------------------------------------------------------------------------
# 2. The map update: a copy of the committed rgbd_envmap.envmap._update_kernel, instrumented, with
#    the prototype options (per-sample footprint scale, freed pixels, colour looked up per map pixel)
# ------------------------------------------------------------------------------------------------

RULES = ("-", "empty", "closer", "trusted", "removal", "freed")
TAG_FILLED, TAG_FILL_ONLY = 1, 2


@numba.njit(cache=True)
def _span(x, half, limit):  # pragma: no cover - compiled
    h = min(max(half, 0.5), limit)
    return int(math.ceil(x - h - 0.5)), int(math.floor(x + h - 0.5))  # noqa: RUF046 (numba)


@numba.njit(cache=True)
def _distort(x, y, k1, k2, p1, p2, k3):  # pragma: no cover - compiled
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y


@numba.njit(cache=True)
def _lookup(img, rot, trans, cam, dist, px, py, pz, out):  # pragma: no cover - compiled
    """Bilinear colour of world point p in a linear (h, w, 3) image; False when outside."""
    x = rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz + trans[0]
    y = rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz + trans[1]
    z = rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz + trans[2]
    if not z > 0.0:
        return False
    xd, yd = _distort(x / z, y / z, dist[0], dist[1], dist[2], dist[3], dist[4])
    u = cam[0] * xd + cam[2]
    v = cam[1] * yd + cam[3]
    h, w = img.shape[0], img.shape[1]
    if not (u >= 0.0 and u <= w - 1 and v >= 0.0 and v <= h - 1):
        return False
    u0 = min(int(u), w - 2)
    v0 = min(int(v), h - 2)
    au, av = u - u0, v - v0
    for c in range(3):
        top = (1.0 - au) * img[v0, u0, c] + au * img[v0, u0 + 1, c]
        bot = (1.0 - au) * img[v0 + 1, u0, c] + au * img[v0 + 1, u0 + 1, c]
        out[c] = (1.0 - av) * top + av * bot
    return True


@numba.njit(cache=True)
def _update_kernel(
    points, colours, fill_only, splat_mul, fac_v, fac_u, tags, src, pv, pu, pr, origin, device, height, width, focal_px, splat,
    splat_scale, max_splat, planes, depth, valid, stamp, frame, trusted_r, removal_r, zbuf, winner, touched,
    row_sc, col_sc, freed, use_freed, lookup, img, rot, trans, cam, dist, jump_rel, frame_id,
    last_frame, last_rule, last_src, last_tag, vote, tau, ratio, min_votes, n_same, n_cand, cand_depth,
    small_gate, gate_jump,
):  # pragma: no cover - compiled
    n = points.shape[0]
    n_touched = 0
    row_px = height / math.pi
    col_px = width / (2.0 * math.pi)
    for i in range(n):
        if not (np.isfinite(points[i, 0]) and np.isfinite(points[i, 1]) and np.isfinite(points[i, 2])):
            continue
        if not (np.isfinite(colours[i, 0]) and np.isfinite(colours[i, 1]) and np.isfinite(colours[i, 2])):
            continue
        r = pr[i]
        if not r > 0.0:
            continue
        v, u = pv[i], pu[i]
        row = min(int(v), height - 1)
        col = int(u)
        col = col - width if col >= width else col
        r0, r1, c0, c1 = row, row, col, col
        if splat and splat_mul[i] > 0.0:
            ex = points[i, 0] - device[0]
            ey = points[i, 1] - device[1]
            ez = points[i, 2] - device[2]
            angle = splat_mul[i] * splat_scale * math.sqrt(ex * ex + ey * ey + ez * ez) / (focal_px * r)
            dx, dy = points[i, 0] - origin[0], points[i, 1] - origin[1]
            s = max(math.sqrt(dx * dx + dy * dy) / r, 1e-6)
            r0, r1 = _span(v, 0.5 * angle * row_px * fac_v[i], max_splat)
            c0, c1 = _span(u, 0.5 * angle * col_px / s * fac_u[i], min(max_splat / s, width // 2))
        for rr in range(r0, r1 + 1):
            if rr < 0 or rr >= height:
                continue
            for cc0 in range(c0, c1 + 1):
                cc = cc0 % width
                if stamp[rr, cc] != frame:
                    stamp[rr, cc] = frame
                    zbuf[rr, cc] = r
                    winner[rr, cc] = i
                    touched[n_touched] = rr * width + cc
                    n_touched += 1
                elif r < zbuf[rr, cc]:
                    zbuf[rr, cc] = r
                    winner[rr, cc] = i
    ox, oy, oz = device[0] - origin[0], device[1] - origin[1], device[2] - origin[2]
    dev_r = math.sqrt(ox * ox + oy * oy + oz * oz)
    trusted = dev_r < trusted_r
    counts = np.zeros(6, np.int64)
    col3 = np.zeros(3)
    for k in range(n_touched):
        p = touched[k]
        rr = p // width
        cc = p - rr * width
        r = zbuf[rr, cc]
        i = winner[rr, cc]
        st = row_sc[rr, 0]
        ux, uy, uz = st * col_sc[cc, 1], st * col_sc[cc, 0], row_sc[rr, 1]
        rule = 0
        stored = depth[rr, cc]
        along = ox * ux + oy * uy + oz * uz
        if along > 0.0:
            qx, qy, qz = ox - along * ux, oy - along * uy, oz - along * uz
            to_ray = math.sqrt(qx * qx + qy * qy + qz * qz)
        else:
            to_ray = dev_r
        new_depth = r
        voted = False
        if not valid[rr, cc]:
            rule = 1
        elif vote:
            # Closer surfaces need votes: a candidate closer than the stored surface by more than
            # tau takes the pixel once it was seen in max(min_votes, ratio · n_same) frames; samples
            # within tau of the stored depth support it (and refresh it when closer, as the library).
            if trusted:
                rule = 3
            elif to_ray < removal_r and not (along > stored or along > r):
                rule = 4
            elif use_freed and freed[rr, cc]:
                rule = 5
            elif r >= (1.0 - tau) * stored:
                if r <= (1.0 + tau) * stored:
                    n_same[rr, cc] = min(n_same[rr, cc] + 1, 10000)
                    if r < stored and not fill_only[i]:
                        rule = 2
            elif not fill_only[i]:
                cd = cand_depth[rr, cc]
                if n_cand[rr, cc] > 0 and abs(r - cd) <= tau * cd:
                    n_cand[rr, cc] += 1
                    cand_depth[rr, cc] = 0.5 * (cd + r)
                else:
                    n_cand[rr, cc] = 1
                    cand_depth[rr, cc] = r
                if n_cand[rr, cc] >= max(min_votes, ratio * n_same[rr, cc]):
                    rule = 2
                    voted = True
                    new_depth = cand_depth[rr, cc]
        elif r < stored and (not fill_only[i] or r > (1.0 - jump_rel) * stored) and not (
                small_gate[i] and r > (1.0 - gate_jump) * stored):
            rule = 2
        elif trusted:
            rule = 3
        elif to_ray < removal_r and not (along > stored or along > r):
            rule = 4
        elif use_freed and freed[rr, cc]:
            rule = 5
        if rule > 0:
            counts[0] += 1
            counts[rule] += 1
            got = False
            if lookup:
                got = _lookup(img, rot, trans, cam, dist, origin[0] + r * ux, origin[1] + r * uy, origin[2] + r * uz, col3)
            for c in range(3):
                planes[c, rr, cc] = col3[c] if got else colours[i, c]
            if voted:  # the candidate's mean depth, and its votes become the support
                depth[rr, cc] = new_depth
                n_same[rr, cc] = n_cand[rr, cc]
                n_cand[rr, cc] = 0
            else:
                depth[rr, cc] = r if (not valid[rr, cc] or rule == 5) else 0.5 * (stored + r)
                if rule != 2:  # a new surface (empty, trusted, removal, freed)
                    n_same[rr, cc] = 1
                    n_cand[rr, cc] = 0
            valid[rr, cc] = True
            last_frame[rr, cc] = frame_id
            last_rule[rr, cc] = rule
            last_src[rr, cc] = src[i]
            last_tag[rr, cc] = tags[i]
    return n_touched, counts


@numba.njit(cache=True)
def _free_space(depth, valid, origin, row_sc, col_sc, rot_cw, t_cw, cam, dist, fdepth, fmeasured, k, tol_rel, tol_abs,
                freed):  # pragma: no cover - compiled
    """Map pixels whose stored point the frame sees through: the point projects into the frame
    where every measured pixel of the (2k+1)² neighbourhood lies farther (along z) than the point by
    more than tol_rel · z + tol_abs (and all of them are measured). Returns how many."""
    height, width = depth.shape
    fh, fw = fdepth.shape
    n = 0
    for rr in range(height):
        st, ct = row_sc[rr, 0], row_sc[rr, 1]
        for cc in range(width):
            freed[rr, cc] = False
            if not valid[rr, cc]:
                continue
            d = depth[rr, cc]
            px = origin[0] + d * st * col_sc[cc, 1]
            py = origin[1] + d * st * col_sc[cc, 0]
            pz = origin[2] + d * ct
            z = rot_cw[2, 0] * px + rot_cw[2, 1] * py + rot_cw[2, 2] * pz + t_cw[2]
            if not z > 0.1:
                continue
            x = rot_cw[0, 0] * px + rot_cw[0, 1] * py + rot_cw[0, 2] * pz + t_cw[0]
            y = rot_cw[1, 0] * px + rot_cw[1, 1] * py + rot_cw[1, 2] * pz + t_cw[1]
            xn, yn = x / z, y / z
            if abs(xn) > 0.8 or abs(yn) > 0.65:  # well outside the 58.5° × 46.5° view
                continue
            xd, yd = _distort(xn, yn, dist[0], dist[1], dist[2], dist[3], dist[4])
            col = int(math.floor(cam[0] * xd + cam[2] + 0.5))  # noqa: RUF046
            row = int(math.floor(cam[1] * yd + cam[3] + 0.5))  # noqa: RUF046
            if row - k < 0 or row + k >= fh or col - k < 0 or col + k >= fw:
                continue
            lim = z * (1.0 + tol_rel) + tol_abs
            ok = True
            for a in range(row - k, row + k + 1):
                for b in range(col - k, col + k + 1):
                    if not fmeasured[a, b] or fdepth[a, b] <= lim:
                        ok = False
                        break
                if not ok:
                    break
            if ok:
                freed[rr, cc] = True
                n += 1
    return n


@numba.njit(cache=True)
def _equirect(points, origin, height, width):  # pragma: no cover - compiled
    n = points.shape[0]
    v, u, r = np.empty(n), np.empty(n), np.empty(n)
    kv, ku = height / math.pi, width / (2.0 * math.pi)
    for i in range(n):
        dx, dy, dz = points[i, 0] - origin[0], points[i, 1] - origin[1], points[i, 2] - origin[2]
        h = math.sqrt(dx * dx + dy * dy)
        r[i] = math.sqrt(h * h + dz * dz)
        v[i] = math.atan2(h, dz) * kv
        u[i] = (math.atan2(dy, dx) + math.pi) * ku
    return v, u, r


def trig_tables(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    theta = np.pi * (np.arange(height) + 0.5) / height
    phi = 2.0 * np.pi * (np.arange(width) + 0.5) / width - np.pi
    return (np.stack([np.sin(theta), np.cos(theta)], -1).astype(np.float32),
            np.stack([np.sin(phi), np.cos(phi)], -1).astype(np.float32))


# ------------------------------------------------------------------------------------------------
# 3. Captures: the EnvironmentCapture loop over cached frames, with the variants
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Variant:
    """One capture configuration. Defaults = the library's defaults (CaptureConfig())."""

    name: str
    #: edge margin (frame px) of samples that may only fill empty pixels (library: 2); None: off.
    edge_margin_px: int | None = 2
    #: the margin applies only to "closer" takeovers by more than this fraction of the stored depth
    #: (None: to every "closer" takeover, as the library).
    margin_jump_rel: float | None = None
    #: margin only around the near (foreground) side of depth jumps, this wide (overrides the above).
    near_margin_px: int | None = None
    #: which filled pixels are projected: all | none | plane_consistent | not_edge (not within
    #: filled_edge_px of an edge)
    filled: str = "all"
    filled_edge_px: int = 2
    #: samples flagged fill-only splat one pixel instead of their footprint.
    edge_centre_only: bool = False
    #: drop (erode) samples within this many px of a near-side edge entirely.
    erode_near_px: int | None = None
    #: depth denoising before projection: None | "plane5" (edge-aware plane fit of 1/z in 5×5)
    denoise: str | None = None
    #: colour per map pixel from the bilinear colour image at the splat's pixel centre ("image")
    #: instead of one colour per sample ("sample").
    colour: str = "sample"
    #: free-space carving: None | "take" (a seen-through pixel takes this frame's sample) |
    #: "invalidate" (… and is emptied when no sample lands there)
    carve: str | None = None
    carve_k: int = 1
    carve_tol_rel: float = 0.05
    carve_tol_abs_m: float = 0.02
    #: sources: depth measured | true_on_measured (true z at measured pixels, holes filled as usual)
    #: | perfect (true z at every in-range pixel, no holes); colour measured | true (ray radiance)
    depth_src: str = "measured"
    colour_src: str = "measured"
    #: estimated | exact (diag of true gain ratios) | identity
    ccm: str = "estimated"
    splat: bool = True
    splat_scale: float = 1.0
    em_height: int | None = None
    #: synthetic sensor: None | "perfect" (ToF rays) | "perfect2x" (2× denser rays, f = 400)
    sensor: str | None = None
    #: samples whose position seen from the origin is uncertain by more than this many map rows (1 σ
    #: of the 1 % range noise, projected across the origin's ray) may only fill (no "closer")
    angular_gate_px: float | None = None
    #: footprint from the surface's normal (plane fit, 5×5): the sample's patch on the surface,
    #: stretched by 1/cos of the device's incidence, projected into the origin's view (foreshortened
    #: there), instead of an isotropic range / f
    aniso: bool = False
    #: "closer" by votes (None: the library's running minimum): a closer candidate (by > vote_tau)
    #: takes over once seen in max(vote_min, vote · n_same) frames
    vote: float | None = None
    #: samples on surfaces seen from the origin at grazing incidence (|cos| below this, from a 5×5
    #: plane-fit normal) may not take over by "closer" when the takeover is by less than
    #: grazing_jump of the stored depth (a nearby surface, e.g. the table just in front of a panel)
    grazing_cos: float | None = None
    grazing_jump: float = 0.3
    vote_tau: float = 0.05
    vote_min: int = 2


class StudyMap:
    """A library EnvironmentMap (so collect_pairs works on it) plus the update scratch and the
    per-pixel record of the last write."""

    def __init__(self, height: int, width: int, origin: np.ndarray) -> None:
        from rgbd_envmap.envmap import EnvironmentMap
        self.em = EnvironmentMap(height, width, origin)
        shape = (height, width)
        self.stamp = np.zeros(shape, np.int32)
        self.zbuf = np.zeros(shape, np.float32)
        self.winner = np.zeros(shape, np.int32)
        self.touched = np.zeros(height * width, np.int64)
        self.freed = np.zeros(shape, bool)
        self.last_frame = np.full(shape, -1, np.int32)
        self.last_rule = np.zeros(shape, np.int8)
        self.last_src = np.full(shape, -1, np.int32)
        self.last_tag = np.zeros(shape, np.int8)
        self.frame = 0
        self.row_sc, self.col_sc = trig_tables(height, width)
        self.rule_counts = np.zeros(6, np.int64)
        self.n_freed = 0
        #: per pixel, frames from 6 s on whose winning sample lay > 5 % beyond the stored depth (the
        #: device saw a surface behind what the map holds) and was not taken
        self.behind_after_6s = np.zeros(shape, np.int16)
        self.n_same = np.zeros(shape, np.int32)
        self.n_cand = np.zeros(shape, np.int32)
        self.cand_depth = np.zeros(shape, np.float32)


@dataclass
class FrameData:
    """What one capture step consumes (after a variant's substitutions)."""

    index: int
    raw_rgb: np.ndarray
    raw_depth: np.ndarray
    raw_known: np.ndarray
    reliable: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    known: np.ndarray
    T: RigidTransform
    intr: Intrinsics
    t_s: float = 0.0
    T_colour_from_world: np.ndarray | None = None
    srgb8: np.ndarray | None = None
    gains: np.ndarray | None = None


@numba.njit(cache=True)
def _plane_denoise(depth, known, rays, half, tol_rel, min_inliers):  # pragma: no cover - compiled
    """Edge-aware denoising: at every known pixel, least-squares plane 1/z = a·x + b·y + c (x, y the
    pixel's normalised ray relative to the centre's; exact for a plane) over the known pixels of the
    (2·half+1)² window whose depth lies within tol_rel of the centre's, evaluated at the centre
    (c). Also returns the plane's unit normal in the camera frame, (a, b, c − a·x₀ − b·y₀) normalised
    (zeros where no fit). Scalar sums and Cramer's rule: no allocation per pixel."""
    h, w = depth.shape
    out = depth.copy()
    normal = np.zeros((h, w, 3))
    for r in range(h):
        for c in range(w):
            if not known[r, c]:
                continue
            z0 = depth[r, c]
            x0, y0 = rays[r, c, 0], rays[r, c, 1]
            sxx = sxy = sx = syy = sy = s1 = 0.0
            bx = by = b1 = 0.0
            n = 0
            for a in range(max(r - half, 0), min(r + half, h - 1) + 1):
                for e in range(max(c - half, 0), min(c + half, w - 1) + 1):
                    if not known[a, e]:
                        continue
                    z = depth[a, e]
                    if abs(z - z0) > tol_rel * z0:
                        continue
                    x = rays[a, e, 0] - x0
                    y = rays[a, e, 1] - y0
                    q = 1.0 / z
                    sxx += x * x
                    sxy += x * y
                    sx += x
                    syy += y * y
                    sy += y
                    s1 += 1.0
                    bx += x * q
                    by += y * q
                    b1 += q
                    n += 1
            if n < min_inliers:
                continue
            # Cramer's rule on [[sxx, sxy, sx], [sxy, syy, sy], [sx, sy, s1]] · (a, b, c) = (bx, by, b1)
            c00 = syy * s1 - sy * sy
            c01 = sy * sx - sxy * s1
            c02 = sxy * sy - syy * sx
            det = sxx * c00 + sxy * c01 + sx * c02
            if abs(det) < 1e-18:
                continue
            pa = (bx * c00 + by * c01 + b1 * c02) / det
            pb = (sxx * (by * s1 - sy * b1) - bx * (sxy * s1 - sy * sx) + sx * (sxy * b1 - by * sx)) / det
            pc = (sxx * (syy * b1 - sy * by) - sxy * (sxy * b1 - sy * bx) + sx * (sxy * by - syy * bx)) / det
            if pc > 0.0:
                out[r, c] = 1.0 / pc
                nc = pc - pa * x0 - pb * y0
                norm = math.sqrt(pa * pa + pb * pb + nc * nc)
                normal[r, c, 0] = pa / norm
                normal[r, c, 1] = pb / norm
                normal[r, c, 2] = nc / norm
    return out, normal


def _reingest(fr: dict, intr: Intrinsics, colour_intr: Intrinsics, depth: np.ndarray, measured: np.ndarray,
              pairs_from: np.ndarray | None = None) -> dict:
    """Re-run the ingest after the depth of the measured pixels changed: colour at the new 3-D
    points, reliability, eq. (1) hole filling, colour of the filled pixels. ``pairs_from`` limits
    the reliable (colour-pair) pixels, e.g. to what the real ToF could measure: a pair on an
    emitter pairs a clipped camera value with a clipped map value and biases the matrix."""
    from rgbd_envmap.depth import fill_holes
    from rgbd_envmap.ingest.tango import colour_filled_pixels
    from rgbd_envmap.types import RGBDFrame
    T_cd = RigidTransform(fr["T_colour_from_depth"], "colour", "depth")
    rays = pixel_rays(intr)
    rgb = np.zeros((*depth.shape, 3), np.float32)
    pts = rays[measured] * depth[measured, None]
    col, ok = colour_at_points(pts, fr["srgb8"], T_cd, colour_intr)
    known = measured.copy()
    known[measured] = ok
    rgb[measured] = col
    z = np.where(known, depth, 0.0).astype(np.float32)
    reliable = mark_reliable(rgb, z, known)
    if pairs_from is not None:
        reliable &= pairs_from
    T = RigidTransform(fr["T_world_from_depth"], "world", "depth")
    raw = RGBDFrame(rgb, z, known, T, intr, fr["timestamp_ns"])
    fd, fk = fill_holes(z, known)
    filled = colour_filled_pixels(raw, fd, fk, fr["srgb8"], T_cd, colour_intr)
    return {"raw_rgb": rgb, "raw_depth": z, "raw_known": known, "reliable": reliable,
            "rgb": filled.rgb, "depth": filled.depth_m, "known": filled.known}


class Session:
    """The cached frames plus the derived ground truth the variants need (computed lazily)."""

    def __init__(self, args, frames: list[dict]) -> None:
        self.args = args
        self.frames = frames
        self.sim = make_sim(args)
        self.origin = self.sim.scene.virtual_object_position
        self.intr = self.sim.calibration.depth
        self.colour_intr = self.sim.calibration.colour
        self.t_end = frames[-1]["t_s"]
        self._true_rgb: list[np.ndarray] | None = None
        self._perfect: dict[str, list[dict]] = {}
        self._gt: dict = {}

    def gt(self, height: int, t_s: float | None = None):
        t = self.t_end if t_s is None else t_s
        key = (height, round(t, 6))
        if key not in self._gt:
            self._gt[key] = render_envmap(self.sim.raycaster, self.origin, height, 2 * height, t)
        return self._gt[key]

    def true_rgb(self, i: int) -> np.ndarray:
        """(H, W, 3) true radiance along each ToF pixel's ray (true pose, frame time)."""
        if self._true_rgb is None:
            rays = pixel_rays(self.intr).reshape(-1, 3)
            dirs = rays / np.linalg.norm(rays, axis=1, keepdims=True)
            out = []
            for fr in self.frames:
                T = fr["true_T_world_from_depth"]
                hits = self.sim.raycaster.cast(T[:3, 3], dirs @ T[:3, :3].T, fr["t_s"], normals=False)
                out.append(hits.radiance.reshape(self.intr.height, self.intr.width, 3).astype(np.float32))
            self._true_rgb = out
        return self._true_rgb[i]

    def perfect_frames(self, kind: str) -> tuple[list[dict], Intrinsics]:
        """Noise-free frames at the ToF rays ("perfect") or 2× denser rays ("perfect2x"): true z of
        every hit within the ToF's 0.1–4 m, true radiance, at the true poses and frame times."""
        base = self.intr
        intr = base if kind == "perfect" else Intrinsics(
            2 * base.width, 2 * base.height, 2 * base.fx, 2 * base.fy, 2 * base.cx + 0.5, 2 * base.cy + 0.5, base.distortion)
        if kind not in self._perfect:
            rays = pixel_rays(intr).reshape(-1, 3)
            ray_len = np.linalg.norm(rays, axis=1)
            dirs = rays / ray_len[:, None]
            out = []
            for fr in self.frames:
                T = fr["true_T_world_from_depth"]
                hits = self.sim.raycaster.cast(T[:3, 3], dirs @ T[:3, :3].T, fr["t_s"], normals=False)
                ok = hits.hit & (hits.distance_m >= 0.1) & (hits.distance_m <= 4.0)
                z = np.where(ok, hits.distance_m / ray_len, 0.0).astype(np.float32).reshape(intr.height, intr.width)
                out.append({"depth": z, "known": ok.reshape(intr.height, intr.width),
                            "rgb": hits.radiance.reshape(intr.height, intr.width, 3).astype(np.float32)})
            self._perfect[kind] = out
        return self._perfect[kind], intr

    def frame_data(self, i: int, v: Variant) -> FrameData:
        fr = self.frames[i]
        T = RigidTransform(fr["T_world_from_depth"], "world", "depth")
        T_cw = fr["T_colour_from_depth"] @ np.linalg.inv(fr["T_world_from_depth"])
        if v.sensor is not None:
            pf, intr = self.perfect_frames(v.sensor)
            p = pf[i]
            T = RigidTransform(fr["true_T_world_from_depth"], "world", "depth")
            return FrameData(i, p["rgb"], p["depth"], p["known"], p["known"], p["rgb"], p["depth"], p["known"], T, intr,
                             fr["t_s"], T_cw, fr["srgb8"], fr["gains"])
        d = {k: fr[k] for k in ("raw_rgb", "raw_depth", "raw_known", "reliable", "rgb", "depth", "known")}
        if v.depth_src == "true_on_measured":
            d = _reingest(fr, self.intr, self.colour_intr, fr["true_depth"], fr["raw_known"] & fr["true_valid"])
        elif v.depth_src == "perfect":
            d = _reingest(fr, self.intr, self.colour_intr, fr["true_depth"], fr["true_valid"], fr["reliable"])
        if v.denoise is not None:
            half = {"plane3": 1, "plane5": 2, "plane7": 3}[v.denoise]
            z, _ = _plane_denoise(d["raw_depth"].astype(np.float64), d["raw_known"], pixel_rays(self.intr), half, 0.04, 6)
            d = _reingest(fr, self.intr, self.colour_intr, z.astype(np.float32), d["raw_known"])
        if v.colour_src == "true":
            t = self.true_rgb(i)
            d["raw_rgb"] = np.where(d["raw_known"][..., None], t, 0.0).astype(np.float32)
            d["rgb"] = np.where(d["known"][..., None], t, 0.0).astype(np.float32)
        return FrameData(i, d["raw_rgb"], d["raw_depth"], d["raw_known"], d["reliable"], d["rgb"], d["depth"], d["known"],
                         T, self.intr, fr["t_s"], T_cw, fr["srgb8"], fr["gains"])


def _edge_masks(depth: np.ndarray, known: np.ndarray, jump_rel: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """(near, far) sides of depth jumps among 8-neighbours; unknown neighbours count as far away."""
    far_val = np.where(known, depth, 1e3).astype(np.float32)
    near_val = np.where(known, depth, 0.0).astype(np.float32)
    k = np.ones((3, 3), np.uint8)
    mx = cv2.dilate(far_val, k)
    mn = cv2.erode(np.where(known, depth, 1e3).astype(np.float32), k)
    near = known & (mx > depth * (1.0 + jump_rel))
    far = known & (mn < depth / (1.0 + jump_rel)) & (near_val > 0)
    return near, far


def _dilate(mask: np.ndarray, px: int) -> np.ndarray:
    if px <= 0:
        return mask.copy()
    k = 2 * int(px) + 1
    return cv2.dilate(mask.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)


def run_capture(session: Session, v: Variant) -> dict:
    from rgbd_envmap.envmap import collect_pairs, frame_points
    height = v.em_height or session.args.em_height
    m = StudyMap(height, 2 * height, session.origin)
    em = m.em
    matrix = np.eye(3)
    lut = srgb8_to_linear_lut()
    cam_c = np.array([session.colour_intr.fx, session.colour_intr.fy, session.colour_intr.cx, session.colour_intr.cy])
    dist_c = np.asarray(session.colour_intr.distortion.coefficients, np.float64)
    g_ref = None
    skipped = 0
    projected = 0
    t0 = time.perf_counter()
    for i in range(len(session.frames)):
        f = session.frame_data(i, v)
        if g_ref is None:
            g_ref = f.gains
            matrix = np.eye(3)
        elif v.ccm == "identity" or v.sensor is not None or v.colour_src == "true":
            matrix = np.eye(3)
        elif v.ccm == "exact":
            matrix = np.diag(g_ref / f.gains)
        else:
            pts = frame_points(f.raw_depth, f.reliable, f.intr, f.T)
            src, dst = collect_pairs(em, pts, f.raw_rgb[f.reliable], 0.01)
            ccm = estimate_ccm(src, dst, method="ridge", max_mse=5e-2, min_pairs=500)
            if not ccm.accepted:
                skipped += 1
                continue
            matrix = np.array(ccm.matrix, np.float64)
        project(m, f, matrix, v, lut, cam_c, dist_c)
        projected += 1
    return {"variant": v, "map": m, "skipped": skipped, "projected": projected, "wall_s": time.perf_counter() - t0,
            "height": height}


def project(m: StudyMap, f: FrameData, matrix: np.ndarray, v: Variant, lut, cam_c, dist_c) -> None:
    from rgbd_envmap.envmap import frame_points
    em = m.em
    # Which pixels go in (CaptureConfig.filled_pixels and the prototypes).
    filled_px = f.known & ~f.raw_known
    if v.filled == "all":
        mask = f.known.copy()
    elif v.filled == "none":
        mask = f.known & f.raw_known
    elif v.filled == "plane_consistent":
        mask = f.known & (f.raw_known | discontinuity_test(f.depth, f.known).passed)
    elif v.filled == "not_edge":
        edge = f.known & ~discontinuity_test(f.depth, f.known).passed
        mask = f.known & ~(filled_px & _dilate(edge, v.filled_edge_px))
    else:
        raise ValueError(v.filled)
    near, _far = _edge_masks(f.depth, f.known)
    if v.erode_near_px:
        mask &= ~_dilate(near, v.erode_near_px - 1)
    # Samples that may only fill (the library's edge margin, or the near-side variant).
    fill_only_px = np.zeros_like(mask)
    if v.near_margin_px is not None:
        fill_only_px = _dilate(near, v.near_margin_px)
    elif v.edge_margin_px is not None:
        plane = discontinuity_test(f.depth, f.known).passed
        fill_only_px = _dilate(f.known & ~plane, v.edge_margin_px)
    pts = np.ascontiguousarray(frame_points(f.depth, mask, f.intr, f.T), np.float64)
    colours = np.ascontiguousarray(apply_ccm(f.rgb[mask], matrix), np.float32)
    fill_only = fill_only_px[mask]
    src = np.flatnonzero(mask.reshape(-1)).astype(np.int32)
    tags = (filled_px[mask] * TAG_FILLED + fill_only * TAG_FILL_ONLY).astype(np.int8)
    splat_mul = np.ones(len(pts), np.float32)
    if v.edge_centre_only:
        splat_mul[fill_only] = 0.0
    v_, u_, r_ = _equirect(pts, em.origin, em.height, em.width)
    device = f.T.translation.astype(np.float64)
    fac_v = np.ones(len(pts))
    fac_u = np.ones(len(pts))
    if v.aniso or v.angular_gate_px is not None:
        ray = pts - device
        rng = np.linalg.norm(ray, axis=1)
        a_dev = ray / rng[:, None]
        d = (pts - em.origin) / r_[:, None]
    if v.angular_gate_px is not None:
        sin_par = np.sqrt(np.clip(1.0 - np.einsum("ij,ij->i", a_dev, d) ** 2, 0.0, 1.0))
        sigma_rows = 0.01 * rng * sin_par / r_ * (em.height / np.pi)
        gated = sigma_rows > v.angular_gate_px
        fill_only = fill_only | gated
        tags = tags | (gated * TAG_FILL_ONLY).astype(np.int8)
    if v.aniso:
        fac_v, fac_u = _aniso_factors(f, mask, a_dev, rng, d, 0.5 * (f.intr.fx + f.intr.fy))
    small_gate = np.zeros(len(pts), bool)
    if v.grazing_cos is not None:
        n = _sample_normals(f, mask)
        ok = np.linalg.norm(n, axis=1) > 0.5
        d0 = (pts - em.origin) / r_[:, None]
        small_gate = ok & (np.abs(np.einsum("ij,ij->i", n, d0)) < v.grazing_cos)
    use_freed = v.carve is not None
    if use_freed:
        Tcw = np.linalg.inv(f.T.matrix)
        cam = np.array([f.intr.fx, f.intr.fy, f.intr.cx, f.intr.cy])
        m.n_freed += _free_space(em.depth_m, em.valid, em.origin, m.row_sc, m.col_sc, np.ascontiguousarray(Tcw[:3, :3]),
                                 np.ascontiguousarray(Tcw[:3, 3]), cam, np.asarray(f.intr.distortion.coefficients, np.float64),
                                 f.raw_depth, f.raw_known, v.carve_k, v.carve_tol_rel, v.carve_tol_abs_m, m.freed)
    lookup = v.colour == "image"
    if lookup:
        img = (lut[f.srgb8].reshape(-1, 3) @ matrix.T.astype(np.float32)).reshape(f.srgb8.shape).astype(np.float32)
        rot, trans = np.ascontiguousarray(f.T_colour_from_world[:3, :3]), np.ascontiguousarray(f.T_colour_from_world[:3, 3])
    else:
        img, rot, trans = np.zeros((2, 2, 3), np.float32), np.eye(3), np.zeros(3)
    m.frame += 1
    focal = 0.5 * (f.intr.fx + f.intr.fy)
    _, counts = _update_kernel(
        pts, colours, np.ascontiguousarray(fill_only), splat_mul, fac_v, fac_u, tags, src, v_, u_, r_, em.origin, device, em.height,
        em.width, float(focal), bool(v.splat), float(v.splat_scale), 24, em.radiance_planes, em.depth_m, em.valid,
        m.stamp, m.frame, 0.10, 0.03, m.zbuf, m.winner, m.touched, m.row_sc, m.col_sc, m.freed, use_freed, lookup,
        img, rot, trans, cam_c, dist_c, float(v.margin_jump_rel or 0.0), f.index, m.last_frame, m.last_rule, m.last_src, m.last_tag,
        v.vote is not None, float(v.vote_tau), float(v.vote or 0.0), int(v.vote_min), m.n_same, m.n_cand, m.cand_depth,
        small_gate, float(v.grazing_jump),
    )
    m.rule_counts += counts
    if f.t_s >= 6.0:
        hit = (m.stamp == m.frame) & em.valid & (m.zbuf > 1.05 * em.depth_m)
        m.behind_after_6s[hit] += 1
    if v.carve == "invalidate":
        gone = m.freed & (m.stamp != m.frame)
        em.valid[gone] = False
        m.last_rule[gone] = 0


def _sample_normals(f: FrameData, mask: np.ndarray) -> np.ndarray:
    """(N, 3) world unit normals of the mask's samples from a 5×5 plane fit (zeros: no fit)."""
    _, nrm = _plane_denoise(f.depth.astype(np.float64), f.known, pixel_rays(f.intr), 2, 0.04, 6)
    return nrm[mask] @ f.T.rotation.T


def _aniso_factors(f: FrameData, mask: np.ndarray, a_dev: np.ndarray, rng: np.ndarray, d: np.ndarray, focal: float):
    """Per-sample factors on the isotropic footprint's row and column half-extents: the sample's
    patch (half-size range / 2f facing the device, stretched by 1/|cos| of the device's incidence
    along the surface's tilt) projected into the origin's view, from a 5×5 plane-fit normal."""
    n = _sample_normals(f, mask)
    ok = np.linalg.norm(n, axis=1) > 0.5
    cos_dev = np.einsum("ij,ij->i", n, a_dev)
    n = np.where((cos_dev > 0)[:, None], -n, n)
    cos_dev = np.clip(np.abs(cos_dev), 0.2, 1.0)
    t1 = a_dev + np.einsum("ij,ij->i", a_dev, n)[:, None] * n * -1.0
    t1n = np.linalg.norm(t1, axis=1)
    face_on = t1n < 1e-6
    t1 = np.where(face_on[:, None], np.cross(n, [0.0, 0.0, 1.0]) + np.cross(n, [1.0, 0.0, 0.0]) * 1e-3, t1)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1), 1e-12)[:, None]
    t2 = np.cross(n, t1)
    half = 0.5 * rng / focal
    l1, l2 = half / cos_dev, half
    sin_t = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    cos_p, sin_p = d[:, 0] / sin_t, d[:, 1] / sin_t
    e_t = np.stack([d[:, 2] * cos_p, d[:, 2] * sin_p, -sin_t], 1)
    e_p = np.stack([-sin_p, cos_p, np.zeros_like(sin_p)], 1)
    ext_t = np.hypot(l1 * np.einsum("ij,ij->i", t1, e_t), l2 * np.einsum("ij,ij->i", t2, e_t))
    ext_p = np.hypot(l1 * np.einsum("ij,ij->i", t1, e_p), l2 * np.einsum("ij,ij->i", t2, e_p))
    fac_v = np.where(ok, np.clip(ext_t / half, 0.05, 4.0), 1.0)
    fac_u = np.where(ok, np.clip(ext_p / half, 0.05, 4.0), 1.0)
    return np.ascontiguousarray(fac_v), np.ascontiguousarray(fac_u)


def scores(em, gt) -> dict:
    covered = em.valid & gt.valid
    a = np.clip(em.radiance, 0, 1)
    b = np.clip(gt.radiance, 0, 1)
    return {"coverage": coverage_of(em.valid, gt.valid), "ws_psnr_db": ws_psnr(a, b, covered)}


# ------------------------------------------------------------------------------------------------
# 4. The error budget
# ------------------------------------------------------------------------------------------------

def _wrap_distance(edge: np.ndarray, pad: int = 64) -> np.ndarray:
    """L2 distance (map px) of every pixel to the nearest edge pixel, longitude wrapping."""
    ext = np.concatenate([edge[:, -pad:], edge, edge[:, :pad]], axis=1)
    d = cv2.distanceTransform((~ext).astype(np.uint8), cv2.DIST_L2, 5)
    return d[:, pad:-pad]


def gt_edges(gt, jump_rel: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """(geometric, texture) edge masks of a true map: a 4-neighbour of another object or a depth
    jump > jump_rel (geometric); a radiance step > 0.01 within one object (texture)."""
    obj, d = gt.object_index, gt.distance_m
    rad = np.clip(gt.radiance, 0, 1)
    geo = np.zeros(obj.shape, bool)
    tex = np.zeros(obj.shape, bool)
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        a, b = tuple(a), tuple(b)
        if axis == 1:  # wrap
            o2, d2, r2 = np.roll(obj, 1, 1), np.roll(d, 1, 1), np.roll(rad, 1, 1)
            g = (o2 != obj) | (np.abs(d2 - d) > jump_rel * np.minimum(d, d2))
            t = (o2 == obj) & (np.abs(r2 - rad).max(-1) > 0.01)
            geo |= g | np.roll(g, -1, 1)
            tex |= t | np.roll(t, -1, 1)
        else:
            g = (obj[a] != obj[b]) | (np.abs(d[a] - d[b]) > jump_rel * np.minimum(d[a], d[b]))
            t = (obj[a] == obj[b]) & (np.abs(rad[a] - rad[b]).max(-1) > 0.01)
            geo[a] |= g
            geo[b] |= g
            tex[a] |= t
            tex[b] |= t
    return geo, tex


class Budget:
    """Solid-angle-weighted squared error of a captured map against a true map, by category."""

    def __init__(self, em, gt) -> None:
        self.covered = em.valid & gt.valid
        w = equirect_solid_angles(em.height, em.width)
        diff = np.clip(em.radiance, 0, 1).astype(np.float64) - np.clip(gt.radiance, 0, 1)
        self.diff = np.where(self.covered[..., None], diff, 0.0)
        self.err = np.where(self.covered, w * (self.diff ** 2).sum(-1), 0.0)
        self.w = np.where(self.covered, w, 0.0)
        self.total = float(self.err.sum())
        self.norm = 3.0 * float(self.w.sum())

    def psnr(self, err_sum: float | None = None) -> float:
        e = self.total if err_sum is None else err_sum
        return float(-10.0 * np.log10(max(e, 1e-30) / self.norm))

    def row(self, label: str, sel: np.ndarray) -> dict:
        sel = sel & self.covered
        e = float(self.err[sel].sum())
        area = float(self.w[sel].sum())
        own = -10.0 * np.log10(e / (3.0 * area)) if e > 0 and area > 0 else float("inf")
        return {"label": label, "area": area / (self.norm / 3.0), "share": e / self.total,
                "gain_db": self.psnr(self.total - e) - self.psnr(), "own_db": own}

    def table(self, rows: list[dict], title: str) -> list[str]:
        out = [f"| {title} | share of covered solid angle | share of squared error | dB gained if this error were 0 | own WS-PSNR (dB) |",
               "|---|---:|---:|---:|---:|"]
        for r in rows:
            out.append(f"| {r['label']} | {100 * r['area']:.1f} % | {100 * r['share']:.1f} % | {r['gain_db']:+.2f} | {r['own_db']:.1f} |")
        return out


def sample_objects(session: Session, m: StudyMap) -> np.ndarray:
    """(H, W) true object of the frame pixel whose sample last wrote each map pixel (−2: none)."""
    out = np.full(m.last_frame.shape, -2, np.int16)
    for i in np.unique(m.last_frame[m.last_frame >= 0]):
        sel = m.last_frame == i
        obj = session.frames[i]["object_index"].reshape(-1)
        src = m.last_src[sel]
        ok = src < obj.size  # perfect2x sources index a larger grid: no truth there
        vals = np.full(src.shape, -2, np.int16)
        vals[ok] = obj[src[ok]]
        out[sel] = vals
    return out


def last_write_gt(session: Session, m: StudyMap, height: int):
    """The true map as it was when each pixel was last written: the scene has three states in the
    default session (box until 6 s, lamp at full until 8 s)."""
    times = np.array([fr["t_s"] for fr in session.frames])
    t_pix = np.where(m.last_frame >= 0, times[np.maximum(m.last_frame, 0)], session.t_end)
    states = [(-1.0, 6.0, 5.9), (6.0, 8.0, 7.0), (8.0, 1e9, session.t_end)]
    rad = np.zeros((height, 2 * height, 3), np.float32)
    valid = np.zeros((height, 2 * height), bool)
    for lo, hi, t in states:
        g = session.gt(height, t)
        sel = (t_pix >= lo) & (t_pix < hi)
        rad[sel] = g.radiance[sel]
        valid[sel] = g.valid[sel]
    end = session.gt(height)
    return type(end)(rad, end.distance_m, valid, end.object_index, end.origin)


def budget_report(session: Session, cap: dict, perfect: dict | None = None) -> tuple[list[str], dict]:
    m: StudyMap = cap["map"]
    em = m.em
    h = cap["height"]
    gt = session.gt(h)
    b = Budget(em, gt)
    names = [o.name for o in session.sim.scene.objects]
    lines = [f"Total: WS-PSNR {b.psnr():.2f} dB over {100 * coverage_of(em.valid, gt.valid):.1f} % coverage.", ""]
    # by true object
    rows = []
    for k in np.unique(gt.object_index[b.covered]):
        rows.append(b.row(names[k] if k >= 0 else "none", gt.object_index == k))
    rows.sort(key=lambda r: -r["share"])
    top = rows[:12]
    rest = rows[12:]
    if rest:
        top.append({"label": f"{len(rest)} other objects", "area": sum(r["area"] for r in rest),
                    "share": sum(r["share"] for r in rest), "gain_db": float("nan"), "own_db": float("nan")})
    lines += ["**By true object** (the true map at t_end):", ""] + b.table(top, "object") + [""]
    # by distance to a true geometric edge / texture edge
    geo, tex = gt_edges(gt)
    dg = _wrap_distance(geo)
    dt = _wrap_distance(tex)
    rows = [b.row("≤ 2 px from a geometric edge", dg <= 2), b.row("2–5 px", (dg > 2) & (dg <= 5)),
            b.row("5–10 px", (dg > 5) & (dg <= 10)), b.row("> 10 px", dg > 10)]
    lines += [("**By distance to a true depth / object edge** (map pixels; an edge: another object or a depth step > 5 % "
              "between 4-neighbours):"), ""] + b.table(rows, "distance") + [""]
    # right surface?
    sobj = sample_objects(session, m)
    box = names.index("removed_box")
    gt_then = last_write_gt(session, m, h)
    stale = (sobj == box) & (gt.object_index != box)
    wrong = (sobj != gt.object_index) & ~stale & (sobj >= -1)
    depth_bad = np.abs(em.depth_m - gt.distance_m) > 0.05 * gt.distance_m
    rows = [b.row("sample of the true object", (sobj == gt.object_index)),
            b.row("… with map depth within 5 % of the truth", (sobj == gt.object_index) & ~depth_bad),
            b.row("… with map depth off by > 5 %", (sobj == gt.object_index) & depth_bad),
            b.row("sample of another object (wrong surface)", wrong),
            b.row("the removed box (stale since 6 s)", stale)]
    lines += ["**By the surface the last-writing sample came from** (the true object along that frame pixel's ray):", ""]
    lines += b.table(rows, "last writer") + [""]
    # filled vs measured, fill-only flag, rule
    filled = (m.last_tag & TAG_FILLED) != 0
    fo = (m.last_tag & TAG_FILL_ONLY) != 0
    rows = [b.row("measured sample, interior", ~filled & ~fo), b.row("measured sample, edge margin (fill-only)", ~filled & fo),
            b.row("hole-filled sample, interior", filled & ~fo), b.row("hole-filled sample, edge margin (fill-only)", filled & fo)]
    lines += ["**By the kind of sample that last wrote the pixel:**", ""] + b.table(rows, "sample") + [""]
    rows = [b.row(f"rule {RULES[k]}", m.last_rule == k) for k in range(1, 6) if (b.covered & (m.last_rule == k)).any()]
    lines += ["**By the rule that last wrote the pixel:**", ""] + b.table(rows, "rule") + [""]
    # wrong surface: which object over which
    sel = wrong & b.covered
    keys = (sobj[sel].astype(np.int64) + 2) * 100 + gt.object_index[sel].astype(np.int64)
    uniq, inv = np.unique(keys, return_inverse=True)
    sums = np.bincount(inv, weights=b.err[sel])
    order = np.argsort(-sums)[:8]
    lines += ["**Wrong surface, largest pairs** (sample's object shown where the true map has another):", "",
              "| sample object → true object | share of squared error |", "|---|---:|"]
    for j in order:
        so, go = divmod(int(uniq[j]), 100)
        so -= 2
        lines.append(f"| {names[so] if so >= 0 else 'none'} → {names[go] if go >= 0 else 'none'} | {100 * sums[j] / b.total:.1f} % |")
    lines.append("")
    # how the three largest pairs were written
    times = np.array([fr["t_s"] for fr in session.frames])
    lines += [("How the three largest pairs were written (error-weighted): map rows (5th–95th percentile), rule, sample "
              "kind, written at t ≥ 10 s (inward orbit), map depth / true depth (median):"), "",
              "| pair | rows | rule closer / empty / freed | measured interior / fill-only / hole-filled | t ≥ 10 s | depth ratio |",
              "|---|---|---|---|---:|---:|"]
    for j in order[:3]:
        so, go = divmod(int(uniq[j]), 100)
        so -= 2
        psel = sel & (sobj == so) & (gt.object_index == go)
        e = b.err[psel]
        rows_ = np.nonzero(psel)[0]
        rule = np.bincount(m.last_rule[psel], weights=e, minlength=6) / e.sum()
        tag = np.bincount(m.last_tag[psel], weights=e, minlength=4) / e.sum()
        late = float(np.average(times[m.last_frame[psel]] >= 10.0, weights=e))
        ratio = float(np.median(em.depth_m[psel] / gt.distance_m[psel]))
        lines.append(f"| {names[so]} → {names[go]} | {np.percentile(rows_, 5):.0f}–{np.percentile(rows_, 95):.0f} | "
                     f"{100 * rule[2]:.0f} / {100 * rule[1]:.0f} / {100 * rule[5]:.0f} % | {100 * tag[0]:.0f} / "
                     f"{100 * (tag[2] + tag[3]):.0f} / {100 * (tag[1] + tag[3]):.0f} % | {100 * late:.0f} % | {ratio:.2f} |")
    lines.append("")
    # texture regions far from geometric edges: bias or resampling?
    textured = [i for i, o in enumerate(session.sim.scene.objects) if o.texture is not None]
    lines += [("**Textured objects, > 5 px from any geometric edge, right surface**: the squared error split into the "
              "per-object mean colour error (bias) and the rest; near (≤ 2 px) / far from a texture edge."), "",
              "| object | share of squared error | bias share of it | ≤ 2 px from a texture edge | own WS-PSNR (dB) | perfect sensor, same pixels (dB) |",
              "|---|---:|---:|---:|---:|---:|"]
    pb = Budget(perfect["map"].em, gt) if perfect is not None else None
    for k in textured:
        sel = b.covered & (gt.object_index == k) & (dg > 5) & (sobj == k)
        if sel.sum() < 50 or b.err[sel].sum() == 0:
            continue
        e = b.err[sel].sum()
        wsum = b.w[sel].sum()
        mean = (b.diff[sel] * b.w[sel, None]).sum(0) / wsum
        bias = wsum * float((mean ** 2).sum())
        near_t = b.err[sel & (dt <= 2)].sum()
        own = -10 * np.log10(e / (3 * wsum))
        pown = float("nan")
        if pb is not None:
            ps = sel & pb.covered
            pown = -10 * np.log10(pb.err[ps].sum() / (3 * pb.w[ps].sum())) if ps.any() else float("nan")
        lines.append(f"| {names[k]} | {100 * e / b.total:.1f} % | {100 * bias / e:.0f} % | {100 * near_t / e:.0f} % | {own:.1f} | {pown:.1f} |")
    lines.append("")
    # fairness of the comparison time
    s_then = scores(em, gt_then)
    lines += [(f"Against the true map **as it was when each pixel was last written** (box present before 6 s, lamp "
              f"full before 8 s): WS-PSNR {s_then['ws_psnr_db']:.2f} dB (against t_end: {b.psnr():.2f} dB)."), ""]
    info = {"b": b, "gt": gt, "dg": dg, "dt": dt, "sobj": sobj, "stale": stale, "wrong": wrong}
    return lines, info


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=20.0)
    p.add_argument("--colour-size", default="960x540")
    p.add_argument("--em-height", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cache", default="/tmp/em_study")
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--figures", type=Path, default=None)
    p.add_argument("--stage", default="all", help="'cache' only simulates; 'all' runs everything")
    return p.parse_args(argv)


def library_capture(session: Session) -> EnvironmentMap:  # noqa: F821
    """The library's EnvironmentCapture (defaults) over the cached frames, to check the copy."""
    from rgbd_envmap.pipeline.capture import CaptureConfig, EnvironmentCapture
    from rgbd_envmap.types import RGBDFrame
    from rgbd_envmap.envmap import UpdateConfig
    # colour_average=1: the colour replaced, as in the copy (the library averages since 2026-12-01).
    cap = EnvironmentCapture(session.origin, CaptureConfig(height=session.args.em_height, width=2 * session.args.em_height,
                                                           update=UpdateConfig(colour_average=1)))
    for fr in session.frames:
        T = RigidTransform(fr["T_world_from_depth"], "world", "depth")
        raw = RGBDFrame(fr["raw_rgb"], fr["raw_depth"], fr["raw_known"], T, session.intr, fr["timestamp_ns"])
        filled = RGBDFrame(fr["rgb"], fr["depth"], fr["known"], T, session.intr, fr["timestamp_ns"])
        cap.process(raw, fr["reliable"], filled)
    return cap.em


def evaluate(session: Session, cap: dict) -> dict:
    """Scores of one capture: coverage and WS-PSNR against the true map at t_end, WS-PSNR with the
    removed box's pixels left out, and against the true map as it was at each pixel's last write."""
    names = [o.name for o in session.sim.scene.objects]
    box = names.index("removed_box")
    m = cap["map"]
    h = cap["height"]
    gt = session.gt(h)
    sc = scores(m.em, gt)
    box_px = session.gt(h, 5.9).object_index == box
    keep = m.em.valid.copy()
    m.em.valid[:] &= ~box_px
    no_box = scores(m.em, gt)["ws_psnr_db"]
    m.em.valid[:] = keep
    last = scores(m.em, last_write_gt(session, m, h))["ws_psnr_db"]
    return {"name": cap["variant"].name, "coverage": sc["coverage"], "ws_psnr_db": sc["ws_psnr_db"], "no_box_db": no_box,
            "last_write_db": last, "projected": cap["projected"], "wall_s": cap["wall_s"]}


def variant_table(rows: list[dict], base_psnr: float) -> list[str]:
    out = ["| capture | coverage | WS-PSNR (dB) | Δ vs default (dB) | without the box's pixels (dB) | vs truth at last-write time (dB) | frames projected | wall (s) |",
           "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['name']} | {100 * r['coverage']:.1f} % | {r['ws_psnr_db']:.2f} | {r['ws_psnr_db'] - base_psnr:+.2f} | "
                   f"{r['no_box_db']:.2f} | {r['last_write_db']:.2f} | {r['projected']} | {r['wall_s']:.0f} |")
    return out


def slim(cap: dict) -> dict:
    """Drop a capture's update scratch (keep the map and the last-write record)."""
    m = cap["map"]
    for k in ("stamp", "zbuf", "winner", "touched", "freed", "n_same", "n_cand", "cand_depth"):
        setattr(m, k, None)
    return cap


def box_report(session: Session, cap: dict, carve_cap: dict | None) -> list[str]:
    """How many of the removed box's pixels any rule could replace on this trajectory."""
    names = [o.name for o in session.sim.scene.objects]
    box = names.index("removed_box")
    m: StudyMap = cap["map"]
    h = cap["height"]
    before = session.gt(h, 5.9)
    box_px = before.object_index == box
    sobj = sample_objects(session, m)
    held = box_px & m.em.valid & (sobj == box)
    # Closest approach of the device to each box pixel's ray after 6 s (removal rule: < 3 cm).
    dirs = equirect_directions(h, 2 * h)[held].astype(np.float64)
    best = np.full(len(dirs), np.inf)
    for fr in session.frames:
        if fr["t_s"] < 6.0:
            continue
        o = fr["T_world_from_depth"][:3, 3] - session.origin
        along = dirs @ o
        perp = np.linalg.norm(o[None] - along[:, None] * dirs, axis=1)
        best = np.minimum(best, np.where(along > 0, perp, np.linalg.norm(o)))
    seen_behind = m.behind_after_6s[held]
    lines = [(f"The box covers {int(box_px.sum())} map pixels of the true map before 6 s; at the end the default "
             f"capture still holds {int(held.sum())} of them with a sample of the box "
             f"({100 * cap['map'].em.valid[box_px].mean():.0f} % of the box's pixels are valid)."),
             (f"Closest approach of the device to those pixels' rays after 6 s: median {100 * np.median(best):.0f} cm, "
             f"minimum {100 * best.min():.0f} cm (the removal rule needs < 3 cm: {int((best < 0.03).sum())} pixels)."),
             (f"Pixels where a frame after 6 s put its sample > 5 % beyond the stored box depth (the device saw the "
             f"surface behind the box's former place): {int((seen_behind > 0).sum())} of {int(held.sum())} "
             f"({100 * (seen_behind > 0).mean():.0f} %); median {np.median(seen_behind):.0f} such frames per pixel.")]
    if carve_cap is not None:
        mc: StudyMap = carve_cap["map"]
        sc = sample_objects(session, mc)
        still = box_px & mc.em.valid & (sc == box)
        lines.append(f"With free-space carving ({carve_cap['variant'].name}): {int(still.sum())} box pixels remain "
                     f"({100 * (1 - still.sum() / max(held.sum(), 1)):.0f} % of the default's removed).")
    return lines


def save_figures(session: Session, base: dict, best: dict | None, info: dict, fig_dir: Path) -> list[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig_dir.mkdir(parents=True, exist_ok=True)
    out = []
    gt = info["gt"]
    b = info["b"]
    w = equirect_solid_angles(*gt.valid.shape)
    per_px = np.where(b.covered, b.err / w / 3.0, np.nan)
    fig, axes = plt.subplots(2, 1, figsize=(12, 12))
    axes[0].imshow(np.clip(base["map"].em.radiance, 0, 1) ** (1 / 2.2))
    axes[0].set_title(f"captured map, default ({base['scores']['ws_psnr_db']:.2f} dB)")
    im = axes[1].imshow(np.log10(per_px + 1e-6), vmin=-5, vmax=0, cmap="magma")
    axes[1].set_title("per-pixel squared error (log10, mean over RGB of clipped radiance)")
    fig.colorbar(im, ax=axes[1], fraction=0.025)
    for a in axes:
        a.set_xticks([]); a.set_yticks([])
    fig.tight_layout()
    p = fig_dir / "em_error_map.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    out.append(str(p))
    # Crop: around the horizon (panels, table edge, the box's place), truth / default / best.
    rows = slice(int(0.33 * gt.valid.shape[0]), int(0.57 * gt.valid.shape[0]))
    panels = [("truth at t_end", np.clip(gt.radiance, 0, 1)), ("default", np.clip(base["map"].em.radiance, 0, 1))]
    if best is not None:
        panels.append((best["variant"].name, np.clip(best["map"].em.radiance, 0, 1)))
    fig, axes = plt.subplots(len(panels), 1, figsize=(14, 3.2 * len(panels)))
    for a, (t, img) in zip(axes, panels):
        a.imshow(img[rows] ** (1 / 2.2))
        a.set_title(t)
        a.set_xticks([]); a.set_yticks([])
    fig.tight_layout()
    p = fig_dir / "em_error_crop.png"
    fig.savefig(p, dpi=80)
    plt.close(fig)
    out.append(str(p))
    return out


def noise_and_timings(session: Session, cap: dict) -> list[str]:
    """Depth noise of the measured pixels before / after the plane-fit denoising (all frames), and
    median / p95 time of the two new kernels (free space on the final default map, denoising)."""
    from common import time_it
    rays = pixel_rays(session.intr)
    before, after = [], []
    for fr in session.frames:
        k = fr["raw_known"] & fr["true_valid"]
        z, _ = _plane_denoise(fr["raw_depth"].astype(np.float64), fr["raw_known"], rays, 2, 0.04, 6)
        t = fr["true_depth"][k]
        before.append((fr["raw_depth"][k] - t) / t)
        after.append((z[k] - t) / t)
    before, after = np.concatenate(before), np.concatenate(after)
    mad = lambda x: 1.4826 * float(np.median(np.abs(x - np.median(x))))
    lines = [(f"Relative depth error of the measured pixels, all {len(session.frames)} frames: raw σ (robust, 1.4826·MAD) "
             f"{100 * mad(before):.2f} %, RMS {100 * np.sqrt(np.mean(before ** 2)):.2f} %; after the 5×5 plane fit "
             f"{100 * mad(after):.2f} %, RMS {100 * np.sqrt(np.mean(after ** 2)):.2f} %."), ""]
    m: StudyMap = cap["map"]
    em = m.em
    fr = session.frames[len(session.frames) // 2]
    Tcw = np.linalg.inv(fr["T_world_from_depth"])
    intr = session.intr
    cam = np.array([intr.fx, intr.fy, intr.cx, intr.cy])
    dist = np.asarray(intr.distortion.coefficients, np.float64)
    freed = np.zeros(em.valid.shape, bool)
    z64 = fr["raw_depth"].astype(np.float64)
    rows = {
        "free_space, 2000×1000 map, one frame (all valid map pixels visited)": time_it(lambda: _free_space(
            em.depth_m, em.valid, em.origin, m.row_sc, m.col_sc, np.ascontiguousarray(Tcw[:3, :3]),
            np.ascontiguousarray(Tcw[:3, 3]), cam, dist, fr["raw_depth"], fr["raw_known"], 1, 0.05, 0.02, freed), 21),
        "plane-fit denoising 5×5, one 224×172 frame": time_it(
            lambda: _plane_denoise(z64, fr["raw_known"], rays, 2, 0.04, 6), 21),
    }
    lines += ["| kernel (prototype, single thread) | median ms | p95 ms | n |", "|---|---:|---:|---:|"]
    lines += [f"| {k} | {r['median_ms']:.1f} | {r['p95_ms']:.1f} | {r['n']} |" for k, r in rows.items()]
    return lines


def main(argv=None) -> None:
    args = parse_args(argv)
    frames = load_or_simulate(args)
    if args.stage == "cache":
        return
    t_start = time.perf_counter()
    session = Session(args, frames)
    V = Variant
    h2 = args.em_height // 2
    header = [(f"Session: orbit, {args.duration:.0f} s, seed {args.seed}, colour {args.colour_size}, map "
              f"{2 * args.em_height}×{args.em_height}, {len(frames)} frames, t_end {session.t_end:.1f} s."), ""]

    def run(v: Variant, keep: bool = False) -> dict:
        cap = run_capture(session, v)
        row = evaluate(session, cap)
        print(f"  {row['name']}: {100 * row['coverage']:.1f} % / {row['ws_psnr_db']:.2f} dB (no box {row['no_box_db']:.2f}) "
              f"[{row['wall_s']:.0f} s]", flush=True)
        if keep:
            row["cap"] = slim(cap)
        return row

    # 0. The copy reproduces the library.
    base = run(V("default (library defaults; study copy of the update)"), keep=True)
    lib_em = library_capture(session)
    gt = session.gt(args.em_height)
    s_lib = scores(lib_em, gt)
    bm = base["cap"]["map"].em
    both = lib_em.valid & bm.valid
    dev = np.abs(lib_em.radiance - bm.radiance).max(-1)[both]
    header += [(f"Check: the library's EnvironmentCapture on the same frames: {100 * s_lib['coverage']:.2f} % / "
                f"{s_lib['ws_psnr_db']:.3f} dB; the study copy {100 * base['coverage']:.2f} % / {base['ws_psnr_db']:.3f} dB; "
                f"valid masks agree on {100 * (lib_em.valid == bm.valid).mean():.3f} % of pixels; colours differ by > 1e-3 on "
                f"{100 * (dev > 1e-3).mean():.4f} % of the pixels valid in both (the copy uses libm atan2, the library a "
                f"polynomial: a few samples land one pixel over and the matrices drift by ~1e-6)."), ""]
    del lib_em
    print(header[-2], flush=True)
    base_psnr = base["ws_psnr_db"]

    print("bound", flush=True)
    bound = [run(v, keep=i == 2) for i, v in enumerate([
        V("perfect sensor at the ToF's rays, library rules", sensor="perfect"),
        V("perfect sensor, paper rules (no edge margin)", sensor="perfect", edge_margin_px=None),
        V("perfect sensor + free-space carving", sensor="perfect", carve="take"),
        V("perfect sensor + carving + normal-aware footprint", sensor="perfect", carve="take", aniso=True),
        V("perfect sensor, one pixel per sample (no splat)", sensor="perfect", splat=False),
        V("perfect sensor, 2× denser rays (448×344, f 400)", sensor="perfect2x"),
        V("perfect sensor, 2× denser rays + carving", sensor="perfect2x", carve="take"),
        V("measured (default) at 1000×500", em_height=h2),
        V("perfect sensor + carving at 1000×500", sensor="perfect", carve="take", em_height=h2),
        V("perfect sensor 2× denser + carving at 1000×500", sensor="perfect2x", carve="take", em_height=h2),
    ])]
    perfect_carve = bound[2].pop("cap")

    print("sources", flush=True)
    sources = [run(v) for v in [
        V("exact colour-correction matrix (diag of true gain ratios)", ccm="exact"),
        V("measured depth, true colour along each ToF ray", colour_src="true"),
        V("true depth at the measured pixels (holes filled as usual), measured colour", depth_src="true_on_measured"),
        V("true depth at the measured pixels, true colour", depth_src="true_on_measured", colour_src="true"),
        V("true depth at every in-range pixel (no holes), measured colour", depth_src="perfect"),
        V("true depth at the measured pixels + carving", depth_src="true_on_measured", carve="take"),
        V("true depth at every in-range pixel + carving, measured colour", depth_src="perfect", carve="take"),
    ]]

    print("fixes", flush=True)
    DC = {"denoise": "plane5", "carve": "take"}
    fixes = [run(v, keep=keep) for v, keep in [
        (V("filled pixels: none", filled="none"), False),
        (V("filled pixels: plane-consistent", filled="plane_consistent"), False),
        (V("filled pixels: not within 2 px of a depth edge", filled="not_edge"), False),
        (V("edge margin 4 px, only for takeovers by > 10 % of the depth", edge_margin_px=4, margin_jump_rel=0.10), False),
        (V("edge margin 2 px, only for takeovers by > 10 %", margin_jump_rel=0.10), False),
        (V("edge margin 3 px around near-side (foreground) edges only", near_margin_px=3), False),
        (V("fill-only samples splat one pixel", edge_centre_only=True), False),
        (V("erode silhouettes: drop near-side edge samples (1 px)", erode_near_px=1), False),
        (V("erode silhouettes: drop near-side edge samples (2 px)", erode_near_px=2), False),
        (V("'closer' needs votes (≥ 2 frames and ≥ 0.5 × the stored surface's)", vote=0.5), False),
        (V("'closer' needs votes (≥ 1 × the stored surface's)", vote=1.0), False),
        (V("'closer' only for samples placed within 2 map rows (1 σ)", angular_gate_px=2), False),
        (V("grazing samples (|cos| < 0.15 from the origin) do not take over nearby surfaces", grazing_cos=0.15), False),
        (V("normal-aware footprint", aniso=True), False),
        (V("colour per map pixel from the colour image", colour="image"), False),
        (V("depth denoised: plane fit of 1/z, 3×3", denoise="plane3"), False),
        (V("depth denoised: plane fit of 1/z, 5×5 (D)", denoise="plane5"), False),
        (V("depth denoised: plane fit of 1/z, 7×7", denoise="plane7"), False),
        (V("free-space carving (C)", carve="take"), True),
        (V("free-space carving, emptied when no sample lands", carve="invalidate"), False),
        (V("free-space carving, 5×5 neighbourhood", carve="take", carve_k=2), False),
        (V("D + C", **DC), False),
        (V("D + C, tolerance 3 % + 1 cm", carve_tol_rel=0.03, carve_tol_abs_m=0.01, **DC), False),
        (V("D + C, edge margin 1 px", edge_margin_px=1, **DC), False),
        (V("D + C + plane-consistent filled pixels", filled="plane_consistent", **DC), False),
        (V("D + C + normal-aware footprint", aniso=True, **DC), False),
        (V("D + C + colour from the image (best)", colour="image", **DC), True),
        (V("D + C + colour from the image + plane-consistent filled", colour="image", filled="plane_consistent", **DC), False),
        (V("D + C + colour from the image, exact matrix (not a fix: the matrix's share)", colour="image", ccm="exact", **DC), False),
    ]]
    carve = next(r.pop("cap") for r in fixes if r["name"] == "free-space carving (C)")
    best = next(r.pop("cap") for r in fixes if r["name"].endswith("(best)"))

    print("budgets", flush=True)
    budget_lines, info = budget_report(session, base["cap"], perfect=perfect_carve)
    best_lines, _ = budget_report(session, best, perfect=perfect_carve)
    perfect_lines, _ = budget_report(session, perfect_carve)
    out = list(header)
    out += ["## Error budget of the default map", ""] + budget_lines
    out += ["## Resolution bound", ""] + variant_table([base] + bound, base_psnr) + [""]
    out += ["Budget of 'perfect sensor + free-space carving':", ""] + perfect_lines
    out += ["## Depth and colour sources", ""] + variant_table([base] + sources, base_psnr) + [""]
    out += ["## Prototype fixes", ""] + variant_table([base] + fixes, base_psnr) + [""]
    out += ["Budget of the best variant:", ""] + best_lines
    out += ["## The removed box", ""] + box_report(session, base["cap"], carve) + [""]
    if args.figures:
        base["cap"]["scores"] = {"ws_psnr_db": base["ws_psnr_db"]}
        figs = save_figures(session, base["cap"], best, info, args.figures)
        out += ["Figures: " + ", ".join(figs), ""]
    out += ["## Denoising and the cost of the prototypes", ""] + noise_and_timings(session, base["cap"]) + [""]
    out.append(f"Total wall time {time.perf_counter() - t_start:.0f} s (after the cached simulation).")
    text = "\n".join(out)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
