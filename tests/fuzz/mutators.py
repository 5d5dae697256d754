"""Bad inputs made from good ones, and what a call's outcome must be.

A mutator turns one valid argument into a bad one: a wrong type (``str``, ``none``, another object:
``config`` an unrelated config, ``packet`` a colour packet), a wrong dtype (``f16``, ``c128``,
``int``, ``bool``, ``obj``), a wrong shape (``empty``, ``flat``, ``extra``), NaN / infinity (``nan``,
``inf``, with the bad value in the first element), a wrong scalar (``neg``, ``zero``, ``huge``,
``float`` for an integer, ``bool`` for a number) or a memory layout the kernels do not take as it is
(``ro`` read-only, ``F`` Fortran order, ``strided`` a non-contiguous view).

Expected outcomes besides an error class:

- ``SAME``: the call succeeds and gives exactly the result of the valid call (layouts, float16 where
  the values survive the rounding, an integer array of the same values).
- ``CLOSE``: as ``SAME`` to float rounding (relative 1e-6): a layout that takes another code path
  (a copy, another summation order).
- ``VALID``: the call succeeds with a documented result that holds no NaN or infinity.
- ``NAN_DOC``: the call succeeds and NaN (or infinity) appears in the result as the function's
  docstring says: element-wise functions propagate it into the element (row) it came from, and the
  rows of valid elements stay finite.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from rgbd_envmap.envmap import UpdateConfig
from rgbd_envmap.errors import RgbdEnvmapError
from rgbd_envmap.types import RigidTransform

SAME, CLOSE, VALID, NAN_DOC = "SAME", "CLOSE", "VALID", "NAN_DOC"


def _with_first(a: np.ndarray, value: float) -> np.ndarray:
    b = a.copy()
    b.flat[0] = value
    return b


def _ro(a: np.ndarray) -> np.ndarray:
    b = a.copy()
    b.setflags(write=False)
    return b


def _packet():
    from tests.fuzz.inputs import colour_packet
    return colour_packet()


MUTATORS = {
    # any argument
    "str": lambda v: "x",
    "none": lambda v: None,
    # arrays
    "f16": lambda a: a.astype(np.float16),
    "c128": lambda a: a.astype(np.complex128),
    "int": lambda a: a.astype(np.int64) if a.dtype.kind != "b" else a.astype(np.int64),
    "float": lambda a: a.astype(np.float64),
    "bool": lambda a: a > 0.5 if isinstance(a, np.ndarray) else True,
    "obj": lambda a: a.astype(object),
    "nan": lambda a: _with_first(a, np.nan) if isinstance(a, np.ndarray) else float("nan"),
    "inf": lambda a: _with_first(a, np.inf) if isinstance(a, np.ndarray) else float("inf"),
    "empty": lambda a: a[:0],
    "flat": lambda a: a.ravel(),
    "extra": lambda a: a[None],
    "ro": _ro,
    "F": np.asfortranarray,
    "strided": lambda a: np.stack([a, a], axis=-1)[..., 0],
    # scalars
    "neg": lambda v: -1 if isinstance(v, int) else -1.0,
    "zero": lambda v: 0 if isinstance(v, int) else 0.0,
    "huge": lambda v: 10**12 if isinstance(v, int) else 1e300,
    "half": lambda v: 2.5,
    "yes": lambda v: "yes",
    "one": lambda v: 1,
    "bogus": lambda v: "bogus",
    # objects
    "config": lambda v: UpdateConfig(),
    "packet": lambda v: _packet(),
    "dict": lambda v: {},
    # transforms: the same pose with its frame names swapped (T_depth_from_world for T_world_from_depth)
    "swapped": lambda T: RigidTransform(T.matrix, T.src or "a", T.dst or "b"),
}


def applicable(value: object) -> list[str]:
    """The mutators that make sense for an argument like ``value``."""
    if isinstance(value, np.ndarray):
        out = ["str", "none"]
        kind = value.dtype.kind
        if kind == "f":
            out += ["f16", "c128", "nan", "inf", "int", "bool"]
        elif kind == "b":
            out += ["int", "float"]
        elif kind in "iu":
            out += ["float", "c128"]
        out += ["obj", "empty", "extra"] + (["flat", "F"] if value.ndim > 1 else []) + ["ro", "strided"]
        return out
    if isinstance(value, bool):
        return ["yes", "one", "none"]
    if isinstance(value, int):
        return ["str", "none", "half", "zero", "neg", "huge", "bool"]
    if isinstance(value, float):
        return ["str", "none", "nan", "inf", "neg", "zero", "huge", "bool"]
    if isinstance(value, str):
        return ["none", "one", "bogus"]
    if isinstance(value, (Path,)):
        return ["none", "one"]
    if isinstance(value, (list, tuple, dict)):
        return ["str", "none", "one"]
    if isinstance(value, type):
        return ["str", "none", "config"]
    if isinstance(value, RigidTransform):
        return ["str", "none", "config", "packet"] + (["swapped"] if value.dst or value.src else [])
    return ["str", "none", "config", "packet"]


def non_finite(result: object, depth: int = 0) -> bool:
    """True when ``result`` (arrays, floats, tuples, dicts, dataclasses) holds NaN or infinity."""
    if depth > 4:
        return False
    if isinstance(result, np.ndarray):
        return result.dtype.kind in "fc" and not np.isfinite(result).all()
    if isinstance(result, (float, np.floating)):
        return not np.isfinite(result)
    if isinstance(result, (tuple, list)):
        return any(non_finite(x, depth + 1) for x in result)
    if isinstance(result, dict):
        return any(non_finite(x, depth + 1) for x in result.values())
    if dataclasses.is_dataclass(result) and not isinstance(result, type):
        return any(non_finite(getattr(result, f.name), depth + 1) for f in dataclasses.fields(result))
    return False


def first_array(result: object) -> np.ndarray | None:
    if isinstance(result, np.ndarray):
        return result
    if isinstance(result, tuple) and result and isinstance(result[0], np.ndarray):
        return result[0]
    if dataclasses.is_dataclass(result):
        for f in dataclasses.fields(result):
            v = getattr(result, f.name)
            if isinstance(v, np.ndarray) and v.dtype.kind == "f":
                return v
    return None


def same(a: object, b: object, depth: int = 0) -> bool:
    """Equal results, arrays bit for bit (NaN equal to NaN) and of one dtype."""
    if depth > 4:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype
                and a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if isinstance(a, (tuple, list)):
        return type(a) is type(b) and len(a) == len(b) and all(same(x, y, depth + 1) for x, y in zip(a, b))
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k], depth + 1) for k in a)
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(same(getattr(a, f.name), getattr(b, f.name), depth + 1)
                                          for f in dataclasses.fields(a))
    if isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b):
        return True
    try:
        return bool(a == b)
    except Exception:  # noqa: BLE001 - objects without a usable ==: compare by type only
        return type(a) is type(b)


def close(a: object, b: object) -> bool:
    """:func:`same` for arrays up to a relative 1e-6 (and one dtype), recursively."""
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and np.allclose(a, b, rtol=1e-6, atol=1e-12, equal_nan=True)
    if isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        return len(a) == len(b) and all(close(x, y) for x, y in zip(a, b))
    return same(a, b)


def outcome_of(fn, good, arg: str, mut: str) -> tuple[str, str]:
    """What calling ``fn`` with ``arg`` mutated by ``mut`` does now: (expected, name in message).
    Used to draft table rows, each reviewed by hand; the test never calls it."""
    kw = good()
    kw[arg] = MUTATORS[mut](kw[arg])
    try:
        result = fn(**kw)
    except RgbdEnvmapError as exc:
        head = str(exc).split(":", 1)[0]
        name = arg if arg in str(exc) else head
        return type(exc).__name__, name
    except Exception as exc:  # noqa: BLE001
        return f"RAW_{type(exc).__name__}", ""
    if same(result, fn(**good())):
        return "SAME", ""
    if close(result, fn(**good())):
        return "CLOSE", ""
    return ("NAN_DOC" if non_finite(result) else "VALID"), ""
