"""The result of every light sampler: :class:`LightSet`, and the irradiance its lights give.

A light set stands for an equirect map as ``n`` lights. Light i has a unit ``direction`` (world
frame, from the map's origin) and a ``power``: per channel, the integral of radiance × solid angle
over the part of the map it stands for, so that Σ power ≈ ∫ L dω (exactly, to float rounding, for the
Q2-Tree). A region method also gives each light's ``solid_angle``. With the map's depth, each light
also has a world ``position`` (metres) and the map's ``origin``: it is then a point light there, of
radiant intensity power × |position − origin|² (the intensity that gives irradiance ``power`` at the
origin across the distance), not a light at infinity.

:func:`irradiance` evaluates the lights on normals (directional lights) or, with positions, at world
points (point lights, inverse square law).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from rgbd_envmap.checks import check_array
from rgbd_envmap.errors import InvalidInputError, ShapeError

__all__ = ["LightSet", "irradiance"]


def _frozen(a: np.ndarray | None, dtype) -> np.ndarray | None:
    if a is None:
        return None
    out = np.array(a, dtype=dtype, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True)
class LightSet:
    """Lights standing for an environment map.

    Attributes:
        directions: (n, 3) float64 unit vectors from the map's origin towards each light.
        power: (n, 3) float64 ≥ 0, per linear RGB channel, radiance × solid angle the light stands
            for (irradiance at the origin from a surface facing the light, without the cosine).
        method: the sampler that made the set (``"pharr"``, ``"hemigon"``, ``"q2tree"``, ...).
        solid_angle: (n,) float64 steradians of each light's region (region methods), else None.
        positions: (n, 3) float64 world metres, where the map's depth places each light (NaN for a
            light whose region holds no valid pixel), else None.
        origin: (3,) float64 the map's world origin, given with ``positions``.
        cells: (n, 2) int64 the Q2-Tree quad of each light, (level, nested HEALPix index at
            nside = 2^level), else None.
        points: (n, k, 3) float64 world metres, k points spread over each light's area (virtual
            area lights, ``"val"``), given with ``positions``; else None.
        point_power: (n, k, 3) float64 ≥ 0, the power each of those points stands for (Σ over k
            is ``power``, to rounding), given with ``points``.
    """

    directions: np.ndarray
    power: np.ndarray
    method: str
    solid_angle: np.ndarray | None = None
    positions: np.ndarray | None = None
    origin: np.ndarray | None = None
    cells: np.ndarray | None = None
    points: np.ndarray | None = None
    point_power: np.ndarray | None = None

    def __post_init__(self) -> None:
        d = check_array(self.directions, "directions", shape=("n", 3), dtype="float", finite=True)
        n = d.shape[0]
        p = check_array(self.power, "power", shape=(n, 3), dtype="float", finite=True)
        if n and np.abs(np.linalg.norm(d, axis=1) - 1.0).max() > 1e-9:
            raise InvalidInputError("directions: expected unit vectors (|d| = 1 to 1e-9), got lengths "
                                    f"in [{np.linalg.norm(d, axis=1).min()}, {np.linalg.norm(d, axis=1).max()}]")
        if n and p.min() < 0:
            raise InvalidInputError(f"power: expected values ≥ 0, got {p.min()}")
        if not isinstance(self.method, str) or not self.method:
            raise InvalidInputError(f"method: expected a non-empty name, got {self.method!r}")
        object.__setattr__(self, "directions", _frozen(d, np.float64))
        object.__setattr__(self, "power", _frozen(p, np.float64))
        if self.solid_angle is not None:
            s = check_array(self.solid_angle, "solid_angle", shape=(n,), dtype="float", finite=True)
            if n and s.min() <= 0:
                raise InvalidInputError(f"solid_angle: expected values > 0, got {s.min()}")
            object.__setattr__(self, "solid_angle", _frozen(s, np.float64))
        if (self.positions is None) != (self.origin is None):
            raise InvalidInputError("positions, origin: expected both or neither, got only "
                                    + ("positions" if self.origin is None else "origin"))
        if self.positions is not None:
            q = check_array(self.positions, "positions", shape=(n, 3), dtype="float")
            if np.isinf(q).any():
                raise InvalidInputError("positions: expected finite values or NaN rows, got infinity")
            o = check_array(self.origin, "origin", shape=(3,), dtype=("float", "int"), finite=True)
            object.__setattr__(self, "positions", _frozen(q, np.float64))
            object.__setattr__(self, "origin", _frozen(o, np.float64))
        if self.cells is not None:
            c = check_array(self.cells, "cells", shape=(n, 2), dtype="int")
            if n and (c[:, 0].min() < 0 or (c[:, 1] < 0).any() or (c[:, 1] >= 12 * 4 ** c[:, 0].astype(np.int64)).any()):
                raise InvalidInputError("cells: expected (level ≥ 0, 0 ≤ index < 12·4^level) rows")
            object.__setattr__(self, "cells", _frozen(c, np.int64))
        if (self.points is None) != (self.point_power is None):
            raise InvalidInputError("points, point_power: expected both or neither, got only "
                                    + ("points" if self.point_power is None else "point_power"))
        if self.points is not None:
            if self.positions is None:
                raise InvalidInputError("points: given without positions; a light's area points need its position")
            q = check_array(self.points, "points", shape=(n, "k", 3), dtype="float", finite=True)
            pp = check_array(self.point_power, "point_power", shape=q.shape, dtype="float", finite=True)
            if q.shape[1] < 1:
                raise InvalidInputError("points: expected at least one point per light, got 0")
            if pp.size and pp.min() < 0:
                raise InvalidInputError(f"point_power: expected values ≥ 0, got {pp.min()}")
            object.__setattr__(self, "points", _frozen(q, np.float64))
            object.__setattr__(self, "point_power", _frozen(pp, np.float64))

    def __len__(self) -> int:
        return int(self.directions.shape[0])

    @cached_property
    def point_lights(self) -> LightSet:
        """The lights as point lights, one per area point (``points``) with that point's power, the
        points of no power left out (the set itself when it has no points). A shadow ray to each
        point gives an area light's penumbra. Made once per set (the set is frozen)."""
        if self.points is None:
            return self
        q = self.points.reshape(-1, 3)
        pp = self.point_power.reshape(-1, 3)
        keep = pp.max(axis=1) > 0
        q, pp = q[keep], pp[keep]
        own = np.repeat(self.directions, self.points.shape[1], axis=0)[keep]
        v = q - self.origin
        nv = np.linalg.norm(v, axis=1, keepdims=True)
        d = np.where(nv > 1e-9, v / np.maximum(nv, 1e-300), own)  # a point at the origin: its light's direction
        return LightSet(d, pp, self.method, positions=q, origin=self.origin)

    @property
    def total_power(self) -> np.ndarray:
        """(3,) float64 Σ power: the map's integral ∫ L dω the lights stand for."""
        return self.power.sum(axis=0)

    @property
    def intensity(self) -> np.ndarray | None:
        """(n, 3) float64 radiant intensity of each light as a point light (power × distance² from
        the origin; W/sr for radiance in W/(sr·m²)), or None without positions."""
        if self.positions is None:
            return None
        r2 = np.sum((self.positions - self.origin) ** 2, axis=1)
        return self.power * r2[:, None]


def irradiance(lights: LightSet, normals: np.ndarray, points: np.ndarray | None = None) -> np.ndarray:
    """Irradiance (..., 3) float64 the lights give on surfaces with unit ``normals`` (..., 3).

    Without ``points``: directional lights, E(n) = Σ_i power_i max(0, n · d_i) — what the map gives
    at its origin, the clamped-cosine convolution of the map sampled by the lights.
    With ``points`` (..., 3) world metres: point lights at ``lights.positions`` (needed), E(x, n) =
    Σ_i I_i max(0, n · ℓ) / |p_i − x|² with ℓ the unit vector from x to p_i and I_i the intensity
    (:attr:`LightSet.intensity`); lights without a position (NaN) give nothing. At x = origin this
    equals the directional sum.
    """
    if not isinstance(lights, LightSet):
        raise InvalidInputError(f"lights: expected a LightSet, got {type(lights).__name__}")
    nrm = check_array(normals, "normals", shape=("*", 3), dtype=("float", "int"), finite=True).astype(np.float64)
    flat = nrm.reshape(-1, 3)
    if points is None:
        cos = np.maximum(flat @ lights.directions.T, 0.0)
        return (cos @ lights.power).reshape(nrm.shape)
    if lights.positions is None:
        raise InvalidInputError("points: given, but the lights have no positions (sample with depth_m)")
    pts = check_array(points, "points", dtype=("float", "int"), finite=True).astype(np.float64)
    if pts.shape != nrm.shape:
        raise ShapeError(f"points: expected the shape of normals {nrm.shape}, got {pts.shape}")
    ok = np.isfinite(lights.positions).all(axis=1)
    pos, inten = lights.positions[ok], lights.intensity[ok]
    out = np.zeros((flat.shape[0], 3))
    for s in range(0, flat.shape[0], 1024):  # bounded memory: 1024 points × n lights at a time
        x = pts.reshape(-1, 3)[s:s + 1024]
        delta = pos[None, :, :] - x[:, None, :]
        r2 = np.sum(delta ** 2, axis=2)
        with np.errstate(divide="ignore", invalid="ignore"):
            cos = np.maximum(np.einsum("pk,plk->pl", flat[s:s + 1024], delta) / np.sqrt(r2), 0.0)
            w = np.where(r2 > 0, cos / r2, 0.0)
        out[s:s + 1024] = w @ inten
    return out.reshape(nrm.shape)
