"""Input validation helpers shared by every module.

Each helper raises a subclass of :class:`rgbd_envmap.errors.RgbdEnvmapError` whose message names the
argument, what was expected and what was given. Helpers return the (possibly converted) array so they
can be used inline: ``depth_m = check_array(depth_m, "depth_m", shape=("H", "W"))``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from rgbd_envmap.errors import (
    DTypeError,
    NonFiniteError,
    RangeError,
    ShapeError,
    UnknownMethodError,
)

__all__ = ["check_array", "check_finite", "check_range", "check_method", "check_positive_int", "check_number", "check_flag",
           "check_instance", "check_path", "check_alloc", "MAX_ELEMENTS", "check_finite_where"]

Dim = int | str


def _match_shape(shape: tuple[int, ...], spec: Sequence[Dim]) -> bool:
    """True when ``shape`` matches ``spec``. ``spec`` entries are ints (exact size), names (any size,
    equal names must agree) or ``"*"`` (any number of leading dimensions, only first)."""
    spec = list(spec)
    if spec and spec[0] == "*":
        rest = spec[1:]
        if len(shape) < len(rest):
            return False
        shape = shape[len(shape) - len(rest):]
        spec = rest
    if len(shape) != len(spec):
        return False
    bound: dict[str, int] = {}
    for size, want in zip(shape, spec):
        if isinstance(want, int):
            if size != want:
                return False
        elif want in bound and bound[want] != size:
            return False
        else:
            bound[want] = size
    return True


def check_array(
    value: object,
    name: str,
    *,
    shape: Sequence[Dim] | None = None,
    dtype: Iterable[type | str] | type | str | None = None,
    finite: bool = False,
) -> np.ndarray:
    """Return ``value`` as an ndarray after checking shape, dtype kind and finiteness.

    Args:
        value: anything ``np.asarray`` accepts.
        name: the argument's name, for the message.
        shape: a shape spec such as ``("H", "W", 3)`` or ``("*", 3)``.
        dtype: accepted dtype(s); ``"float"``, ``"int"``, ``"bool"`` accept any of that kind. With
            ``"float"`` among them, float16 is returned converted to float32. Strings, objects and
            None are a :class:`DTypeError` (checked before the shape).
        finite: reject NaN and infinity.
    """
    try:
        arr = np.asarray(value)
    except Exception as exc:  # noqa: BLE001 - anything unconvertible is a type error for the caller
        raise DTypeError(f"{name}: expected an array, got {type(value).__name__} ({exc})") from exc
    if dtype is not None and arr.dtype.kind in "OUSVMm":
        # Strings, objects (None, mixed lists), records and dates are never numbers: say so before
        # any shape message.
        got = type(value).__name__ if not isinstance(value, np.ndarray) else f"an array of {arr.dtype}"
        raise DTypeError(f"{name}: expected an array of numbers, got {got}")
    if shape is not None and not _match_shape(arr.shape, shape):
        raise ShapeError(f"{name}: expected shape {tuple(shape)}, got {arr.shape}")
    if dtype is not None:
        wanted = [dtype] if isinstance(dtype, (type, str)) else list(dtype)
        if arr.dtype == np.float16 and "float" in wanted:
            # The dtype policy: float16 is converted to float32 (no kernel computes in half precision);
            # complex is rejected (no argument of the library is complex).
            arr = arr.astype(np.float32)
        kinds = {"float": "f", "int": "iu", "bool": "b", "uint": "u"}
        ok = False
        for want in wanted:
            if isinstance(want, str) and want in kinds:
                ok |= arr.dtype.kind in kinds[want]
            else:
                ok |= arr.dtype == np.dtype(want)
        if not ok:
            raise DTypeError(f"{name}: expected dtype {wanted}, got {arr.dtype}")
    if finite:
        check_finite(arr, name)
    return arr


def check_finite(arr: np.ndarray, name: str) -> np.ndarray:
    """Raise :class:`NonFiniteError` if ``arr`` holds NaN or infinity."""
    arr = np.asarray(arr)
    if arr.dtype.kind in "fc" and not np.isfinite(arr).all():
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise NonFiniteError(f"{name}: expected finite values, got {bad} NaN or inf of {arr.size}")
    return arr


def check_range(arr: np.ndarray, name: str, low: float, high: float) -> np.ndarray:
    """Raise :class:`RangeError` unless every value lies in the closed interval [low, high]."""
    arr = np.asarray(arr)
    if arr.size and not (np.all(arr >= low) and np.all(arr <= high)):
        raise RangeError(
            f"{name}: expected values in [{low}, {high}], got [{np.nanmin(arr)}, {np.nanmax(arr)}]"
            + (" and NaN" if np.isnan(arr).any() else "")
        )
    return arr


def check_positive_int(value: object, name: str) -> int:
    """Return ``value`` as an int, raising :class:`RangeError` unless it is an integer ≥ 1."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise DTypeError(f"{name}: expected a positive integer, got {value!r}")
    if value < 1:
        raise RangeError(f"{name}: expected a positive integer, got {value}")
    return int(value)


def check_method(method: str, valid: Iterable[str], name: str = "method") -> str:
    """Raise :class:`UnknownMethodError` listing the valid names unless ``method`` is one of them."""
    valid = list(valid)
    if method not in valid:
        raise UnknownMethodError(f"{name}: unknown method {method!r}; valid methods are {valid}")
    return method


def check_number(value: object, name: str, *, low: float | None = None, high: float | None = None,
                 low_open: bool = False, high_open: bool = False, integer: bool = False,
                 optional: bool = False) -> float | int | None:
    """Return ``value`` as a float (an int with ``integer``), raising :class:`DTypeError` unless it is
    a real number (not a bool, not a string; None only with ``optional``) and :class:`RangeError`
    unless it is finite and within [low, high] (``low_open`` / ``high_open``: the bound excluded).
    The message names the argument, the expected range and the value given."""
    if value is None and optional:
        return None
    kinds = (int, np.integer) if integer else (int, float, np.integer, np.floating)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, kinds):
        want = "an integer" if integer else "a number"
        raise DTypeError(f"{name}: expected {want}{' or None' if optional else ''}, got {value!r}")
    number = int(value) if integer else float(value)
    finite = integer or math.isfinite(number)
    if finite and (low is None or (number > low if low_open else number >= low)) and \
            (high is None or (number < high if high_open else number <= high)):
        return number  # the common case: no message is formatted
    lo = "" if low is None else f"{'>' if low_open else '≥'} {low}"
    hi = "" if high is None else f"{'<' if high_open else '≤'} {high}"
    expected = " and ".join(x for x in (lo, hi) if x) or "finite"
    if not finite:
        raise RangeError(f"{name}: expected a finite number ({expected}), got {value!r}")
    raise RangeError(f"{name}: expected a number {expected}, got {value!r}")


def check_flag(value: object, name: str) -> bool:
    """Return ``value`` as a bool, raising :class:`DTypeError` unless it is one (a string such as
    ``"false"`` is not)."""
    if not isinstance(value, (bool, np.bool_)):
        raise DTypeError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def check_instance(value: object, cls: type | tuple[type, ...], name: str, *, optional: bool = False) -> object:
    """Return ``value``, raising :class:`DTypeError` unless it is an instance of ``cls`` (None too with
    ``optional``). The message names the argument, the expected class and the type given, so a config
    or packet passed in the wrong place fails at the boundary, not deep inside with an AttributeError."""
    if value is None and optional:
        return None
    if not isinstance(value, cls):
        classes = cls if isinstance(cls, tuple) else (cls,)
        want = " or ".join(c.__name__ for c in classes) + (" or None" if optional else "")
        raise DTypeError(f"{name}: expected {want}, got {type(value).__name__}")
    return value


def check_path(value: object, name: str = "path") -> Path:
    """Return ``value`` as a :class:`pathlib.Path`, raising :class:`DTypeError` unless it is a ``str``
    or an ``os.PathLike`` (an empty string is a :class:`RangeError`)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (str, os.PathLike)):
        raise DTypeError(f"{name}: expected a path (str or os.PathLike), got {type(value).__name__}")
    if isinstance(value, str) and not value:
        raise RangeError(f"{name}: expected a path, got an empty string")
    return Path(value)


#: The largest array any public function allocates from a size argument (elements of any dtype):
#: 2**31 elements, 8 GiB at float32. A size past it is refused before allocating, saying how much
#: memory it would take.
MAX_ELEMENTS = 2**31


def check_alloc(n_elements: int, itemsize: int, name: str, *, limit: int = MAX_ELEMENTS) -> int:
    """Raise :class:`RangeError` when an array of ``n_elements`` elements of ``itemsize`` bytes, sized
    by the argument ``name``, would pass ``limit`` elements; the message gives the memory it would
    take. Returns ``n_elements``."""
    if n_elements > limit:
        raise RangeError(
            f"{name}: expected at most {limit:,} elements, got {n_elements:,}; that "
            f"would take about {n_elements * itemsize / 2**30:.3g} GiB"
        )
    return n_elements


def check_finite_where(values: np.ndarray, mask: np.ndarray, name: str, what: str = "known") -> np.ndarray:
    """Raise :class:`NonFiniteError` when ``values`` ((H, W) or (H, W, C)) holds NaN or infinity at a
    pixel where ``mask`` ((H, W) bool) is True; elsewhere anything is allowed. One float64 sum decides
    the common case (all finite: about 30 µs for a 224×172 float32 image), the mask is read only when
    it is not. Meant for calls made once per map or file, not per depth frame."""
    if values.dtype.kind not in "fc" or np.isfinite(values.sum(dtype=np.float64)):
        return values
    bad = ~np.isfinite(values)
    if bad.ndim == mask.ndim + 1:
        bad = bad.any(axis=-1)
    n = int(np.count_nonzero(bad & mask))
    if n:
        raise NonFiniteError(f"{name}: expected finite values where {what}, got {n} NaN or inf "
                             f"of {int(np.count_nonzero(mask))} {what} pixels")
    return values
