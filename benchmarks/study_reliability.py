"""Study of the depth-discontinuity test of reliability marking (paper 003 §5.2): the authors'
statistic against the one derived from the ToF noise model. Writes the figures used by
docs/design/reliability.md and prints its tables (Markdown).

    python benchmarks/study_reliability.py [--trials 20] [--packets 50] [--figures docs/figures]

Part 1, synthetic: walls at 0°, 45°, 70° incidence and step edges of 1, 3, 10, 30 cm at 0.5–4 m, with
the simulator's ToF noise model (Gaussian range noise, σ = 1 % of the range; depth along a pixel ray
is range × const, so z gets the same relative noise). Geometry uses the simulated Tango ToF camera's
intrinsics and distortion; a 96×32-pixel patch around the principal point (so a 70° wall spans a
modest depth range) is evaluated, every pixel known, no mixed pixels. Rates per setting pool
``--trials`` noise draws.

Part 2, detection bound: Monte Carlo of the best an 8-neighbour test can do against a step.

Part 3, simulator: ``--packets`` depth packets of the default scene ("office", "orbit" trajectory,
seed 0) spread over one orbit; depth image from the ToF points with confidence ≥ 0.7
(``rgbd_envmap.ingest.tango.depth_image_from_points``); colour = the true radiance along each depth
pixel's ray times a steady-state auto-exposure gain (mean clipped luma 0.18, the simulated colour
camera's target), no white balance, noise or quantisation. Precision / recall of "unreliable"
against ground-truth depth discontinuities, mixed pixels and the emissive / shiny / dark masks.
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.stats import chi2, norm  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rgbd_envmap.depth.reliability import discontinuity_test, exposure_ok, mark_reliable  # noqa: E402
from rgbd_envmap.geometry import pixel_rays  # noqa: E402
from sim.device import TangoDeviceConfig  # noqa: E402

DISTANCES_M = (0.5, 1.0, 2.0, 3.0, 4.0)
INCIDENCES_DEG = (0.0, 45.0, 70.0)
STEPS_M = (0.01, 0.03, 0.10, 0.30)
NOISE_REL = 0.01
PATCH = (98, 34)  # rows, cols incl. a 1-pixel margin that is not evaluated

# (label, method, depth scale): the authors' statistic in metres (as specified) and, for the units
# question, the same code fed millimetres.
VARIANTS = (
    ("noise_model", "noise_model", 1.0),
    ("monroy2018 (m)", "monroy2018", 1.0),
    ("monroy2018 (mm)", "monroy2018", 1000.0),
)
DEFAULT_LABEL = "+ exposure + noise_model (default: min_nb 8, p 0.05)"
COLOURS = {"noise_model": "tab:blue", "monroy2018 (m)": "tab:red", "monroy2018 (mm)": "tab:orange"}


# --------------------------------------------------------------------------------------------------
# Part 1: synthetic walls and steps
# --------------------------------------------------------------------------------------------------


def patch_rays() -> np.ndarray:
    """(98, 34, 3) z = 1 rays of the ToF camera around its principal point (with distortion)."""
    intr = TangoDeviceConfig().tof.intrinsics
    rays = pixel_rays(intr)
    r0 = int(round(intr.cy)) - PATCH[0] // 2
    c0 = int(round(intr.cx)) - PATCH[1] // 2
    return np.array(rays[r0:r0 + PATCH[0], c0:c0 + PATCH[1]])


def wall_depth(rays: np.ndarray, distance_m: float, incidence_deg: float) -> np.ndarray:
    """True z-depth of a plane through (0, 0, distance) whose normal is tilted by ``incidence_deg``
    about the camera y axis (depth changes along image columns)."""
    t = np.radians(incidence_deg)
    normal = np.array([-np.sin(t), 0.0, np.cos(t)])
    return distance_m * np.cos(t) / (rays @ normal)


def step_depth(rays: np.ndarray, distance_m: float, step_m: float) -> np.ndarray:
    """Fronto-parallel wall at ``distance_m`` whose right half (columns ≥ the middle) is ``step_m``
    farther."""
    z = np.full(rays.shape[:2], distance_m)
    z[:, PATCH[1] // 2:] += step_m
    return z


def add_tof_noise(z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The simulator's ToF model: range × (1 + noise_rel · N(0, 1)); z scales with the range."""
    return z * (1.0 + NOISE_REL * rng.standard_normal(z.shape))


def rejected(z: np.ndarray, method: str, scale: float) -> np.ndarray:
    return ~discontinuity_test(z * scale, np.ones(z.shape, bool), method).passed


def run_synthetic(trials: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    rays = patch_rays()
    inner = (slice(1, -1), slice(1, -1))
    walls = {}  # (variant, incidence, distance) -> false-rejection rate
    stats = {}  # (variant, case) -> statistic / threshold samples, for the histogram figure
    for inc in INCIDENCES_DEG:
        for dist in DISTANCES_M:
            z_true = wall_depth(rays, dist, inc)
            counts = {v[0]: 0 for v in VARIANTS}
            total = 0
            for _ in range(trials):
                z = add_tof_noise(z_true, rng)
                total += z[inner].size
                for label, method, scale in VARIANTS:
                    counts[label] += int(rejected(z, method, scale)[inner].sum())
                    if inc == 0.0 and dist in (1.0, 3.0):
                        t = discontinuity_test(z * scale, np.ones(z.shape, bool), method)
                        ratio = t.statistic[inner] / t.threshold[inner]
                        stats.setdefault((label, f"wall {dist:g} m"), []).append(ratio.ravel())
            for label in counts:
                walls[(label, inc, dist)] = counts[label] / total
    edges = {}  # (variant, step, distance) -> (near-side rate, far-side rate)
    mid = PATCH[1] // 2
    for step in STEPS_M:
        for dist in DISTANCES_M:
            z_true = step_depth(rays, dist, step)
            near = {v[0]: 0 for v in VARIANTS}
            far = {v[0]: 0 for v in VARIANTS}
            total = 0
            for _ in range(trials):
                z = add_tof_noise(z_true, rng)
                total += PATCH[0] - 2
                for label, method, scale in VARIANTS:
                    rej = rejected(z, method, scale)
                    near[label] += int(rej[1:-1, mid - 1].sum())
                    far[label] += int(rej[1:-1, mid].sum())
                    if step == 0.10 and dist in (1.0, 3.0):
                        t = discontinuity_test(z * scale, np.ones(z.shape, bool), method)
                        edge = (slice(1, -1), slice(mid - 1, mid + 1))
                        ratio = t.statistic[edge] / t.threshold[edge]
                        stats.setdefault((label, f"10 cm step {dist:g} m"), []).append(ratio.ravel())
            for label in near:
                edges[(label, step, dist)] = (near[label] / total, far[label] / total)
    stats = {k: np.concatenate(v) for k, v in stats.items()}
    return walls, edges, stats


def model_error_table() -> list[tuple[float, float, float]]:
    """Noise-free statistic on planes over the *whole* distorted image: the plane-model error of
    fitting 1/z (the library) and of fitting z directly, in χ² units (a wall's mean is n − 3 ≈ 6)."""
    from benchmarks.bench_reliability import noise_model_statistic_numpy

    intr = TangoDeviceConfig().tof.intrinsics
    rays = pixel_rays(intr)
    rows = []
    for inc in (45.0, 70.0, 80.0):
        z = wall_depth(rays, 2.0, inc)
        ok = (z > 0.1) & (z < 10.0)
        t_inv = discontinuity_test(z, ok).statistic[ok]
        t_z, _ = noise_model_statistic_numpy(z, ok, NOISE_REL, 0.0, fit="z")
        rows.append((inc, float(t_inv.max()), float(t_z[ok].max())))
    return rows


# --------------------------------------------------------------------------------------------------
# Part 2: what any 8-neighbour test can detect
# --------------------------------------------------------------------------------------------------


def detection_bound(samples: int = 200_000, seed: int = 1) -> list[tuple[float, ...]]:
    """Detection rate of a vertical step of h/σ between a pixel's column and the next, at 5 % false
    rejection on planes: the plane-fit χ² (the library's statistic), a directed test (max over the 8
    step patterns of the 3×3 window of the squared, plane-orthogonal step contrast), and the
    Neyman–Pearson bound for this one known step, Φ(√λ − z₀.₉₅) with λ = (h/σ)²/2 the step's
    non-planar energy. The last column is the plane-fit χ² at 1 % false rejection."""
    rng = np.random.default_rng(seed)
    vv, uu = np.mgrid[-1:2, -1:2]
    a = np.stack([np.ones(9), uu.ravel(), vv.ravel()], 1)
    proj = np.eye(9) - a @ np.linalg.pinv(a)
    cuts = [uu > 0, uu < 0, vv > 0, vv < 0, uu + vv > 0, uu + vv < 0, uu - vv > 0, uu - vv < 0]
    pats = []
    for cut in cuts:
        r = proj @ cut.ravel().astype(float)
        pats.append(r / np.linalg.norm(r))
    q = np.array(pats)
    e = rng.standard_normal((samples, 9))
    thr_omni = chi2.isf(0.05, 6)
    thr_omni_01 = chi2.isf(0.01, 6)
    thr_dir = np.quantile(np.max((e @ q.T) ** 2, 1), 0.95)
    step = (uu > 0).ravel().astype(float)
    lam_unit = float(step @ proj @ step)  # = 1/2
    rows = []
    for h in (2.0, 10 / 3, 5.0, 7.0, 10.0):
        y = e + h * step
        t_omni = np.einsum("ij,ij->i", y @ proj, y)
        omni = np.mean(t_omni > thr_omni)
        omni_01 = np.mean(t_omni > thr_omni_01)
        directed = np.mean(np.max((y @ q.T) ** 2, 1) > thr_dir)
        bound = norm.cdf(np.sqrt(lam_unit) * h - norm.isf(0.05))
        rows.append((h, float(omni), float(directed), float(bound), float(omni_01)))
    return rows


# --------------------------------------------------------------------------------------------------
# Part 3: simulator
# --------------------------------------------------------------------------------------------------


def gt_discontinuity(true_z: np.ndarray, true_valid: np.ndarray, rel_jump: float = 0.05) -> np.ndarray:
    """True-valid pixels with an in-image 8-neighbour whose true depth differs by more than
    ``rel_jump`` relative (to the nearer of the two), or that has no true surface."""
    h, w = true_z.shape
    z = np.where(true_valid, true_z.astype(np.float64), np.nan)
    pad = np.pad(z, 1, constant_values=np.nan)
    inside = np.pad(np.ones((h, w), bool), 1, constant_values=False)
    out = np.zeros((h, w), bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            nb = pad[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]
            nb_in = inside[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]
            with np.errstate(invalid="ignore"):
                jump = np.abs(nb - z) > rel_jump * np.fmin(nb, z)
            out |= nb_in & (np.isnan(nb) | jump)
    return out & true_valid


def steady_exposure(radiance: np.ndarray, target: float = 0.18, lo: float = 0.05, hi: float = 40.0) -> float:
    """Gain g with mean luma of clip(g · radiance, 0, 1) = ``target`` (bisection in log g)."""
    luma = np.array([0.2126, 0.7152, 0.0722])

    def mean_luma(g):
        return float(np.mean(np.clip(radiance * g, 0.0, 1.0) @ luma))

    a, b = np.log(lo), np.log(hi)
    for _ in range(40):
        m = 0.5 * (a + b)
        if mean_luma(np.exp(m)) < target:
            a = m
        else:
            b = m
    return float(np.exp(0.5 * (a + b)))


def simulator_frames(n_packets: int, filter_mixed: bool = True):
    """Depth packets of the default scene as (index, depth_m, known, rgb, groundtruth).
    ``filter_mixed`` False gives mixed (flying) pixels full confidence: a sensor that lets them through."""
    from dataclasses import replace

    from sim.colour_camera import ColourCameraConfig
    from sim.scene import load_scene
    from sim.session import Simulator
    from sim.trajectory import load_trajectory

    device = TangoDeviceConfig(colour=ColourCameraConfig(width=64, height=48))
    if not filter_mixed:
        device = replace(device, tof=replace(device.tof, mixed_confidence=1.0))
    sim = Simulator(load_scene("office"), load_trajectory("orbit"), device, seed=0)
    intr = sim.calibration.depth
    try:
        from rgbd_envmap.ingest.tango import depth_image_from_points
    except ImportError:  # pragma: no cover - ingest not available: rasterise by the sim's pixel index
        depth_image_from_points = None
    rays = pixel_rays(intr).reshape(-1, 3)
    dirs = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    step = max(1, 100 // n_packets)  # one orbit = 20 s = 100 packets at 5 Hz
    for i in range(0, step * n_packets, step):
        sp = sim.depth_packet(i, sim.start_ns + i * 200_000_000)
        pk, gt = sp.packet, sp.groundtruth
        if depth_image_from_points is not None:
            img = depth_image_from_points(pk.points_m, pk.confidence, intr, confidence_threshold=0.7)
            depth, known = img.depth_m, img.known
        else:
            depth = np.zeros(intr.height * intr.width, np.float32)
            known = np.zeros(intr.height * intr.width, bool)
            sel = pk.confidence >= 0.7
            depth[gt["pixel_index"][sel]] = pk.points_m[sel, 2]
            known[gt["pixel_index"][sel]] = True
            depth, known = depth.reshape(intr.height, intr.width), known.reshape(intr.height, intr.width)
        hits = sim.raycaster.cast(sp.true_pose.translation, sp.true_pose.rotate(dirs), sp.t_s, normals=False)
        radiance = hits.radiance.reshape(intr.height, intr.width, 3).astype(np.float64)
        rgb = np.clip(radiance * steady_exposure(radiance), 0.0, 1.0).astype(np.float32)
        yield i, depth, known, rgb, gt


def sim_configs():
    """(label, function (rgb, depth, known) → reliable)."""

    def conf_only(rgb, depth, known):
        return known.copy()

    def exposure(rgb, depth, known):
        return known & exposure_ok(rgb)

    def neighbour_rule(rgb, depth, known):  # every in-image neighbour known, no statistic
        return discontinuity_test(depth, known, "monroy2018", min_neighbours=8).testable & exposure_ok(rgb)

    def test(method, scale=1.0, **kw):
        def f(rgb, depth, known):
            return mark_reliable(rgb, depth * scale, known, method, **kw)
        return f

    return [
        ("confidence ≥ 0.7 only", conf_only),
        ("+ exposure rule", exposure),
        ("+ exposure + monroy2018 (m)", test("monroy2018")),
        ("+ exposure + monroy2018 (mm)", test("monroy2018", 1000.0)),
        ("+ exposure + noise_model, min_nb 3", test("noise_model", min_neighbours=3)),
        ("+ exposure + noise_model, min_nb 5", test("noise_model", min_neighbours=5)),
        ("+ exposure + noise_model, min_nb 7", test("noise_model", min_neighbours=7)),
        ("+ exposure + noise_model (default: min_nb 8, p 0.05)", test("noise_model")),
        ("+ exposure + noise_model, min_nb 8, p 0.01", test("noise_model", p_value=0.01)),
        ("+ exposure + neighbour rule only (min_nb 8, no statistic)", neighbour_rule),
    ]


def run_simulator(n_packets: int, filter_mixed: bool = True):
    configs = sim_configs()
    acc = {label: {} for label, _ in configs}
    example = None

    def add(d, key, value):
        d[key] = d.get(key, 0) + int(value)

    n_frames = 0
    for i, depth, known, rgb, gt in simulator_frames(n_packets, filter_mixed):
        n_frames += 1
        tv = gt["true_valid"]
        disc = gt_discontinuity(gt["true_depth_m"], tv)
        disc2 = gt_discontinuity(gt["true_depth_m"], tv, rel_jump=0.02)
        mixed = gt["mixed"] & tv
        flags = gt["flags"]
        masks = {
            "disc": disc, "disc2": disc2, "mixed": mixed,
            "emissive": (flags & 1) > 0, "shiny": (flags & 2) > 0, "dark": (flags & 4) > 0,
        }
        masks = {k: v & tv for k, v in masks.items()}
        masks["any flag"] = masks["emissive"] | masks["shiny"] | masks["dark"]
        masks["bad"] = masks["disc"] | masks["mixed"] | masks["any flag"]
        outs = {}
        for label, fn in configs:
            rel = fn(rgb, depth, known)
            outs[label] = rel
            unrel = tv & ~rel
            a = acc[label]
            add(a, "pixels", tv.sum())
            add(a, "unreliable", unrel.sum())
            for k, m in masks.items():
                add(a, f"{k}", m.sum())
                add(a, f"{k}&unrel", (m & unrel).sum())
            # The test's own contribution: among known, well-exposed pixels, which does it reject?
            base = known & exposure_ok(rgb) & tv
            rej = base & ~rel
            add(a, "base", base.sum())
            add(a, "base", 0)
            for k in ("disc", "disc2", "mixed"):
                add(a, f"base&{k}", (base & masks[k]).sum())
                add(a, f"rej&{k}", (rej & masks[k]).sum())
            add(a, "rej", rej.sum())
            add(a, "rej&bad_dm", (rej & (masks["disc"] | masks["mixed"])).sum())
        # The example figure shows the packet with the most known discontinuity pixels among those
        # that also see flagged material.
        score = int((disc & known).sum()) if masks["any flag"].sum() > 1000 else -1
        if example is None or score > example[0]:
            example = (score, i, depth, known, rgb, disc, masks["any flag"], outs)
    return acc, example, n_frames


# --------------------------------------------------------------------------------------------------
# Figures and tables
# --------------------------------------------------------------------------------------------------


def figure_walls(walls, path: Path) -> None:
    fig, axes = plt.subplots(1, len(INCIDENCES_DEG), figsize=(12, 3.8), sharey=True)
    for ax, inc in zip(axes, INCIDENCES_DEG):
        for label, _, _ in VARIANTS:
            rates = [100 * walls[(label, inc, d)] for d in DISTANCES_M]
            ax.plot(DISTANCES_M, rates, "o-", color=COLOURS[label], label=label, lw=2)
        ax.axhline(5.0, color="grey", ls=":", lw=1)
        ax.set_title(f"noisy wall, {inc:g}° incidence")
        ax.set_xlabel("distance (m)")
        ax.set_xticks(DISTANCES_M)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("false rejections (% of wall pixels)")
    axes[0].text(2.3, 6.6, "p_value = 0.05", color="grey", fontsize=8)
    axes[0].legend(loc="upper left", fontsize=9)
    axes[0].set_ylim(-1, 30)
    fig.suptitle("Walls with 1 % ToF range noise: share of pixels rejected as 'near a discontinuity' (lower is better)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure_edges(edges, path: Path) -> None:
    fig, axes = plt.subplots(1, len(VARIANTS), figsize=(12, 3.8), sharey=True)
    cmap = plt.get_cmap("viridis")
    for ax, (label, _, _) in zip(axes, VARIANTS):
        for k, step in enumerate(STEPS_M):
            rates = [100 * min(edges[(label, step, d)]) for d in DISTANCES_M]
            ax.plot(DISTANCES_M, rates, "o-", color=cmap(k / (len(STEPS_M) - 0.5)), lw=2, label=f"{100 * step:g} cm step")
        ax.set_title(label, color=COLOURS[label])
        ax.set_xlabel("distance (m)")
        ax.set_xticks(DISTANCES_M)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("edge pixels rejected (%, worse side)")
    axes[0].set_ylim(-3, 103)
    axes[1].legend(loc="center", fontsize=9, title="1 % noise: σ = 1 cm per metre")
    fig.suptitle("Step edges with 1 % ToF range noise: share of the pixels beside the step that are rejected (higher is better)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure_statistics(stats, path: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8))
    cases = [("wall 1 m", "tab:green", "-"), ("wall 3 m", "tab:green", "--"),
             ("10 cm step 1 m", "tab:purple", "-"), ("10 cm step 3 m", "tab:purple", "--")]
    for ax, label in zip(axes, ("noise_model", "monroy2018 (m)")):
        vals = [stats[(label, c)] for c, _, _ in cases]
        lo = max(min(np.percentile(v[v > 0], 0.5) for v in vals), 1e-9)
        hi = max(np.percentile(v, 99.5) for v in vals)
        bins = np.geomspace(lo, max(hi, 2.0), 80)
        for (case, colour, ls), v in zip(cases, vals):
            ax.hist(np.clip(v, lo, None), bins=bins, histtype="step", lw=2, color=colour, ls=ls, density=True, label=case)
        ax.axvline(1.0, color="k", lw=1.5)
        ax.text(1.08, 0.93, "threshold", transform=ax.get_xaxis_transform(), fontsize=8)
        ax.set_xscale("log")
        ax.set_yticks([])
        ax.set_xlabel("statistic / threshold (log)")
        ax.set_title(label, color=COLOURS[label])
    axes[0].legend(fontsize=8, loc="upper left")
    fig.suptitle("Distribution of each statistic on wall pixels and on the pixels beside a 10 cm step (rejected right of the line)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure_example(example, path: Path) -> None:
    _, idx, depth, known, rgb, disc, flagged, outs = example
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.6), constrained_layout=True)
    d = np.where(known, depth, np.nan)
    im = axes[0].imshow(d, cmap="turbo")
    fig.colorbar(im, ax=axes[0], fraction=0.04, pad=0.02, label="z-depth (m)")
    axes[0].set_title(f"packet {idx}: known depth (white: unknown)", fontsize=10)
    truth = np.ones(depth.shape + (3,))
    truth[known] = 0.85
    truth[flagged] = (0.35, 0.55, 1.0)
    truth[disc] = (0.85, 0.1, 0.1)
    axes[1].imshow(truth)
    axes[1].set_title("truth: red = 5 % depth jump, blue = emissive / shiny / dark,\ngrey = known, white = unknown", fontsize=9)
    for ax, label in zip(axes[2:], ("+ exposure + monroy2018 (m)", DEFAULT_LABEL)):
        rel = outs[label]
        img = np.ones(depth.shape + (3,))
        img[known & ~rel] = (0.1, 0.1, 0.1)
        img[known & rel] = (0.85, 0.85, 0.85)
        ax.imshow(img)
        name = label.split(" + ")[-1].split(" (default")[0]
        ax.set_title(f"{name}: black = known but unreliable\n(grey reliable, white unknown)", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.savefig(path, dpi=110)
    plt.close(fig)


def pct(x: float) -> str:
    return f"{100 * x:.1f}"


def print_tables(walls, edges, bound, model_rows, acc, n_frames) -> None:
    print("\n### Walls: false rejections (% of wall pixels)\n")
    print("| statistic | incidence | " + " | ".join(f"{d:g} m" for d in DISTANCES_M) + " |")
    print("|---|---|" + "---|" * len(DISTANCES_M))
    for label, _, _ in VARIANTS:
        for inc in INCIDENCES_DEG:
            print(f"| {label} | {inc:g}° | " + " | ".join(pct(walls[(label, inc, d)]) for d in DISTANCES_M) + " |")
    print("\n### Step edges: pixels rejected beside the step (%, near side / far side)\n")
    print("| statistic | step | " + " | ".join(f"{d:g} m" for d in DISTANCES_M) + " |")
    print("|---|---|" + "---|" * len(DISTANCES_M))
    for label, _, _ in VARIANTS:
        for step in STEPS_M:
            cells = [f"{pct(edges[(label, step, d)][0])} / {pct(edges[(label, step, d)][1])}" for d in DISTANCES_M]
            print(f"| {label} | {100 * step:g} cm | " + " | ".join(cells) + " |")
    print("\n### Detection bound for a step of h/σ (5 % false rejection)\n")
    print("| h/σ | plane-fit χ² (noise_model) | directed step test | Neyman–Pearson bound (known step) | plane-fit χ², p = 0.01 |")
    print("|---|---|---|---|---|")
    for h, omni, directed, b, omni_01 in bound:
        print(f"| {h:.2f} | {pct(omni)} | {pct(directed)} | {pct(b)} | {pct(omni_01)} |")
    print("\n### Plane-model error: largest noise-free statistic over the whole distorted 224×172 image\n")
    print("| incidence | fit 1/z (library) | fit z |")
    print("|---|---|---|")
    for inc, t_inv, t_z in model_rows:
        print(f"| {inc:g}° | {t_inv:.1e} | {t_z:.1e} |")
    print(f"\n### Simulator: {n_frames} depth packets, all true-surface pixels\n")
    print("Unreliable = not marked reliable (unknown, badly exposed or rejected by the test). "
          "P = precision of 'unreliable' against 'bad' (discontinuity ∪ mixed ∪ flagged); R = recall per mask.\n")
    print("| configuration | unreliable % | P vs bad | R disc. | R mixed | R emissive | R shiny | R dark | R any flag |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, a in acc.items():
        def r(k, a=a):
            return pct(a[f"{k}&unrel"] / a[k]) if a[k] else "–"
        print(f"| {label} | {pct(a['unreliable'] / a['pixels'])} | {pct(a['bad&unrel'] / a['unreliable'])} | "
              f"{r('disc')} | {r('mixed')} | {r('emissive')} | {r('shiny')} | {r('dark')} | {r('any flag')} |")
    print("\nThe test's own contribution, among known, well-exposed true-surface pixels: what it rejects "
          "against the true discontinuities (5 % and 2 % relative jump) that survived the confidence threshold.\n")
    print("| configuration | rejected % | precision vs disc. 5 % | recall disc. 5 % | precision vs disc. 2 % | recall disc. 2 % |")
    print("|---|---|---|---|---|---|")
    for label, a in acc.items():
        if label.startswith("confidence") or label == "+ exposure rule":
            continue
        cells = []
        for k in ("disc", "disc2"):
            cells.append(pct(a[f"rej&{k}"] / a["rej"]) if a["rej"] else "–")
            cells.append(pct(a[f"rej&{k}"] / a[f"base&{k}"]))
        print(f"| {label} | {pct(a['rej'] / a['base'])} | " + " | ".join(cells) + " |")
    a = next(iter(acc.values()))
    print(f"\nKnown, well-exposed true-surface pixels: {a['base']}, of which {a['base&disc']} within a 5 % and "
          f"{a['base&disc2']} within a 2 % true-depth jump.")
    a = next(iter(acc.values()))
    print(f"Counts over all packets: {a['pixels']} true-surface pixels, {a['disc']} discontinuity (5 %), "
          f"{a['mixed']} mixed, {a['emissive']} emissive, {a['shiny']} shiny, {a['dark']} dark.")


def print_unfiltered(acc, n_frames) -> None:
    print(f"\n### Simulator without flying-pixel filtering (mixed pixels at full confidence), {n_frames} packets\n")
    print("Among known, well-exposed true-surface pixels.\n")
    print("| configuration | rejected % | recall mixed | recall disc. 5 % | precision vs mixed ∪ disc. 5 % |")
    print("|---|---|---|---|---|")
    for label, a in acc.items():
        if label.startswith("confidence") or label == "+ exposure rule":
            continue
        print(f"| {label} | {pct(a['rej'] / a['base'])} | {pct(a['rej&mixed'] / a['base&mixed'])} | "
              f"{pct(a['rej&disc'] / a['base&disc'])} | {pct(a['rej&bad_dm'] / a['rej']) if a['rej'] else '–'} |")
    a = next(iter(acc.values()))
    print(f"\nKnown, well-exposed true-surface pixels: {a['base']}, of which {a['base&mixed']} mixed and "
          f"{a['base&disc']} within a 5 % jump.")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=20, help="noise draws per synthetic setting")
    parser.add_argument("--packets", type=int, default=50, help="simulator depth packets (≥ 20)")
    parser.add_argument("--figures", type=Path, default=Path(__file__).resolve().parent.parent / "docs" / "figures")
    args = parser.parse_args()
    args.figures.mkdir(parents=True, exist_ok=True)

    walls, edges, stats = run_synthetic(args.trials)
    figure_walls(walls, args.figures / "reliability_walls.png")
    figure_edges(edges, args.figures / "reliability_edges.png")
    figure_statistics(stats, args.figures / "reliability_statistics.png")
    bound = detection_bound()
    model_rows = model_error_table()
    acc, example, n_frames = run_simulator(args.packets)
    figure_example(example, args.figures / "reliability_sim_example.png")
    print_tables(walls, edges, bound, model_rows, acc, n_frames)
    acc_u, _, n_u = run_simulator(args.packets, filter_mixed=False)
    print_unfiltered(acc_u, n_u)


if __name__ == "__main__":
    main()
