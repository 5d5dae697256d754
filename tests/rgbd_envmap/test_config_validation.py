"""Config dataclasses check every field at construction: the project's typed errors naming the field,
for wrong types, NaN / inf, out-of-range values, unknown method names and sizes past their bound."""

import math

import pytest

from rgbd_envmap.checks import check_flag, check_number
from rgbd_envmap.config import apply_overrides
from rgbd_envmap.envmap import UpdateConfig
from rgbd_envmap.errors import DTypeError, RangeError, RgbdEnvmapError, UnknownMethodError
from rgbd_envmap.ingest.tango import TangoIngestConfig
from rgbd_envmap.pipeline import CaptureConfig, PipelineConfig

BAD_UPDATE = [
    ("trusted_radius_m", -0.1, RangeError), ("trusted_radius_m", math.nan, RangeError),
    ("removal_radius_m", math.inf, RangeError), ("removal_radius_m", "0.03", DTypeError),
    ("splat", "yes", DTypeError), ("splat", 1, DTypeError),
    ("splat_scale", 0.0, RangeError), ("splat_scale", math.nan, RangeError), ("splat_scale", -1.0, RangeError),
    ("max_splat_px", -1, RangeError), ("max_splat_px", 0, RangeError), ("max_splat_px", 10_000, RangeError),
    ("max_splat_px", 2.5, DTypeError), ("max_splat_px", True, DTypeError),
    ("carve", None, DTypeError), ("carve_tol_rel", -0.01, RangeError), ("carve_tol_abs_m", math.nan, RangeError),
    ("carve_window", 2, RangeError), ("carve_window", 0, RangeError), ("colour_average", 256, RangeError),
]


@pytest.mark.parametrize("field,value,error", BAD_UPDATE)
def test_update_config_rejects_bad_fields(field, value, error):
    with pytest.raises(error, match=f"UpdateConfig.{field}"):
        UpdateConfig(**{field: value})


BAD_CAPTURE = [
    ("height", 0, RangeError), ("width", -5, RangeError), ("height", 1.5, DTypeError),
    ("pair_max_depth_diff_m", math.nan, RangeError), ("pair_max_depth_diff_m", -1.0, RangeError),
    ("colour_correction", "false", DTypeError), ("update", "x", DTypeError),
    ("edge_margin_px", -1, RangeError), ("edge_margin_px", 1.5, DTypeError), ("freeze", 0, DTypeError),
    ("max_mse", math.nan, RangeError), ("min_pairs", 0, RangeError),
]


@pytest.mark.parametrize("field,value,error", BAD_CAPTURE)
def test_capture_config_rejects_bad_fields(field, value, error):
    with pytest.raises(error, match=f"CaptureConfig.{field}"):
        CaptureConfig(**{field: value})


def test_a_map_too_large_is_refused_saying_how_much_memory_it_would_take():
    with pytest.raises(RangeError, match=r"100000×200000 would take about [0-9.]+ GiB"):
        CaptureConfig(height=100_000, width=200_000)
    CaptureConfig(height=4096, width=8192)  # the bound itself is accepted


def test_unknown_method_names_fail_when_the_config_is_made():
    with pytest.raises(UnknownMethodError, match="TangoIngestConfig.fill_method.*monroy2018"):
        TangoIngestConfig(fill_method="bogus")
    with pytest.raises(UnknownMethodError, match="TangoIngestConfig.reliability_method"):
        TangoIngestConfig(reliability_method="bogus")
    TangoIngestConfig(fill_method=None)  # hole filling off


@pytest.mark.parametrize("override,field", [
    ("capture.update.max_splat_px=-1", "max_splat_px"),
    ("capture.update.splat_scale=nan", "splat_scale"),
    ("capture.update.splat_scale=.nan", "splat_scale"),
    ("capture.height=0", "height"),
    ("ingest.fill_method=bogus", "fill_method"),
])
def test_command_line_overrides_are_checked_as_the_config_is_built(override, field):
    with pytest.raises(RgbdEnvmapError, match=field):
        apply_overrides(PipelineConfig(), [override])


def test_defaults_and_valid_values_pass_unchanged():
    cfg = UpdateConfig(max_splat_px=8, splat_scale=1.25, carve=False)
    assert (cfg.max_splat_px, cfg.splat_scale, cfg.carve) == (8, 1.25, False)
    assert apply_overrides(PipelineConfig(), ["capture.update.max_splat_px=12"]).capture.update.max_splat_px == 12


def test_check_number_and_check_flag():
    assert check_number(3, "x", low=0, integer=True) == 3
    assert check_number(None, "x", optional=True) is None
    assert check_number(0.5, "x", low=0.0, high=1.0) == 0.5
    with pytest.raises(RangeError, match="x: expected a number > 0"):
        check_number(0.0, "x", low=0.0, low_open=True)
    with pytest.raises(RangeError, match="x: expected a number ≥ 0.0 and < 1.0, got 1.0"):
        check_number(1.0, "x", low=0.0, high=1.0, high_open=True)
    with pytest.raises(DTypeError, match="x: expected a number, got None"):
        check_number(None, "x")
    with pytest.raises(DTypeError):
        check_number(False, "x")
    assert check_flag(False, "f") is False
    with pytest.raises(DTypeError, match="f: expected True or False"):
        check_flag("False", "f")
