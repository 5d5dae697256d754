"""Colour: the sensor boundary (NV21, sRGB: :mod:`rgbd_envmap.colour.nv21`) and the colour-correction
matrix of paper 003 §5 (:mod:`rgbd_envmap.colour.ccm`) and HDR capture (frames brought to one
exposure, clipped pixels flagged: :mod:`rgbd_envmap.colour.hdr`). Every public name is re-exported here.
"""

from rgbd_envmap.colour.ccm import (
    CCM_METHODS,
    DEFAULT_MAX_CONDITION,
    DEFAULT_RIDGE,
    GAIN_CHANNELS,
    MIN_SPREAD_SNR,
    SUMS_CCM_METHODS,
    CCMResult,
    apply_ccm,
    ccm_from_sums,
    ccm_sums,
    estimate_ccm,
    invert_ccm,
    matrix_gain,
)
from rgbd_envmap.colour.hdr import HDRConfig, clipped_pixels, exposure_scale, hdr_frame, low_confidence_pixels
from rgbd_envmap.colour.nv21 import decode_nv21, encode_nv21, linear_to_srgb, srgb8_to_linear_lut, srgb_to_linear

__all__ = [
    "decode_nv21",
    "encode_nv21",
    "srgb_to_linear",
    "linear_to_srgb",
    "srgb8_to_linear_lut",
    "CCM_METHODS",
    "SUMS_CCM_METHODS",
    "GAIN_CHANNELS",
    "DEFAULT_RIDGE",
    "DEFAULT_MAX_CONDITION",
    "MIN_SPREAD_SNR",
    "CCMResult",
    "estimate_ccm",
    "ccm_sums",
    "ccm_from_sums",
    "apply_ccm",
    "invert_ccm",
    "matrix_gain",
    "HDRConfig",
    "clipped_pixels",
    "exposure_scale",
    "hdr_frame",
    "low_confidence_pixels",
]
