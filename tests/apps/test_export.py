"""The run folder's envmap.hdr / envmap.exr, ``rgbd-envmap export`` and ``--envmap FILE``.

Independent readers: OpenCV (``cv2.imread``, IMREAD_ANYDEPTH | IMREAD_ANYCOLOR, BGR) for .hdr and the
``OpenEXR`` package for .exr. RGBE bound: the writer truncates each channel to 8 bits at the pixel's
shared exponent e (largest channel M ∈ [2^(e−1), 2^e)) and OpenCV decodes without an offset, so
0 ≤ x − x̂ < 2^(e−8) ≤ 2^-7 · M (docs/reference/export.md derives it).

The parsers are built here from ``add_export_parser`` / ``add_envmap_args``, as apps.cli wires them.
"""

from __future__ import annotations

import argparse
import json

import cv2
import numpy as np
import OpenEXR
import pytest

from apps.export import add_envmap_args, add_export_parser, envmap_config, run_export
from apps.run import save_envmap
from rgbd_envmap.envmap import EnvironmentMap
from rgbd_envmap.envmap_io import to_convention, write_envmap
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.pipeline import PipelineConfig


def cv2_read(path):
    img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    assert img is not None and img.dtype == np.float32
    return img[..., ::-1]


def exr_read(path):
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {k: np.asarray(c.pixels) for k, c in f.channels().items()}, dict(f.header())


def assert_rgbe(decoded, truth):
    truth = np.maximum(truth.astype(np.float64), 0.0)
    M = truth.max(axis=-1, keepdims=True)
    _, e = np.frexp(M)
    err = truth - decoded
    assert np.all(err >= 0) and np.all(err < np.ldexp(1.0, e - 8)) and np.all(err <= 2.0 ** -7 * M)


def make_map(H=50, W=100, seed=0):
    rng = np.random.default_rng(seed)
    rad = (rng.random((H, W, 3)) * 10.0 ** rng.integers(-3, 3, (H, W, 1))).astype(np.float32)
    valid = rng.random((H, W)) > 0.25
    depth = (0.5 + 4 * rng.random((H, W))).astype(np.float32)
    return EnvironmentMap.from_arrays(rad, depth, valid, np.array([0.0, 0.0, 0.8]))


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    em = make_map()
    em.radiance_planes[:, ~em.valid] = 7.0  # meaningless data under invalid pixels: never written out
    save_envmap(out, em)
    return out


def test_run_folder_hdr_equals_the_npz_to_rgbe_precision(run_folder):
    with np.load(run_folder / "envmap.npz") as z:
        rad, valid = z["radiance"], z["valid"]
    got = cv2_read(run_folder / "envmap.hdr")
    assert got.shape == rad.shape
    assert_rgbe(got[valid], rad[valid])
    np.testing.assert_array_equal(got[~valid], 0)  # invalid pixels: 0 radiance


def test_run_folder_exr_equals_the_npz_exactly(run_folder):
    with np.load(run_folder / "envmap.npz") as z:
        rad, valid, depth, origin = z["radiance"], z["valid"], z["depth_m"], z["origin"]
    ch, header = exr_read(run_folder / "envmap.exr")
    assert set(ch) == {"R", "G", "B", "valid", "depth"}
    np.testing.assert_array_equal(ch["valid"] > 0.5, valid)
    np.testing.assert_array_equal(np.unique(ch["valid"]), [0, 1])
    for i, c in enumerate("RGB"):
        assert ch[c].dtype == np.float32
        np.testing.assert_array_equal(ch[c][valid], rad[..., i][valid])
        np.testing.assert_array_equal(ch[c][~valid], 0)
    np.testing.assert_array_equal(ch["depth"][valid], depth[valid])
    np.testing.assert_array_equal(ch["depth"][~valid], 0)
    assert header["rgbd_envmap_convention"] == "ours"
    np.testing.assert_array_equal(header["rgbd_envmap_origin"], origin)


# ---------------------------------------------------------------------------------------- export

def parse(argv):
    parser = argparse.ArgumentParser(prog="rgbd-envmap")
    add_export_parser(parser.add_subparsers(dest="command", required=True), argparse.HelpFormatter)
    return parser.parse_args(["export", *argv])


@pytest.mark.parametrize("convention", ["blender", "mitsuba", "ours"])
def test_export_exr_in_each_convention(run_folder, tmp_path, convention, capsys):
    out = tmp_path / f"m_{convention}.exr"
    assert run_export(parse([str(run_folder), "--convention", convention, "--out", str(out)])) == 0
    assert str(out) in capsys.readouterr().out
    with np.load(run_folder / "envmap.npz") as z:
        rad, valid, depth = z["radiance"], z["valid"], z["depth_m"]
    ch, header = exr_read(out)
    assert header["rgbd_envmap_convention"] == convention
    want_valid = to_convention(valid, convention)
    np.testing.assert_array_equal(ch["valid"] > 0.5, want_valid)
    rgb = np.stack([ch[c] for c in "RGB"], axis=-1)
    np.testing.assert_array_equal(rgb, to_convention(np.where(valid[..., None], rad, 0), convention))
    np.testing.assert_array_equal(ch["depth"], to_convention(np.where(valid, depth, 0), convention))


def test_export_defaults_and_hdr(run_folder, tmp_path):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(run_folder, run)
    assert run_export(parse([str(run), "--convention", "blender"])) == 0
    assert (run / "envmap_blender.exr").stat().st_size > 0  # default: RUN/envmap_CONVENTION.exr
    assert run_export(parse([str(run / "envmap.npz"), "--convention", "mitsuba", "--format", "hdr"])) == 0
    with np.load(run / "envmap.npz") as z:
        rad, valid = z["radiance"], z["valid"]
    got = cv2_read(run / "envmap_mitsuba.hdr")
    assert_rgbe(got, to_convention(np.where(valid[..., None], rad, 0), "mitsuba"))
    assert run_export(parse([str(run), "--convention", "ours", "--out", str(tmp_path / "h.exr"), "--half"])) == 0
    ch, _ = exr_read(tmp_path / "h.exr")
    assert ch["R"].dtype == np.float16
    np.testing.assert_array_equal(ch["R"], np.where(valid, rad[..., 0], 0).astype(np.float16))


@pytest.mark.parametrize("argv, message", [
    (["--convention", "blender", "--out", "x.exr", "--format", "hdr"], "does not match"),
    (["--convention", "blender", "--out", "x.png"], r"\.hdr or \.exr"),
    (["--convention", "blender", "--format", "hdr", "--half"], "--half"),
])
def test_export_bad_options_fail_clearly(run_folder, tmp_path, argv, message):
    argv = [a if a != "x.exr" and a != "x.png" else str(tmp_path / a) for a in argv]
    with pytest.raises(InvalidInputError, match=message):
        run_export(parse([str(run_folder), *argv]))


def test_export_of_a_folder_without_a_map_fails_naming_it(tmp_path):
    with pytest.raises(InvalidInputError, match="envmap.npz"):
        run_export(parse([str(tmp_path), "--convention", "ours"]))
    np.savez(tmp_path / "other.npz", radiance=np.zeros((2, 4, 3)))
    with pytest.raises(InvalidInputError, match="missing arrays"):
        run_export(parse([str(tmp_path / "other.npz"), "--convention", "ours"]))


def test_export_needs_a_convention(run_folder, capsys):
    with pytest.raises(SystemExit):
        parse([str(run_folder)])
    assert "--convention" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------- --envmap

def envmap_args(argv):
    parser = argparse.ArgumentParser()
    add_envmap_args(parser.add_argument_group("pipeline settings"))
    return parser.parse_args(argv)


def test_envmap_args_set_the_lighting_file(tmp_path, monkeypatch):
    em = make_map(16, 32)
    write_envmap(tmp_path / "sky.exr", em.radiance, em.valid, convention="blender")
    monkeypatch.chdir(tmp_path)
    cfg = envmap_config(PipelineConfig(), envmap_args(["--envmap", "sky.exr"]))
    assert cfg.shading.lighting_file == str((tmp_path / "sky.exr").resolve()) and cfg.shading.lighting_convention is None
    cfg = envmap_config(PipelineConfig(), envmap_args(["--envmap", "sky.exr", "--envmap-convention", "ours"]))
    assert cfg.shading.lighting_convention == "ours"
    assert envmap_config(PipelineConfig(), envmap_args([])) == PipelineConfig()
    with pytest.raises(InvalidInputError, match="no such file"):
        envmap_config(PipelineConfig(), envmap_args(["--envmap", "missing.hdr"]))
    with pytest.raises(InvalidInputError, match="needs --envmap"):
        envmap_config(PipelineConfig(), envmap_args(["--envmap-convention", "blender"]))
    with pytest.raises(SystemExit):
        envmap_args(["--envmap", "sky.exr", "--envmap-convention", "unity"])


@pytest.mark.slow
def test_simulate_lit_from_a_file_still_captures_and_reports(tmp_path):
    """End to end: a 1 s session lit by an .hdr exported from another map; the capture's accuracy is
    reported and the lighting metrics measure the file's lighting against the true map."""
    from apps.simulate import SimulateOptions, run_simulate
    from rgbd_envmap import sh
    from rgbd_envmap.config import load_yaml
    from rgbd_envmap.envmap_io import read_envmap

    em = make_map(32, 64, seed=3)
    write_envmap(tmp_path / "sky.hdr", em.radiance, em.valid, convention="mitsuba")
    cfg = envmap_config(PipelineConfig(), envmap_args(["--envmap", str(tmp_path / "sky.hdr")]))
    cfg = load_yaml(PipelineConfig, _yaml(tmp_path, cfg))  # through config.yaml, as a replay would read it
    from dataclasses import replace

    from rgbd_envmap.pipeline import RenderConfig
    from rgbd_envmap.pipeline.capture import CaptureConfig

    cfg = replace(cfg, capture=CaptureConfig(height=250, width=500), render=RenderConfig(enabled=False))
    out = tmp_path / "run"
    run_simulate(SimulateOptions(duration_s=1.0, out=out, seed=1, colour_width=320, colour_height=180, config=cfg,
                                 progress=False, video=False, preview_envmap_height=32))
    for name in ("envmap.npz", "envmap.hdr", "envmap.exr", "accuracy.json", "config.yaml"):
        assert (out / name).stat().st_size > 0, name
    assert "lighting_file: " + str(tmp_path / "sky.hdr") in (out / "config.yaml").read_text()
    acc = json.loads((out / "accuracy.json").read_text())
    assert 0 < acc["em_coverage"] <= 1 and np.isfinite(acc["em_ws_psnr_db"])
    with np.load(out / "session" / "groundtruth" / "envmap.npz") as z:
        truth = sh.project_equirect(z["radiance"], z["valid"], 5)
    lit = sh.project_equirect(read_envmap(tmp_path / "sky.hdr").radiance, None, 5)
    want = np.linalg.norm(lit - truth) / np.linalg.norm(truth)
    assert acc["sh_coeff_rel_error"] == pytest.approx(want, rel=1e-9)
    timing = (out / "timing.csv").read_text()
    assert "Project sample to EM*" in timing and "Calculate SH coefficients*" not in timing


def _yaml(tmp_path, cfg):
    from rgbd_envmap.config import dump_yaml

    path = tmp_path / "cfg.yaml"
    dump_yaml(cfg, path)
    return path
