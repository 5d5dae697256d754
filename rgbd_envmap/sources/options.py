"""How a recording is opened: :class:`SourceOptions` and the camera presets :func:`resolve_intrinsics` names.

Every layout :func:`rgbd_envmap.sources.frames.open_source` reads takes the same options object; each
layout says which of its fields apply (:attr:`rgbd_envmap.sources.frames.SourceLayout.takes`), and a
field given to a layout it does not apply to is refused rather than ignored. The ``rgbd-envmap
replay`` options map one to one onto the fields (:data:`OPTION_FLAGS`), so that an error can name the
flag the user typed.

Intrinsics presets (:data:`INTRINSICS_PRESETS`): the TUM RGB-D benchmark's freiburg1/2/3 calibrations
and its ROS default (:data:`rgbd_envmap.tum.TUM_INTRINSICS`), ICL-NUIM's signed camera
(:data:`rgbd_envmap.icl.ICL_NUIM_INTRINSICS`) and ``primesense``, Open3D's ``PrimeSenseDefault``
(640×480, fx = fy = 525, cx = 319.5, cy = 239.5: the default of the Redwood data). A JSON file holds
either our :meth:`~rgbd_envmap.types.Intrinsics.to_dict` (``width``, ``height``, ``fx``, ``fy``, ``cx``,
``cy``, optionally ``distortion``) or Open3D's ``PinholeCameraIntrinsic`` JSON (``width``, ``height``,
``intrinsic_matrix``: the 3×3 matrix's nine entries in column-major order), as
``open3d.io.write_pinhole_camera_intrinsic`` writes it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from rgbd_envmap.checks import check_flag, check_number
from rgbd_envmap.errors import InvalidInputError, LogFormatError, RgbdEnvmapError
from rgbd_envmap.types import Intrinsics

__all__ = ["SourceOptions", "INTRINSICS_PRESETS", "PRIMESENSE_INTRINSICS", "OPTION_FLAGS", "resolve_intrinsics",
           "read_intrinsics_json"]

#: Open3D's ``PinholeCameraIntrinsicParameters.PrimeSenseDefault``, the Redwood data's camera.
PRIMESENSE_INTRINSICS = Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
#: the preset names :func:`resolve_intrinsics` takes besides a JSON file.
INTRINSICS_PRESETS = ("fr1", "fr2", "fr3", "default", "icl-nuim", "primesense")
#: the ``rgbd-envmap replay`` flag of each :class:`SourceOptions` field a layout may refuse.
OPTION_FLAGS = {"intrinsics": "--intrinsics", "depth_scale": "--depth-scale", "poses": "--poses",
                "depth_correction": "--tum-depth-correction"}


def _presets() -> dict[str, Intrinsics]:
    from rgbd_envmap.icl import ICL_NUIM_INTRINSICS
    from rgbd_envmap.tum import TUM_INTRINSICS

    return {**TUM_INTRINSICS, "icl-nuim": ICL_NUIM_INTRINSICS, "primesense": PRIMESENSE_INTRINSICS}


def read_intrinsics_json(path: str | Path) -> Intrinsics:
    """The camera of a JSON file: our ``Intrinsics.to_dict()`` or Open3D's ``PinholeCameraIntrinsic``
    JSON (``intrinsic_matrix`` column-major; no distortion).

    Raises:
        LogFormatError: missing file, invalid JSON (line named), or neither form.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise LogFormatError(f"{path}: {'missing file' if isinstance(exc, FileNotFoundError) else exc}") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise LogFormatError(f"{path}, line {exc.lineno}: invalid JSON ({exc.msg})") from None
    try:
        if not isinstance(d, dict):
            raise TypeError(f"expected a JSON object, got {type(d).__name__}")
        if "intrinsic_matrix" in d:  # Open3D: [fx, 0, 0, 0, fy, 0, cx, cy, 1], column-major
            m = [float(v) for v in d["intrinsic_matrix"]]
            if len(m) != 9:
                raise ValueError(f"intrinsic_matrix: expected 9 numbers, got {len(m)}")
            if m[1] or m[2] or m[5] or m[3] or m[8] != 1.0:
                raise ValueError(f"intrinsic_matrix: expected [fx, 0, 0, 0, fy, 0, cx, cy, 1] (column-major, no skew), got {m}")
            return Intrinsics(int(d["width"]), int(d["height"]), m[0], m[4], m[6], m[7])
        return Intrinsics.from_dict(d)
    except (ValueError, KeyError, TypeError, AttributeError, RgbdEnvmapError) as exc:
        raise LogFormatError(f"{path}: invalid intrinsics ({type(exc).__name__}: {exc}); expected the keys width, height, "
                             "fx, fy, cx, cy and optionally distortion {k1, k2, p1, p2, k3}, or Open3D's width, height, "
                             "intrinsic_matrix") from None


def resolve_intrinsics(value: str | Path | Intrinsics, flag: str = "intrinsics") -> tuple[Intrinsics, tuple[str, str]]:
    """``(Intrinsics, (source, reason))`` for a camera given as a preset name (:data:`INTRINSICS_PRESETS`),
    a JSON file (:func:`read_intrinsics_json`) or an :class:`Intrinsics`. ``flag`` names the option in
    the reason and in errors (``"--intrinsics"`` from the CLI): the reason is ``"FLAG NAME"`` for a
    preset, ``"FLAG FILE"`` for a file, ``"given by the caller"`` for an object.

    Raises:
        InvalidInputError: neither a preset nor an existing file. LogFormatError: a malformed file.
    """
    if isinstance(value, Intrinsics):
        return value, ("given", "given by the caller")
    if not isinstance(value, (str, Path)):
        raise InvalidInputError(f"{flag}: expected an Intrinsics, a preset name or a JSON file, got {type(value).__name__}")
    presets = _presets()
    if isinstance(value, str) and value in presets:
        return presets[value], (value, f"{flag} {value}")
    path = Path(value)
    if not path.is_file():
        raise InvalidInputError(f"{flag}: expected one of {', '.join(INTRINSICS_PRESETS)} or a JSON file of Intrinsics "
                                f"(width, height, fx, fy, cx, cy, distortion; or Open3D's intrinsic_matrix), got "
                                f"{str(value)!r} (no such file)")
    return read_intrinsics_json(path), (str(path), f"{flag} FILE")


@dataclass(frozen=True)
class SourceOptions:
    """How :func:`~rgbd_envmap.sources.frames.open_source` opens a recording; None: the layout's own.

    Attributes:
        intrinsics: the camera of an RGB-D recording: an :class:`Intrinsics`, a preset name or a JSON
            file (:func:`resolve_intrinsics`). TUM RGB-D: overrides ``calibration.json`` and the camera
            the folder's name names; ICL-NUIM: its published camera; Redwood: ``camera_intrinsic.json``
            and the PrimeSense default; RealSense: the bag's own.
        intrinsics_source: ``(name, reason)`` recorded for ``intrinsics`` (None: from
            :func:`resolve_intrinsics` with the keyword's name).
        depth_scale: depth PNG units per metre (> 0; TUM RGB-D and ICL-NUIM: 5000, Redwood: 1000,
            RealSense: the bag's).
        poses: a trajectory file (TUM format, by time, or ``.log``, by frame number:
            :func:`rgbd_envmap.tum.open_trajectory`) instead of the recording's own, or for one that has
            none (a RealSense bag, a Redwood folder without its ``*-traj.txt``).
        depth_correction: TUM RGB-D only: None (off), ``"auto"`` (the factor of the freiburg camera in
            use) or ``"fr1"`` / ``"fr2"`` / ``"fr3"``.
        strict: stop at the first unreadable frame or packet instead of skipping and counting it.
        depth_rate_hz: phone captures: depth packets per second taken (> 0), or None for every image.
        colour_size: phone captures: (width, height) to decode the video at, or None for its own size.
    """

    intrinsics: Intrinsics | str | Path | None = None
    intrinsics_source: tuple[str, str] | None = None
    depth_scale: float | None = None
    poses: Path | None = None
    depth_correction: str | None = None
    strict: bool = False
    depth_rate_hz: float | None = 5.0
    colour_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.intrinsics is not None and not isinstance(self.intrinsics, (Intrinsics, str, Path)):
            raise InvalidInputError(f"intrinsics: expected an Intrinsics, a preset name or a JSON file, got "
                                    f"{type(self.intrinsics).__name__}")
        if self.depth_scale is not None:
            object.__setattr__(self, "depth_scale", check_number(self.depth_scale, "depth_scale", low=0.0, low_open=True))
        if self.poses is not None:
            if not isinstance(self.poses, (str, Path)):
                raise InvalidInputError(f"poses: expected a trajectory file path, got {type(self.poses).__name__}")
            object.__setattr__(self, "poses", Path(self.poses))
        if self.depth_correction not in (None, "auto", "fr1", "fr2", "fr3"):
            raise InvalidInputError(f"depth_correction: expected None, 'auto', 'fr1', 'fr2' or 'fr3', got {self.depth_correction!r}")
        object.__setattr__(self, "strict", check_flag(self.strict, "strict"))
        if self.depth_rate_hz is not None:
            object.__setattr__(self, "depth_rate_hz", check_number(self.depth_rate_hz, "depth_rate_hz", low=0.0, low_open=True))

    def given(self) -> tuple[str, ...]:
        """The names of the fields of :data:`OPTION_FLAGS` that are set (not None)."""
        return tuple(name for name in OPTION_FLAGS if getattr(self, name) is not None)

    def camera(self) -> tuple[Intrinsics, tuple[str, str]] | None:
        """``(Intrinsics, (source, reason))`` of :attr:`intrinsics`, or None when not given."""
        if self.intrinsics is None:
            return None
        intr, source = resolve_intrinsics(self.intrinsics)
        return intr, (self.intrinsics_source or source)
