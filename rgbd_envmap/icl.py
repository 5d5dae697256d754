"""ICL-NUIM sequences in their TUM-compatible layout: read as :class:`~rgbd_envmap.tum.TumSequence`.

The ICL-NUIM benchmark (Handa, Whelan, McDonald, Davison 2014) renders its living-room and office
scenes with POV-Ray and publishes each trajectory also in a layout close to TUM RGB-D's::

    sequence/
      associations.txt   "<t_depth> depth/<N>.png <t_rgb> rgb/<N>.png" per frame ("#" comments); a file
                         with the colour columns first ("<t_rgb> rgb/… <t_depth> depth/…", as TUM's
                         associate.py writes when given rgb.txt first) is read too: the columns are
                         told apart by their folders
      <name>.gt.freiburg one trajectory in TUM format: "<t> tx ty tz qx qy qz qw", T_world_from_cam
      rgb/<N>.png        8-bit colour
      depth/<N>.png      16-bit z-depth, 5000 units per metre, 0 = no measurement, registered to colour

Intrinsics: the dataset's published pinhole, :data:`ICL_NUIM_INTRINSICS` (fx = 481.20, fy = −480.00,
cx = 319.5, cy = 239.5, 640×480, no distortion). The negative fy is no mistake: POV-Ray's camera
frame has y up, and the pinhole u = fx·x/z + cx, v = fy·y/z + cy holds with the signs as given in the
frame the trajectory's poses name, so the library takes the signed focal length as it is (see
:class:`rgbd_envmap.types.Intrinsics`) rather than flipping images or poses. The reconstruction is
then in the dataset's own world frame.

Association: the pairs are the file's; each pair takes the pose nearest its depth timestamp (or the
interpolated one) within ``max_dt_s``, exactly as :func:`rgbd_envmap.tum.read_tum_sequence` does; pairs
without a pose are skipped and counted (``skipped["no_pose"]``).

Errors: :class:`~rgbd_envmap.errors.LogFormatError` naming the file and line (a missing or malformed
``associations.txt``, no or several ``*.gt.freiburg`` files, an image path outside the sequence).

References:
    Handa, Whelan, McDonald, Davison (2014). A Benchmark for RGB-D Visual Odometry, 3D Reconstruction
    and SLAM. ICRA (the dataset's intrinsics and its TUM-compatible files).
"""

from __future__ import annotations

from pathlib import Path

from rgbd_envmap.checks import check_method, check_number
from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.logs import parse_timestamp, read_timestamped_table
from rgbd_envmap.tum import TUM_DEPTH_SCALE, TumAssociation, TumSequence, open_trajectory
from rgbd_envmap.types import Intrinsics

__all__ = ["ICL_NUIM_INTRINSICS", "ASSOCIATIONS", "TRAJECTORY_SUFFIX", "is_icl_nuim_sequence", "icl_nuim_trajectory",
           "read_icl_nuim_sequence"]

#: The dataset's published intrinsics (signed: fy < 0, POV-Ray's y-up camera frame).
ICL_NUIM_INTRINSICS = Intrinsics(640, 480, 481.20, -480.00, 319.5, 239.5)
#: The index file and the trajectory file's suffix of the layout.
ASSOCIATIONS = "associations.txt"
TRAJECTORY_SUFFIX = ".gt.freiburg"
_POSE_METHODS = ("nearest", "linear")


def _trajectories(root: Path) -> list[Path]:
    return sorted(p for p in root.glob(f"*{TRAJECTORY_SUFFIX}") if p.is_file())


def is_icl_nuim_sequence(path: str | Path) -> bool:
    """True for a folder in the TUM-compatible ICL-NUIM layout: ``associations.txt``, a
    ``*.gt.freiburg`` trajectory, ``rgb/`` and ``depth/``."""
    root = Path(path)
    return ((root / ASSOCIATIONS).is_file() and (root / "rgb").is_dir() and (root / "depth").is_dir()
            and bool(_trajectories(root)))


def icl_nuim_trajectory(path: str | Path) -> Path:
    """The one ``*.gt.freiburg`` file of a sequence folder.

    Raises:
        LogFormatError: there is none, or there are several (pass ``trajectory=`` to choose).
    """
    root = Path(path)
    found = _trajectories(root)
    if len(found) != 1:
        what = "no" if not found else f"{len(found)} ({', '.join(p.name for p in found)})"
        raise LogFormatError(f"{root}: expected one *{TRAJECTORY_SUFFIX} trajectory file, found {what}"
                             + ("; name the one to use" if found else ""))
    return found[0]


def _image_path(root: Path, rel: str, where: str) -> Path:
    if Path(rel).is_absolute() or ".." in Path(rel).parts:
        raise LogFormatError(f"{where}: image path must be relative to the sequence, got {rel!r}")
    return root / rel


def _read_associations(root: Path) -> list[tuple[int, int, Path, int, Path]]:
    """(line, depth ns, depth path, rgb ns, rgb path) per line of associations.txt, depth-timestamp order."""
    path = root / ASSOCIATIONS
    out = []
    for lineno, first_ns, (first_rel, second_stamp, second_rel) in read_timestamped_table(path, 4):
        where = f"{path}, line {lineno}"
        try:
            second_ns = parse_timestamp(second_stamp)
        except ValueError as exc:
            raise LogFormatError(f"{where}: {exc}") from None
        first, second = _image_path(root, first_rel, where), _image_path(root, second_rel, where)
        rgb_first = Path(first_rel).parts[:1] == ("rgb",) and Path(second_rel).parts[:1] == ("depth",)
        if rgb_first:
            out.append((lineno, second_ns, second, first_ns, first))
        else:
            out.append((lineno, first_ns, first, second_ns, second))
    out.sort(key=lambda r: r[1])
    for a, b in zip(out, out[1:]):
        if a[1] == b[1]:
            raise LogFormatError(f"{path}, line {b[0]}: depth timestamp repeats line {a[0]}'s")
    return out


def read_icl_nuim_sequence(path: str | Path, *, max_dt_s: float = 0.02, poses: str = "nearest",
                           intrinsics: Intrinsics | None = None, depth_scale: float = TUM_DEPTH_SCALE,
                           trajectory: str | Path | None = None) -> TumSequence:
    """Open an ICL-NUIM sequence in its TUM-compatible layout (module docstring).

    Args:
        path: the sequence folder.
        max_dt_s: largest |time difference| in seconds between a depth image and its pose.
        poses: ``"nearest"`` or ``"linear"``, as in :func:`rgbd_envmap.tum.read_tum_sequence`.
        intrinsics: overrides :data:`ICL_NUIM_INTRINSICS`.
        depth_scale: depth PNG units per metre (> 0; the dataset's 5000).
        trajectory: a pose file instead of the folder's ``*.gt.freiburg``: TUM format, or ``.log``
            (block ``i``: the ``i``-th pair of associations.txt in depth-time order, from 0).

    Returns:
        A :class:`~rgbd_envmap.tum.TumSequence` (its frames load like a TUM sequence's; errors name
        ``associations.txt`` and the line).

    Raises:
        LogFormatError: a missing or malformed file (naming file and line).
        InvalidInputError / RangeError / UnknownMethodError: bad arguments.
    """
    root = Path(path)
    if not root.is_dir():
        raise LogFormatError(f"{root}: not a directory (expected an ICL-NUIM sequence)")
    max_dt_s = check_number(max_dt_s, "max_dt_s", low=0.0)
    check_method(poses, _POSE_METHODS, "poses")
    if intrinsics is None:
        intrinsics, source = ICL_NUIM_INTRINSICS, ("icl-nuim", "the ICL-NUIM layout (associations.txt, *.gt.freiburg)")
    elif isinstance(intrinsics, Intrinsics):
        source = ("given", "given by the caller")
    else:
        raise InvalidInputError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
    rows = _read_associations(root)
    trajectory_path = icl_nuim_trajectory(root) if trajectory is None else Path(trajectory)
    track = open_trajectory(trajectory_path)
    max_dt_ns = round(max_dt_s * 1e9)
    frames: list[TumAssociation] = []
    skipped = {"no_rgb": 0, "no_pose": 0, "rgb_unused": 0}
    for index, (lineno, d_ns, d_path, c_ns, c_path) in enumerate(rows):
        pose = track.pose_at(d_ns, max_dt_ns, poses, index=index)
        if pose is None:
            skipped["no_pose"] += 1
            continue
        frames.append(TumAssociation(d_ns, d_path, c_ns, c_path, lineno, lineno, pose[0], pose[1]))
    return TumSequence(root, intrinsics, None, frames, skipped, max_dt_s, poses, intrinsics_source=source,
                       depth_scale=depth_scale, trajectory=trajectory_path, index_names=(ASSOCIATIONS, ASSOCIATIONS))
