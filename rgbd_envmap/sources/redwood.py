"""Redwood RGB-D folders (Redwood indoor scans, Augmented ICL-NUIM): read as :class:`~rgbd_envmap.tum.TumSequence`.

The layout is the one Open3D's reconstruction system and its dataset classes (``RedwoodIndoorLivingRoom1``
…, ``SampleRedwoodRGBDImages``) describe::

    folder/
      colors/ | color/ | image/ | rgb/   colour images, 8-bit 3-channel JPEG or PNG, one per frame
      depth/                             16-bit PNG z-depth registered to colour, 1000 units per metre
                                         (millimetres; 0 = no measurement), one per frame
      camera_intrinsic.json              optional: Open3D's PinholeCameraIntrinsic JSON (width, height,
                                         intrinsic_matrix, column-major); without it Open3D's
                                         PrimeSenseDefault (640×480, fx = fy = 525, cx = 319.5, cy = 239.5)
      <name>-traj.txt | trajectory.log   optional: the camera trajectory in the .log format (per frame a
                                         line "frame frame frame+1", then the 4×4 T_world_from_cam)

Frames are the images in name order, colour and depth paired by position (the counts must agree); frame
``i`` is at ``i / 30`` s (the PrimeSense's 30 Hz; the folders hold no timestamps) and takes block ``i``
of the trajectory. The Augmented ICL-NUIM folders also hold ``depth_noisy/`` (the same frames with a
Kinect-like noise model applied); ``depth_folder="depth_noisy"`` reads those.

Poses: the folder's trajectory file if it has exactly one (``*-traj.txt``, else ``trajectory.log``), or
the file given (``trajectory=``: ``.log`` by frame number, or TUM format by the ``i / 30`` s
timestamps). A folder with neither fails, naming ``--poses FILE`` (the CLI) and ``trajectory=``. Camera
axes are OpenCV's (x right, y down, z forward), as Open3D's.

References:
    Choi, Zhou, Koltun (2015). Robust Reconstruction of Indoor Scenes. CVPR (the Augmented ICL-NUIM
    data and the .log trajectory format). Zhou, Park, Koltun (2018). Open3D: A Modern Library for 3D
    Data Processing. arXiv:1801.09847 (the folder layout and the PrimeSense default camera).
"""

from __future__ import annotations

from pathlib import Path

from rgbd_envmap.checks import check_number
from rgbd_envmap.errors import InvalidInputError, LogFormatError
from rgbd_envmap.sources.options import PRIMESENSE_INTRINSICS, read_intrinsics_json
from rgbd_envmap.tum import TumAssociation, TumSequence, open_trajectory
from rgbd_envmap.types import Intrinsics

__all__ = ["REDWOOD_DEPTH_SCALE", "REDWOOD_FPS", "COLOUR_FOLDERS", "is_redwood_folder", "redwood_trajectory",
           "read_redwood_sequence"]

#: depth PNG units per metre (millimetres, Open3D's default depth scale).
REDWOOD_DEPTH_SCALE = 1000.0
#: frames per second assumed for the timestamps (the folders hold none).
REDWOOD_FPS = 30.0
#: the colour folder names Open3D's reconstruction system looks for, in its order (``colors`` first:
#: the Augmented ICL-NUIM name).
COLOUR_FOLDERS = ("colors", "color", "image", "rgb")
_COLOUR_SUFFIXES = (".jpg", ".jpeg", ".png")


def _colour_folder(root: Path) -> Path | None:
    for name in COLOUR_FOLDERS:
        if (root / name).is_dir():
            return root / name
    return None


def is_redwood_folder(path: str | Path) -> bool:
    """True for a folder with ``depth/`` and one of :data:`COLOUR_FOLDERS` (file names only are looked at)."""
    root = Path(path)
    return root.is_dir() and (root / "depth").is_dir() and _colour_folder(root) is not None


def redwood_trajectory(path: str | Path) -> Path | None:
    """The folder's own trajectory: its one ``*-traj.txt``, else ``trajectory.log``, else None.

    Raises:
        LogFormatError: several ``*-traj.txt`` files (give the one to use).
    """
    root = Path(path)
    found = sorted(p for p in root.glob("*-traj.txt") if p.is_file())
    if len(found) > 1:
        raise LogFormatError(f"{root}: {len(found)} trajectory files ({', '.join(p.name for p in found)}); "
                             "name the one to use with --poses FILE (Python: trajectory=FILE)")
    if found:
        return found[0]
    return root / "trajectory.log" if (root / "trajectory.log").is_file() else None


def _images(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes)


def read_redwood_sequence(path: str | Path, *, intrinsics: Intrinsics | None = None, depth_scale: float = REDWOOD_DEPTH_SCALE,
                          trajectory: str | Path | None = None, depth_folder: str = "depth", fps: float = REDWOOD_FPS,
                          max_dt_s: float = 0.02) -> TumSequence:
    """Open a Redwood folder (module docstring).

    Args:
        path: the folder.
        intrinsics: overrides ``camera_intrinsic.json`` and the PrimeSense default.
        depth_scale: depth PNG units per metre (> 0; the data's 1000).
        trajectory: a pose file instead of the folder's own (``.log``: block ``i`` is frame ``i``; TUM
            format: looked up at ``i / fps`` seconds, within ``max_dt_s``).
        depth_folder: ``"depth"`` or, for Augmented ICL-NUIM, ``"depth_noisy"``.
        fps: frames per second, for the timestamps (> 0).
        max_dt_s: for a TUM-format ``trajectory``: largest |time difference| to the nearest pose.

    Returns:
        A :class:`~rgbd_envmap.tum.TumSequence` (``layout = "Redwood"``; errors name the file and
        frame); frames without a pose are skipped and counted (``skipped["no_pose"]``).

    Raises:
        LogFormatError: no poses (naming ``--poses FILE``), no images, colour and depth counts that
            differ, a malformed camera or trajectory file.
        InvalidInputError / RangeError: bad arguments.
    """
    root = Path(path)
    if not root.is_dir():
        raise LogFormatError(f"{root}: not a directory (expected a Redwood folder)")
    depth_scale = check_number(depth_scale, "depth_scale", low=0.0, low_open=True)
    fps = check_number(fps, "fps", low=0.0, low_open=True)
    max_dt_s = check_number(max_dt_s, "max_dt_s", low=0.0)
    if depth_folder not in ("depth", "depth_noisy"):
        raise InvalidInputError(f"depth_folder: expected 'depth' or 'depth_noisy', got {depth_folder!r}")
    colour_dir, depth_dir = _colour_folder(root), root / depth_folder
    if colour_dir is None or not depth_dir.is_dir():
        raise LogFormatError(f"{root}: expected {depth_folder}/ and one of {', '.join(f + '/' for f in COLOUR_FOLDERS)}")
    if intrinsics is None:
        cam = root / "camera_intrinsic.json"
        if cam.is_file():
            intrinsics, source = read_intrinsics_json(cam), ("camera_intrinsic.json", "camera_intrinsic.json in the folder")
        else:
            intrinsics, source = PRIMESENSE_INTRINSICS, ("primesense", "no camera_intrinsic.json: Open3D's PrimeSenseDefault")
    elif isinstance(intrinsics, Intrinsics):
        source = ("given", "given by the caller")
    else:
        raise InvalidInputError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
    trajectory_path = redwood_trajectory(root) if trajectory is None else Path(trajectory)
    if trajectory_path is None:
        raise LogFormatError(f"{root}: no camera poses (no *-traj.txt or trajectory.log in the folder); give a trajectory "
                             "with --poses FILE (the .log format, one 4×4 pose per frame, or TUM format at frame / 30 s; "
                             "Python: trajectory=FILE)")
    colour, depth = _images(colour_dir, _COLOUR_SUFFIXES), _images(depth_dir, (".png",))
    if not depth:
        raise LogFormatError(f"{depth_dir}: no depth PNGs")
    if len(colour) != len(depth):
        raise LogFormatError(f"{root}: {len(colour)} colour images in {colour_dir.name}/ but {len(depth)} depth images in "
                             f"{depth_folder}/ (frames are paired by position: the counts must agree)")
    track = open_trajectory(trajectory_path)
    max_dt_ns = round(max_dt_s * 1e9)
    frames: list[TumAssociation] = []
    skipped = {"no_rgb": 0, "no_pose": 0, "rgb_unused": 0}
    for i, (c_path, d_path) in enumerate(zip(colour, depth)):
        ns = round(i * 1e9 / fps)
        pose = track.pose_at(ns, max_dt_ns, "nearest", index=i)
        if pose is None:
            skipped["no_pose"] += 1
            continue
        frames.append(TumAssociation(ns, d_path, ns, c_path, i + 1, i + 1, pose[0], pose[1]))
    seq = TumSequence(root, intrinsics, None, frames, skipped, max_dt_s, "nearest", intrinsics_source=source,
                      depth_scale=depth_scale, trajectory=trajectory_path, index_names=None)
    seq.layout = "Redwood"
    return seq
