"""``rgbd-envmap sweep``'s rendering axes: the grid, the light-sampling error, the composite scoring
(closed forms on synthetic frames) and, on a tiny simulated run, the identity that the sweep's default
point scores the composite exactly as ``simulate`` did."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import yaml

from apps.sweep import (AXES, RENDER_AXES, ReferenceScorer, brute_force_irradiance, fibonacci_normals, grid,
                        lights_irradiance_error, pareto, read_rows, run_point, score_composites)
from rgbd_envmap.config import apply_overrides
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.geometry import equirect_directions, equirect_solid_angles
from rgbd_envmap.lights import LightSet
from rgbd_envmap.pipeline import PipelineConfig
from tests.sim.test_reference_frames import _ROOM as _REFERENCE_ROOM


# --- the grid ------------------------------------------------------------------------------------------


def _render_changes(point) -> dict:
    """The render settings a point changes from the defaults (field → new value)."""
    base = PipelineConfig().render
    cfg = apply_overrides(PipelineConfig(), list(point.overrides)).render
    return {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if getattr(cfg, f.name) != getattr(base, f.name)}


def test_lights_axis_is_every_sampler_times_both_counts_with_rendering_on():
    pts = grid(["lights"])
    assert [p.axis for p in pts[:2]] == ["default", "render_default"]
    assert not pts[0].render and pts[1].render and pts[1].overrides == ()
    rc = PipelineConfig().render
    assert (rc.composite, rc.light_method, rc.lights) == ("differential", "val", 12)
    combos = {(rc.light_method, rc.lights)}
    for p in pts[2:]:
        assert p.axis == "lights" and p.render
        cfg = apply_overrides(PipelineConfig(), list(p.overrides)).render
        assert cfg.composite == "differential" and cfg.object_shading == rc.object_shading and cfg.tau == rc.tau
        combos.add((cfg.light_method, cfg.lights))
    assert len(pts) == 2 + 7 and combos == {(m, n) for m in ("val", "q2tree", "pharr", "hemigon") for n in (12, 48)}
    assert len({p.name for p in pts}) == len(pts)


def test_composite_axis_changes_one_render_setting_each():
    pts = [p for p in grid(["composite"]) if p.axis == "composite"]
    assert all(p.render for p in pts)
    assert [_render_changes(p) for p in pts] == [{"composite": "paper003"}, {"object_shading": "lights"},
                                                 {"tau": 0.2}, {"tau": 0.5}, {"tau": 0.8},
                                                 {"receiver_spacing_m": 0.008}, {"receiver_spacing_m": 0.016},
                                                 {"light_grid_stride": 4}]


def test_capture_axes_replay_without_rendering_and_the_render_default_is_shared():
    everything = grid()
    assert set(AXES) >= set(RENDER_AXES)
    assert sum(p.axis == "render_default" for p in everything) == 1
    assert all(not p.render for p in everything if p.axis not in (*RENDER_AXES, "render_default"))
    assert all(p.axis != "render_default" for p in grid(["em_size", "bands"]))
    with pytest.raises(InvalidInputError, match="lights_count"):
        grid(["lights_count"])


# --- the light-sampling error --------------------------------------------------------------------------


def test_brute_force_irradiance_against_the_reference_and_a_constant_sky():
    from rgbd_envmap.reference.lights import brute_force_irradiance as reference

    rng = np.random.default_rng(3)
    rad = rng.random((24, 48, 3)).astype(np.float32)
    valid = rng.random((24, 48)) > 0.3
    nrm = fibonacci_normals(40)
    np.testing.assert_allclose(brute_force_irradiance(rad, valid, nrm, chunk=100), reference(rad, nrm, valid), rtol=1e-7)  # float32 directions
    # L = 1 everywhere: E(n) = π for every normal (to the pixels' discretisation of the cosine lobe)
    e = brute_force_irradiance(np.ones((200, 400, 3)), np.ones((200, 400), bool), nrm)
    np.testing.assert_allclose(e, math.pi, rtol=2e-4)
    assert np.all(brute_force_irradiance(rad, np.zeros((24, 48), bool), nrm) == 0)


def test_lights_irradiance_error_of_exact_and_missing_lights():
    H, W = 40, 80
    rad = np.zeros((H, W, 3))
    valid = np.ones((H, W), bool)
    i, j = 9, 23
    rad[i, j] = [50.0, 40.0, 30.0]
    direction = equirect_directions(H, W)[i, j].astype(np.float64)
    power = rad[i, j] * equirect_solid_angles(H, W)[i, j]
    exact = LightSet(direction[None] / np.linalg.norm(direction), power[None], "test")
    zero_sh = np.zeros((25, 3))
    assert lights_irradiance_error(exact, zero_sh, rad, valid) < 1e-6
    assert lights_irradiance_error(None, zero_sh, rad, valid) == pytest.approx(1.0)
    half = LightSet(exact.directions, exact.power / 2, "test")
    assert lights_irradiance_error(half, zero_sh, rad, valid) == pytest.approx(0.5, rel=1e-6)
    # a constant sky as its SH (c_00 = √(4π) L): E = π, no lights needed
    sky = np.zeros((25, 3))
    sky[0] = math.sqrt(4 * math.pi)
    assert lights_irradiance_error(None, sky, np.ones((H, W, 3)), valid) < 2e-3
    assert math.isnan(lights_irradiance_error(None, zero_sh, np.zeros((H, W, 3)), valid))


# --- the composite scoring -----------------------------------------------------------------------------


def _frame(path, *, gains, with_value, n_object, n_shadow, shape=(6, 10)):
    """A reference frame: rows 0.. with the object (first n_object pixels), then shadow pixels; one
    invalid pixel inside each region; NaN outside the valid pixels."""
    h, w = shape
    obj = np.zeros(h * w, bool)
    obj[:n_object] = True
    shadow = np.zeros(h * w, bool)
    shadow[n_object:n_object + n_shadow] = True
    valid = obj | shadow
    valid[[0, n_object]] = False
    ref = np.full((h * w, 3), np.nan, np.float32)
    ref[obj] = with_value[0]
    ref[shadow] = with_value[1]
    np.savez_compressed(path, with_object=ref.reshape(h, w, 3).astype(np.float16),
                        without_object=ref.reshape(h, w, 3).astype(np.float16), object_mask=obj.reshape(h, w),
                        shadow_mask=shadow.reshape(h, w), valid=valid.reshape(h, w), gains=np.asarray(gains, np.float64))


def test_score_composites_pools_squared_errors_over_frames_in_the_references_linear_space(tmp_path):
    # code 255 decodes to 1.0; divided by gains 2 → 0.5; object reference 0.4 (error 0.1), shadow 0.25 (error 0.25)
    _frame(tmp_path / "100.npz", gains=[2.0, 2.0, 2.0], with_value=(0.375, 0.25), n_object=5, n_shadow=9)
    _frame(tmp_path / "200.npz", gains=[4.0, 4.0, 4.0], with_value=(0.375, 0.25), n_object=3, n_shadow=3)
    _frame(tmp_path / "300.npz", gains=[1.0, 1.0, 1.0], with_value=(1.0, 1.0), n_object=3, n_shadow=3)
    refs = {int(p.stem): p for p in tmp_path.glob("*.npz")}
    white = np.full((6, 10, 3), 255, np.uint8)
    got = score_composites({100: white, 200: white, 999: white}, refs)
    # frame 100: 4 object pixels at 0.5 vs 0.375, 8 shadow at 0.5 vs 0.25; frame 200: 2 at 0.25 vs 0.375, 2 at 0.25 vs 0.25
    num_o, den_o = 4 * 0.125 ** 2 + 2 * 0.125 ** 2, 6 * 0.375 ** 2
    num_s, den_s = 8 * 0.25 ** 2 + 0.0, 10 * 0.25 ** 2
    assert got["composite_object_rel_rmse"] == pytest.approx(math.sqrt(num_o / den_o), rel=1e-12)
    assert got["composite_shadow_rel_rmse"] == pytest.approx(math.sqrt(num_s / den_s), rel=1e-12)
    assert got["composite_rel_rmse"] == pytest.approx(math.sqrt((num_o + num_s) / (den_o + den_s)), rel=1e-12)
    assert (got["composite_reference_frames"], got["composite_reference_missing"]) == (2, 1)
    assert (got["composite_object_pixels"], got["composite_shadow_pixels"]) == (6, 10)
    none = score_composites({}, refs)
    assert none["composite_rel_rmse"] is None and none["composite_reference_missing"] == 3
    with pytest.raises(InvalidInputError, match="shape"):
        score_composites({100: white[:5]}, refs)


def test_the_scorer_keeps_only_the_reference_timestamps(tmp_path):
    _frame(tmp_path / "100.npz", gains=[1, 1, 1], with_value=(0.5, 0.5), n_object=4, n_shadow=4)
    (tmp_path / "frames.csv").write_text("not a frame\n")
    scorer = ReferenceScorer(tmp_path)
    step = type("Step", (), {})
    for ts, image in ((50, np.zeros((6, 10, 3), np.uint8)), (100, np.full((6, 10, 3), 188, np.uint8)), (100, None)):
        s = step()
        s.timestamp_ns, s.image = ts, image
        scorer.on_step(s, None)
    assert list(scorer.images) == [100]
    metrics, facts = scorer.finish(None, tmp_path)
    assert facts["reference_frames"] == 1 and metrics["composite_rel_rmse"] < 0.01  # code 188 ≈ 0.5 linear


# --- the outputs ---------------------------------------------------------------------------------------


def test_sweep_csv_round_trips_and_the_plot_covers_the_rendering_axes(tmp_path):
    from apps.sweep import _write_outputs

    def row(axis, name, **acc):
        return {"axis": axis, "name": name, "depth_total_median_ms": 20.0, "depth_total_p95_ms": 30.0,
                "colour_total_median_ms": 9.0, "colour_total_p95_ms": 12.0,
                "stages": {"Lights from the map": 2.5, "Rasterise": 7.0, "Project sample to EM*": 3.0}, "accuracy": acc}

    rows = [row("default", "default", em_ws_psnr_db=30.0), row("em_size", "em 500x250", em_ws_psnr_db=29.0),
            row("render_default", "render default", composite_rel_rmse=0.2, lights_irradiance_rel_error=0.05),
            row("lights", "lights pharr 48", composite_rel_rmse=0.25, lights_irradiance_rel_error=0.03, lights_count=48),
            row("composite", "composite paper003", composite_rel_rmse=0.3)]
    md = _write_outputs(tmp_path, rows, reference="RUN/reference").read_text()
    assert "## Rendering axes" in md and "| lights | lights pharr 48 | 20 / 30 | 9 / 12 | 2.5 |" in md
    assert "RUN/reference" in md and (tmp_path / "pareto.png").stat().st_size > 0
    back = read_rows(tmp_path / "sweep.csv")
    assert [r["name"] for r in back] == [r["name"] for r in rows]
    assert back[3]["accuracy"]["lights_count"] == 48 and back[3]["stages"]["Lights from the map"] == 2.5
    assert back[4]["accuracy"]["composite_rel_rmse"] == 0.3 and back[1]["stages"]["Project sample to EM*"] == 3.0
    pareto(tmp_path / "again.png", back)


# --- the scoring identity on a tiny simulated run ------------------------------------------------------

# the small lit room of the reference-frame tests (walls, table, a ceiling lamp), under its own name
_ROOM = {**_REFERENCE_ROOM, "name": "sweep_room"}
_SETTINGS = ["capture.width=400", "capture.height=200"]


@pytest.mark.slow
def test_the_default_point_scores_the_composite_as_simulate_did(tmp_path):
    from apps.cli import main
    from apps.replay import default_origin
    from apps.sweep import default_reference
    from rgbd_envmap.logs import SessionLog

    scene = tmp_path / "room.yaml"
    scene.write_text(yaml.safe_dump(_ROOM))
    run = tmp_path / "run"
    argv = ["simulate", "--scene", str(scene), "--duration", "2.2", "--out", str(run), "--colour-size", "160x90",
            "--reference-every", "1", "--reference-spp", "8", "--reference-object-spp", "16", "--no-video", "--quiet"]
    assert main(argv + [a for s in _SETTINGS for a in ("--set", s)]) == 0
    truth = json.loads((run / "accuracy.json").read_text())
    assert truth["composite_reference_frames"] >= 1 and truth["composite_rel_rmse"] is not None
    log = run / "session"
    reference = default_reference(log)
    assert reference == (run / "reference").resolve()
    origin = default_origin(SessionLog.open(log)).tolist()
    points = {p.name: p for p in grid(["lights", "composite"])}
    default = next(p for p in points.values() if p.axis == "render_default")
    got = run_point(log, tmp_path / "default", default, origin, reference=reference, base_overrides=_SETTINGS)["accuracy"]
    assert got["composite_reference_frames"] == truth["composite_reference_frames"]
    assert got["composite_reference_missing"] == 0
    for key in ("composite_object_pixels", "composite_shadow_pixels"):
        assert got[key] == truth[key], key
    for key in ("composite_rel_rmse", "composite_object_rel_rmse", "composite_shadow_rel_rmse"):
        # the same composite; the sweep reads the references as stored (float16)
        assert got[key] == pytest.approx(truth[key], rel=2e-3, abs=1e-6), key
    assert 0 <= got["lights_irradiance_rel_error"] < 1 and got["lights_count"] >= 1
    assert 0 <= got["sh_irradiance_rel_error"] < 0.1
    # another composite mode draws another composite, scored on the same frames
    other = run_point(log, tmp_path / "paper003", points["composite paper003"], origin, reference=reference,
                      base_overrides=_SETTINGS)["accuracy"]
    assert other["composite_reference_frames"] == truth["composite_reference_frames"]
    assert other["composite_rel_rmse"] != pytest.approx(got["composite_rel_rmse"], rel=1e-3)
    assert "lights_irradiance_rel_error" not in other
    assert not list((tmp_path / "default").glob("*.mp4"))
    # the sweep's own options: a folder without frames, a bad setting (usage errors, before any point runs)
    for extra in (["--reference", str(tmp_path / "nothing")], ["--set", "render.lights=0"]):
        assert main(["sweep", str(log), "--out", str(tmp_path / "bad"), "--axes", "lights", "--quiet", *extra]) == 2
    assert not (tmp_path / "bad" / "points").exists()
