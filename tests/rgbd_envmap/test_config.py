import dataclasses

import pytest

from rgbd_envmap.config import apply_overrides, dump_yaml, from_dict, load_yaml, to_dict
from rgbd_envmap.errors import InvalidInputError, UnknownMethodError
from rgbd_envmap.pipeline import PipelineConfig


def test_round_trip_through_a_dict_and_yaml(tmp_path):
    cfg = PipelineConfig()
    assert from_dict(PipelineConfig, to_dict(cfg)) == cfg
    dump_yaml(cfg, tmp_path / "c.yaml")
    assert load_yaml(PipelineConfig, tmp_path / "c.yaml") == cfg


def test_partial_yaml_overrides_only_what_it_names(tmp_path):
    (tmp_path / "p.yaml").write_text("capture:\n  width: 1000\n  height: 500\n  update:\n    splat_scale: 1.25\nshading: {bands: 3}\n")
    cfg = load_yaml(PipelineConfig, tmp_path / "p.yaml")
    assert (cfg.capture.width, cfg.capture.height, cfg.capture.update.splat_scale, cfg.shading.bands) == (1000, 500, 1.25, 3)
    default = PipelineConfig()
    assert cfg.capture.update.trusted_radius_m == default.capture.update.trusted_radius_m
    assert cfg.ingest == default.ingest and cfg.render == default.render


def test_dotted_overrides_coerce_to_the_field_types():
    cfg = apply_overrides(PipelineConfig(), [
        "capture.ccm_method=Cheung 2004", "capture.colour_correction=false", "ingest.fill_method=none",
        "shading.bands=7", "capture.update.splat_scale=2", "capture.edge_margin_px=null", "max_colour_lag_ms=5",
    ])
    assert cfg.capture.ccm_method == "Cheung 2004" and cfg.capture.colour_correction is False
    assert cfg.ingest.fill_method is None and cfg.capture.edge_margin_px is None
    assert cfg.shading.bands == 7 and isinstance(cfg.shading.bands, int)
    assert cfg.capture.update.splat_scale == 2.0 and isinstance(cfg.capture.update.splat_scale, float)
    assert cfg.max_colour_lag_ms == 5.0
    assert dataclasses.is_dataclass(cfg.capture.update)


@pytest.mark.parametrize("override, message", [
    ("capture.nope=1", "capture.nope"),
    ("nosuch=1", "nosuch"),
    ("shading.bands=abc", "shading.bands"),
    ("shading.bands=2.5", "shading.bands"),
    ("render.enabled=maybe", "render.enabled"),
    ("capture=3", "capture"),
    ("no_equals_sign", "KEY=VALUE"),
])
def test_bad_overrides_name_the_key(override, message):
    with pytest.raises(InvalidInputError, match=message.replace(".", r"\.")):
        apply_overrides(PipelineConfig(), [override])


def test_invalid_values_are_caught_by_the_configs_own_checks():
    with pytest.raises(UnknownMethodError):
        apply_overrides(PipelineConfig(), ["capture.filled_pixels=some"])
    with pytest.raises(UnknownMethodError):
        apply_overrides(PipelineConfig(), ["translation_method=teleport"])


def test_bad_yaml_files(tmp_path):
    with pytest.raises(InvalidInputError, match="no such config file"):
        load_yaml(PipelineConfig, tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("capture: [unclosed\n")
    with pytest.raises(InvalidInputError, match="not valid YAML"):
        load_yaml(PipelineConfig, tmp_path / "bad.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(InvalidInputError, match="mapping"):
        load_yaml(PipelineConfig, tmp_path / "list.yaml")
