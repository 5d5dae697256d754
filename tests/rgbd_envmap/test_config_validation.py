"""Config dataclasses check every field at construction: the project's typed errors naming the field,
for wrong types, NaN / inf, out-of-range values, unknown method names and sizes past their bound."""

import math

import pytest

from rgbd_envmap.checks import check_flag, check_number
from rgbd_envmap.config import apply_overrides
from rgbd_envmap.envmap import UpdateConfig
from rgbd_envmap.errors import DTypeError, InvalidInputError, RangeError, RgbdEnvmapError, UnknownMethodError
from rgbd_envmap.ingest.tango import TangoIngestConfig
from rgbd_envmap.pipeline import CaptureConfig, ObjectConfig, PipelineConfig, PoseCheckConfig, RenderConfig, ShadingConfig
from rgbd_envmap.prt import MAX_PRT_DIRS
from rgbd_envmap.sh import MAX_BANDS

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


BAD_SHADING = [
    ("bands", 0, RangeError), ("bands", MAX_BANDS + 1, RangeError), ("bands", 1000, RangeError),
    ("bands", "x", DTypeError), ("bands", 2.0, DTypeError), ("bands", True, DTypeError),
    ("auto_bands", "true", DTypeError), ("auto_bands", 1, DTypeError),
    ("band_tolerance", math.nan, RangeError), ("band_tolerance", -0.01, RangeError),
    ("band_tolerance", math.inf, RangeError), ("band_tolerance", "0.01", DTypeError),
    ("max_bands", 0, RangeError), ("max_bands", 10**6, RangeError), ("max_bands", None, DTypeError),
    ("lighting_convention", "maya", UnknownMethodError), ("lighting_file", "", InvalidInputError),
]

BAD_OBJECT = [
    ("name", "teapot", UnknownMethodError), ("name", None, UnknownMethodError),
    ("height_m", -1.0, RangeError), ("height_m", 0.0, RangeError), ("height_m", math.nan, RangeError),
    ("height_m", "0.1", DTypeError),
    ("base_below_origin_m", math.inf, RangeError), ("base_below_origin_m", None, DTypeError),
    ("prt_dirs", 0, RangeError), ("prt_dirs", MAX_PRT_DIRS + 1, RangeError), ("prt_dirs", 10**12, RangeError),
    ("prt_dirs", 1024.0, DTypeError), ("prt_dirs", False, DTypeError),
    ("plane_size_m", 0.0, RangeError), ("plane_size_m", -0.5, RangeError), ("plane_size_m", math.nan, RangeError),
    ("plane_size_m", 1e7, RangeError),
    ("plane_resolution", 1, RangeError), ("plane_resolution", 10**5, RangeError), ("plane_resolution", 4.5, DTypeError),
]

BAD_RENDER = [
    ("enabled", "no", DTypeError), ("enabled", 0, DTypeError), ("backend", "vulkan", UnknownMethodError),
    ("shadow_grey", -0.1, RangeError), ("shadow_grey", 1.5, RangeError), ("shadow_grey", math.nan, RangeError),
    ("shadow_grey", None, DTypeError),
]

BAD_PIPELINE = [
    ("shading", {"bands": 3}, DTypeError), ("object", None, DTypeError), ("render", ShadingConfig(), DTypeError),
    ("capture", "default", DTypeError), ("ingest", CaptureConfig(), DTypeError), ("kinect", 1, DTypeError),
    ("pose_check", RenderConfig(), DTypeError),
    ("max_colour_lag_ms", -1.0, RangeError), ("max_colour_lag_ms", math.nan, RangeError),
    ("max_colour_lag_ms", "20", DTypeError),
    ("kinect_em_every", 0, RangeError), ("kinect_em_every", 6.0, DTypeError),
    ("kinect_em_stride", -2, RangeError), ("kinect_em_stride", None, DTypeError),
]


@pytest.mark.parametrize("cls,prefix,field,value,error",
                         [(ShadingConfig, "shading.", *c) for c in BAD_SHADING]
                         + [(ObjectConfig, "object.", *c) for c in BAD_OBJECT]
                         + [(RenderConfig, "render.", *c) for c in BAD_RENDER]
                         + [(PipelineConfig, "", *c) for c in BAD_PIPELINE])
def test_pipeline_sections_reject_bad_fields(cls, prefix, field, value, error):
    with pytest.raises(error, match=f"^{prefix}{field}: (expected|unknown method)") as info:
        cls(**{field: value})
    assert "\n" not in str(info.value)  # one line, naming the field


def test_section_bounds_themselves_are_accepted():
    assert ShadingConfig(bands=MAX_BANDS, max_bands=MAX_BANDS, band_tolerance=0.0).bands == MAX_BANDS
    assert ShadingConfig(bands=1, max_bands=1).max_bands == 1
    oc = ObjectConfig(name="blob", prt_dirs=MAX_PRT_DIRS, plane_resolution=2, plane_size_m=None,
                      base_below_origin_m=-0.2)
    assert (oc.prt_dirs, oc.plane_resolution, oc.plane_size_m) == (MAX_PRT_DIRS, 2, None)
    assert RenderConfig(enabled=False, backend="pyrender", shadow_grey=1.0).shadow_grey == 1.0
    assert RenderConfig(shadow_grey=0).shadow_grey == 0
    cfg = PipelineConfig(max_colour_lag_ms=0.0, kinect_em_every=1, kinect_em_stride=1, pose_check=PoseCheckConfig())
    assert (cfg.kinect_em_every, cfg.kinect_em_stride) == (1, 1)


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
    ("shading.bands=1000", "shading.bands"),
    ("shading.bands=x", "shading.bands"),
    ("shading.band_tolerance=.nan", "shading.band_tolerance"),
    ("shading.auto_bands=maybe", "shading.auto_bands"),
    ("object.height_m=-1", "object.height_m"),
    ("object.prt_dirs=1000000000000", "object.prt_dirs"),
    ("object.name=teapot", "object.name"),
    ("render.backend=vulkan", "render.backend"),
    ("render.shadow_grey=2", "render.shadow_grey"),
    ("kinect_em_every=0", "kinect_em_every"),
    ("max_colour_lag_ms=-1", "max_colour_lag_ms"),
])
def test_command_line_overrides_are_checked_as_the_config_is_built(override, field):
    with pytest.raises(RgbdEnvmapError, match=field) as info:
        apply_overrides(PipelineConfig(), [override])
    assert "\n" not in str(info.value)


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
