"""Tests for rgbd_envmap.checks (input validation helpers) and the error hierarchy they raise."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from rgbd_envmap import errors
from rgbd_envmap.checks import check_array, check_finite, check_method, check_positive_int, check_range
from rgbd_envmap.errors import (
    DTypeError,
    NonFiniteError,
    RangeError,
    RgbdEnvmapError,
    ShapeError,
    UnknownMethodError,
)


@dataclass(frozen=True)
class _Tolerances:
    range_edge: float = 1e-12  #: a step just outside a closed interval that must be rejected


TOL = _Tolerances()


# --------------------------------------------------------------------------------------------------
# The error hierarchy
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cls,builtin", [
    (errors.InvalidInputError, ValueError), (ShapeError, ValueError), (NonFiniteError, ValueError),
    (RangeError, ValueError), (UnknownMethodError, ValueError), (errors.LogFormatError, ValueError),
    (DTypeError, TypeError),
])
def test_every_error_is_a_project_error_and_a_builtin(cls, builtin):
    assert issubclass(cls, RgbdEnvmapError)
    assert issubclass(cls, builtin)


def test_all_names_in_errors_exist():
    for name in errors.__all__:
        assert issubclass(getattr(errors, name), Exception)


# --------------------------------------------------------------------------------------------------
# check_array: shape specs
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape,spec", [
    ((4, 3), ("N", 3)),
    ((0, 3), ("N", 3)),
    ((3,), ("*", 3)),
    ((2, 5, 3), ("*", 3)),
    ((2, 5, 7, 3), ("*", "H", "W", 3)),
    ((5, 6, 3), ("H", "W", 3)),
    ((4, 4), ("N", "N")),
    ((2, 4, 4), ("*", "N", "N")),
    ((), ()),
    ((2, 3), ("*",)),
    ((), ("*",)),
])
def test_shape_spec_matches(shape, spec):
    arr = check_array(np.zeros(shape), "x", shape=spec)
    assert arr.shape == shape


@pytest.mark.parametrize("shape,spec", [
    ((4, 2), ("N", 3)),
    ((4,), ("N", 3)),
    ((4, 3, 1), ("N", 3)),
    ((2,), ("*", 3)),
    ((), ("*", 3)),
    ((3, 2), ("*", 3)),
    ((4, 5), ("N", "N")),
    ((2, 4, 5), ("*", "N", "N")),
    ((5, 6, 3), ("H", "H", 3)),
    ((3,), ()),
])
def test_shape_spec_rejects(shape, spec):
    with pytest.raises(ShapeError) as info:
        check_array(np.zeros(shape), "my_arg", shape=spec)
    msg = str(info.value)
    assert "my_arg" in msg
    assert str(shape) in msg  # the actual shape
    assert isinstance(info.value, ValueError)


def test_named_dims_are_independent_between_calls():
    # A name bound to 4 in one call must not constrain the next call.
    check_array(np.zeros((4, 4)), "a", shape=("N", "N"))
    check_array(np.zeros((5, 5)), "b", shape=("N", "N"))


def test_check_array_accepts_lists_and_returns_an_array():
    arr = check_array([[1.0, 2.0, 3.0]], "x", shape=("N", 3), dtype="float")
    assert isinstance(arr, np.ndarray) and arr.shape == (1, 3)


def test_check_array_ragged_input_is_a_dtype_error():
    with pytest.raises(DTypeError) as info:
        check_array([[1.0, 2.0], [3.0]], "ragged")
    assert "ragged" in str(info.value)


# --------------------------------------------------------------------------------------------------
# check_array: dtype kinds and finiteness
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype,kind,ok", [
    (np.float32, "float", True), (np.float64, "float", True), (np.float16, "float", True),
    (np.int32, "float", False), (np.bool_, "float", False),
    (np.int8, "int", True), (np.int64, "int", True), (np.uint16, "int", True), (np.float32, "int", False),
    (np.uint8, "uint", True), (np.int8, "uint", False),
    (np.bool_, "bool", True), (np.uint8, "bool", False),
    (np.uint8, np.uint8, True), (np.uint16, np.uint8, False), (np.int8, np.uint8, False),
    (np.float32, "float32", True), (np.float64, "float32", False),
    (np.int16, ("float", "int"), True), (np.bool_, ("float", "int"), False),
    (np.uint8, (np.uint16, "bool"), False), (np.uint16, (np.uint16, "bool"), True),
])
def test_dtype_kinds(dtype, kind, ok):
    arr = np.zeros(3, dtype=dtype)
    if ok:  # float16 is converted to float32 where a float is wanted (the dtype policy)
        want = np.float32 if dtype == np.float16 and kind == "float" else dtype
        assert check_array(arr, "x", dtype=kind).dtype == want
    else:
        with pytest.raises(DTypeError) as info:
            check_array(arr, "x_arg", dtype=kind)
        assert "x_arg" in str(info.value) and str(np.dtype(dtype)) in str(info.value)
        assert isinstance(info.value, TypeError)


def test_shape_is_checked_before_dtype():
    with pytest.raises(ShapeError):
        check_array(np.zeros((2, 2), dtype=np.int8), "x", shape=("N", 3), dtype="float")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_finite_flag(bad):
    arr = np.array([1.0, bad, 2.0])
    check_array(arr, "x")  # not requested: accepted
    with pytest.raises(NonFiniteError) as info:
        check_array(arr, "vals", finite=True)
    assert "vals" in str(info.value)


def test_check_finite_counts_bad_values_and_ignores_ints():
    with pytest.raises(NonFiniteError) as info:
        check_finite(np.array([[np.nan, 1.0], [np.inf, 2.0]]), "grid")
    assert "2" in str(info.value) and "grid" in str(info.value)
    check_finite(np.array([1, 2, 3]), "ints")
    check_finite(np.array([1.0, 2.0]), "ok")


# --------------------------------------------------------------------------------------------------
# check_range, check_positive_int, check_method
# --------------------------------------------------------------------------------------------------


def test_check_range_is_closed_and_rejects_nan():
    check_range(np.array([0.0, 0.5, 1.0]), "c", 0.0, 1.0)
    check_range(np.array([]), "empty", 0.0, 1.0)
    for bad in (-TOL.range_edge, 1.0 + TOL.range_edge, np.nan):
        with pytest.raises(RangeError) as info:
            check_range(np.array([0.5, bad]), "conf", 0.0, 1.0)
        assert "conf" in str(info.value)


def test_check_range_message_reports_nan():
    with pytest.raises(RangeError) as info:
        check_range(np.array([0.5, np.nan]), "conf", 0.0, 1.0)
    assert "NaN" in str(info.value)


@pytest.mark.parametrize("value", [1, 7, np.int64(3), np.uint8(2)])
def test_check_positive_int_accepts(value):
    out = check_positive_int(value, "n")
    assert out == int(value) and type(out) is int


@pytest.mark.parametrize("value,error", [
    (0, RangeError), (-1, RangeError), (np.int32(0), RangeError),
    (1.0, DTypeError), (True, DTypeError), ("3", DTypeError), (None, DTypeError),
])
def test_check_positive_int_rejects(value, error):
    with pytest.raises(error) as info:
        check_positive_int(value, "height")
    assert "height" in str(info.value)


def test_check_method_returns_valid_names():
    assert check_method("gardner", ["depth", "gardner"]) == "gardner"


def test_check_method_lists_valid_names_in_message():
    valid = ["Cheung 2004", "Finlayson 2015", "Vandermonde"]
    with pytest.raises(UnknownMethodError) as info:
        check_method("cheung", valid, name="ccm_method")
    msg = str(info.value)
    for name in valid:
        assert name in msg
    assert "cheung" in msg and "ccm_method" in msg
    assert isinstance(info.value, ValueError)


def test_check_method_accepts_any_iterable_once():
    # A generator is consumed once; the message must still list every name.
    with pytest.raises(UnknownMethodError) as info:
        check_method("x", (n for n in ("a", "b")))
    assert "'a'" in str(info.value) and "'b'" in str(info.value)
