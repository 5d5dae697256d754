"""Session logs: write sensor packets to a directory and read them back bit-for-bit.

A session directory holds::

    session/
      calibration.json       {"format": "rgbd-envmap-session", "version": 1, **Calibration.to_dict()}
      depth.txt              TUM-style index: comment lines start with '#'; "<timestamp_s> depth/<timestamp_ns>.ply"
      depth/<ns>.ply         binary_little_endian PLY 1.0, element vertex N with float x y z confidence (depth sensor frame, metres)
      depth_poses.txt        TUM RGB-D trajectory: "timestamp_s tx ty tz qx qy qz qw" (T_world_from_depth)
      colour.txt             "<timestamp_s> colour/<ns>.png"
      colour/<ns>.png        the NV21 buffer as a single-channel 8-bit PNG of shape (H*3/2, W) (lossless; documented)
      colour_poses.txt       T_world_from_colour, TUM format
      colour_exposure.txt    optional: "<timestamp_s> <exposure_s> <iso> <bracketed 0|1>" for the colour packets that
                             carry exposure metadata (a log without it, or a packet without a line, reads as unknown)
      colour_white_balance.txt  optional: "<timestamp_s> <r> <g> <b>", the white-balance gains of the colour packets
                             that carry them (the same rule)
      groundtruth/           optional: depth_poses.txt, colour_poses.txt (true poses, TUM), depth/<ns>.npz and colour/<ns>.npz (arbitrary named arrays per packet)

Timestamps are integer nanoseconds in memory and ``<seconds>.<9 digits>`` in text, converted by string
splitting, never through a float, so every ``ns >= 0`` below 2**63 survives exactly (the reader also
accepts fewer than 9 decimals, as in the TUM benchmark). Poses are written as translation and unit
quaternion (x, y, z, w; w >= 0) with ``%.17g``; reading rebuilds the rotation from the quaternion, so a
pose matrix comes back to about 1e-15, not bit-for-bit (tests use 1e-12). Frame names of a read pose are
``("world", "depth")`` / ``("world", "colour")``.

Writers append each line (file, then pose, then index entry) as the packet arrives, so a crash leaves a
readable prefix. Readers raise :class:`LogFormatError` naming the file (and line, for text files).

References:
    Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012 (file formats).
    Bourke, "PLY - Polygon File Format", paulbourke.net/dataformats/ply.
"""

from __future__ import annotations

import json
import re
import shutil
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import cv2
import numpy as np

from rgbd_envmap.errors import InvalidInputError, LogFormatError, RgbdEnvmapError, ShapeError
from rgbd_envmap.types import Calibration, ColourPacket, DepthPacket, RigidTransform

__all__ = ["SessionWriter", "SessionLog", "as_logged", "read_timestamped_table", "read_tum_trajectory", "read_log_trajectory",
           "trajectory_format", "format_timestamp", "parse_timestamp", "QUATERNION_NORM_TOL", "LOG_ROTATION_TOL"]

FORMAT, VERSION = "rgbd-envmap-session", 1
KINDS = ("depth", "colour")
_EXT = {"depth": "ply", "colour": "png"}
_SESSION_ENTRIES = ("calibration.json", "groundtruth", *KINDS, *(f"{k}{s}.txt" for k in KINDS for s in ("", "_poses")),
                    "colour_exposure.txt", "colour_white_balance.txt")
_PLY_FIELDS = ("x", "y", "z", "confidence")
_TIMESTAMP_RE = re.compile(r"([0-9]+)(?:\.([0-9]{1,9}))?")
#: Largest accepted | |q| - 1 | of a quaternion read from a pose file (TUM files print 4 decimals).
QUATERNION_NORM_TOL = 1e-3


def format_timestamp(timestamp_ns: int) -> str:
    """Integer nanoseconds ``>= 0`` as seconds with exactly 9 decimals, e.g. 1 -> "0.000000001"."""
    ns = int(timestamp_ns)
    if ns < 0:
        raise InvalidInputError(f"timestamp_ns: expected >= 0, got {ns}")
    return f"{ns // 10**9}.{ns % 10**9:09d}"


def parse_timestamp(text: str) -> int:
    """Inverse of :func:`format_timestamp` (exact); ``ValueError`` unless ``text`` is ``\\d+(.\\d{1,9})?``."""
    m = _TIMESTAMP_RE.fullmatch(text)
    if m is None:
        raise ValueError(f"malformed timestamp {text!r}")
    ns = int(m[1]) * 10**9 + int((m[2] or "").ljust(9, "0"))
    if ns >= 2**63:
        raise ValueError(f"timestamp {text!r} does not fit in int64 nanoseconds")
    return ns


def read_timestamped_table(path: Path, n_fields: int) -> list[tuple[int, int, list[str]]]:
    """(line number, timestamp_ns, other fields) per data line of a whitespace-separated text file whose
    first field is a timestamp in seconds (TUM RGB-D style: ``#`` comments, up to 9 decimals);
    timestamps must strictly increase. Errors name the file and line."""
    rows: list[tuple[int, int, list[str]]] = []
    for lineno, line in enumerate(_read_bytes(path).decode("utf-8", "replace").splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) != n_fields:
            raise LogFormatError(f"{path}, line {lineno}: expected {n_fields} fields, got {len(fields)}: {line.strip()!r}")
        try:
            ns = parse_timestamp(fields[0])
        except ValueError as exc:
            raise LogFormatError(f"{path}, line {lineno}: {exc}") from None
        if rows and ns <= rows[-1][1]:
            raise LogFormatError(f"{path}, line {lineno}: timestamp {fields[0]} does not increase "
                                 f"(previous {format_timestamp(rows[-1][1])}; unsorted or duplicate)")
        rows.append((lineno, ns, fields[1:]))
    return rows


def read_tum_trajectory(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A trajectory in TUM RGB-D format (``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments):
    (N,) int64 timestamps in ns, (N, 3) float64 translations and (N, 4) float64 quaternions xyzw as
    written (their norm within :data:`QUATERNION_NORM_TOL` of 1). Timestamps must increase.

    Raises:
        LogFormatError: naming the file and line of a malformed, non-finite or non-unit pose.
    """
    stamps, values = [], []
    for lineno, ns, fields in read_timestamped_table(path, 8):
        where = f"{path}, line {lineno}"
        try:
            v = np.array([float(f) for f in fields])
        except ValueError:
            raise LogFormatError(f"{where}: pose values must be numbers, got {fields}") from None
        if not np.isfinite(v).all():
            raise LogFormatError(f"{where}: pose holds NaN or inf: {fields}")
        norm = np.linalg.norm(v[3:])
        if abs(norm - 1.0) > QUATERNION_NORM_TOL:
            raise LogFormatError(f"{where}: quaternion norm {norm:.6g} is not 1 (tolerance {QUATERNION_NORM_TOL})")
        stamps.append(ns)
        values.append(v)
    arr = np.array(values, dtype=np.float64).reshape(-1, 7)
    return np.array(stamps, dtype=np.int64), arr[:, :3], arr[:, 3:]


#: largest max |RᵀR − I| of a ``.log`` pose's rotation (files print 6 to 8 decimals); within it the
#: rotation is made orthonormal (nearest rotation, by SVD), beyond it the pose is refused.
LOG_ROTATION_TOL = 1e-3


def _nearest_rotation(r: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(r)
    out = u @ vt
    if np.linalg.det(out) < 0:
        u[:, -1] *= -1
        out = u @ vt
    return out


def read_log_trajectory(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A trajectory in the ``.log`` format of the Redwood / Augmented ICL-NUIM data (the one Open3D's
    ``read_pinhole_camera_trajectory`` reads): per frame a metadata line of three integers
    (``frame frame frame+1`` as written: the first is the frame's index) and then four lines of the
    4×4 matrix ``T_world_from_cam`` (camera to world, OpenCV camera axes), blank lines ignored.

    Returns:
        (N,) int64 frame indices (the first metadata number; unique) and (N, 4, 4) float64 matrices,
        their rotations made orthonormal (:data:`LOG_ROTATION_TOL`) and last rows exactly [0, 0, 0, 1].

    Raises:
        LogFormatError: naming the file and line of a malformed block (metadata not three integers, a
            row not four numbers, NaN, a last row other than [0, 0, 0, 1], a rotation off by more than
            :data:`LOG_ROTATION_TOL`, a repeated frame index, or a truncated last block).
    """
    lines = [(n, line.split()) for n, line in enumerate(_read_bytes(path).decode("utf-8", "replace").splitlines(), start=1)]
    lines = [(n, f) for n, f in lines if f]
    if len(lines) % 5:
        raise LogFormatError(f"{path}, line {lines[-1][0]}: truncated .log trajectory ({len(lines)} non-empty lines; "
                             "expected 5 per frame: a metadata line and four matrix rows)")
    ids, mats, where_id = [], [], {}
    for b in range(0, len(lines), 5):
        lineno, meta = lines[b]
        if len(meta) != 3 or not all(re.fullmatch(r"[+-]?[0-9]+", x) for x in meta):
            raise LogFormatError(f"{path}, line {lineno}: expected a metadata line of three integers "
                                 f"(frame frame frame+1), got {' '.join(meta)!r}")
        m = np.empty((4, 4))
        for r in range(4):
            row_no, row = lines[b + 1 + r]
            if len(row) != 4:
                raise LogFormatError(f"{path}, line {row_no}: expected a matrix row of 4 numbers, got {len(row)}: "
                                     f"{' '.join(row)!r}")
            try:
                m[r] = [float(x) for x in row]
            except ValueError:
                raise LogFormatError(f"{path}, line {row_no}: matrix values must be numbers, got {' '.join(row)!r}") from None
        if not np.isfinite(m).all():
            raise LogFormatError(f"{path}, lines {lines[b + 1][0]}-{lines[b + 4][0]}: the matrix holds NaN or inf")
        if np.abs(m[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-6:
            raise LogFormatError(f"{path}, line {lines[b + 4][0]}: the last matrix row must be 0 0 0 1, got {m[3].tolist()}")
        rot = m[:3, :3]
        err = float(np.abs(rot.T @ rot - np.eye(3)).max())
        if err > LOG_ROTATION_TOL or np.linalg.det(rot) <= 0:
            raise LogFormatError(f"{path}, lines {lines[b + 1][0]}-{lines[b + 3][0]}: not a rotation (max |RᵀR − I| = "
                                 f"{err:.3g}, det = {np.linalg.det(rot):.4g}; tolerance {LOG_ROTATION_TOL})")
        m[:3, :3] = _nearest_rotation(rot)
        m[3] = [0.0, 0.0, 0.0, 1.0]
        frame = int(meta[0])
        if frame in where_id:
            raise LogFormatError(f"{path}, line {lineno}: frame {frame} repeats the block at line {where_id[frame]}")
        where_id[frame] = lineno
        ids.append(frame)
        mats.append(m)
    return np.array(ids, dtype=np.int64), np.array(mats, dtype=np.float64).reshape(-1, 4, 4)


def trajectory_format(path: Path) -> str:
    """``"tum"`` or ``"log"``: the format of a trajectory file, told by its first data line (TUM: eight
    fields, ``timestamp tx ty tz qx qy qz qw``, ``#`` comments; ``.log``: three integers), not by its
    name (Augmented ICL-NUIM names its ``.log`` trajectories ``*-traj.txt``).

    A file without data lines counts as TUM (no poses).

    Raises:
        LogFormatError: the file is missing, or its first data line is neither.
    """
    for lineno, line in enumerate(_read_bytes(path).decode("utf-8", "replace").splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) == 8:
            return "tum"
        if len(fields) == 3:
            return "log"
        raise LogFormatError(f"{path}, line {lineno}: not a trajectory: expected TUM format (timestamp tx ty tz qx qy qz qw) "
                             f"or the .log format (a line 'frame frame frame+1', then four rows of a 4×4 matrix), "
                             f"got {len(fields)} fields")
    return "tum"  # no data line: an empty TUM trajectory (every frame then lacks a pose, and is counted)


def _read_poses(path: Path, kind: str) -> dict[int, RigidTransform]:
    """TUM trajectory file -> {timestamp_ns: T_world_from_<kind>}."""
    stamps, translations, quaternions = read_tum_trajectory(path)
    return {int(ns): RigidTransform.from_quaternion(t, q, "world", kind)
            for ns, t, q in zip(stamps, translations, quaternions)}


def _pose_line(timestamp_ns: int, T: RigidTransform) -> str:
    values = np.concatenate([T.translation, T.quaternion_xyzw()])
    return format_timestamp(timestamp_ns) + " " + " ".join("%.17g" % x for x in values) + "\n"


def _logged_pose(T: RigidTransform) -> RigidTransform:
    """``T`` as :meth:`SessionLog.open` reads it back: translation and quaternion are written with 17
    significant digits (exact for float64), and the rotation is rebuilt from the quaternion."""
    return RigidTransform.from_quaternion(T.translation, T.quaternion_xyzw(), T.dst, T.src)


def as_logged(packet: DepthPacket | ColourPacket) -> DepthPacket | ColourPacket:
    """The packet exactly as a :class:`SessionLog` of it returns it (points, confidence and images are
    stored losslessly; only the pose goes through the quaternion). Feeding a live pipeline with
    these makes a replay of the recorded log reproduce its results bit for bit."""
    if isinstance(packet, DepthPacket):
        return DepthPacket(packet.timestamp_ns, packet.points_m, packet.confidence, _logged_pose(packet.T_world_from_depth))
    return ColourPacket(packet.timestamp_ns, packet.nv21, _logged_pose(packet.T_world_from_colour), *_logged_exposure(packet),
                        packet.white_balance)


def _logged_exposure(packet: ColourPacket) -> tuple[float | None, float | None, bool]:
    """(exposure_s, iso, bracketed) as the log reads them back: ``%.17g`` is exact for float64; a
    packet missing either value is logged without a line, so it reads back as (None, None, False)."""
    if packet.exposure_s is None or packet.iso is None:
        return None, None, False
    return packet.exposure_s, packet.iso, packet.bracketed


def _ply_bytes(points_m: np.ndarray, confidence: np.ndarray) -> bytes:
    body = np.empty(len(points_m), dtype=[(f, "<f4") for f in _PLY_FIELDS])
    body["x"], body["y"], body["z"] = points_m.T
    body["confidence"] = confidence
    header = ("ply\nformat binary_little_endian 1.0\ncomment rgbd-envmap depth packet, depth sensor frame, metres\n"
              f"element vertex {len(body)}\n" + "".join(f"property float {f}\n" for f in _PLY_FIELDS) + "end_header\n")
    return header.encode("ascii") + body.tobytes()


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Our PLY layout (x y z confidence as float32 in any order) -> ((N, 3) float32 m, (N,) float32)."""
    data = _read_bytes(path)
    end = re.search(rb"end_header\r?\n", data)
    if not data.startswith(b"ply") or end is None:
        raise LogFormatError(f"{path}: not a PLY file (no 'ply' magic or no end_header)")
    n, names, elements, fmt = 0, [], 0, None
    for line in data[: end.start()].decode("ascii", "replace").splitlines()[1:]:
        w = line.split() or ["comment"]
        if w[0] in ("comment", "obj_info"):
            continue
        elif w[0] == "format":
            fmt = w[1:]
        elif w[0] == "element" and len(w) == 3 and w[1] == "vertex" and w[2].isdigit():
            n, elements = int(w[2]), elements + 1
        elif w[0] == "property" and len(w) == 3 and w[1] in ("float", "float32") and elements == 1:
            names.append(w[2])
        else:
            raise LogFormatError(f"{path}: unsupported PLY header line {line!r}")
    if fmt != ["binary_little_endian", "1.0"] or elements != 1 or sorted(names) != sorted(_PLY_FIELDS):
        raise LogFormatError(f"{path}: expected binary_little_endian 1.0 with one vertex element of float "
                             f"{' '.join(_PLY_FIELDS)}, got format {fmt}, properties {names}")
    body = data[end.end():]
    if len(body) != n * 16:
        raise LogFormatError(f"{path}: body holds {len(body)} bytes, header says {n} vertices x 16 = {n * 16}"
                             + (" (truncated)" if len(body) < n * 16 else ""))
    arr = np.frombuffer(body, dtype=[(f, "<f4") for f in names])
    points = np.stack([arr["x"], arr["y"], arr["z"]], axis=-1).astype(np.float32).reshape(n, 3)
    return points, arr["confidence"].astype(np.float32)


def _packet(path: Path, cls: type, *args: object) -> DepthPacket | ColourPacket:
    try:
        return cls(*args)
    except RgbdEnvmapError as exc:
        raise LogFormatError(f"{path}: invalid packet ({exc})") from None


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise LogFormatError(f"{path}: {'missing file' if isinstance(exc, FileNotFoundError) else exc}") from None


class SessionWriter:
    """Record packets into a session directory (layout in the module docstring); a context manager.

    Args:
        root: the session directory; created if missing. An existing non-empty directory raises
            :class:`LogFormatError` unless ``overwrite``, which removes only the entries this format owns.
        calibration: written to ``calibration.json``; colour packets must match ``calibration.colour``.
    """

    def __init__(self, root: str | Path, calibration: Calibration, *, overwrite: bool = False) -> None:
        self.root = Path(root)
        if self.root.is_dir() and any(self.root.iterdir()):
            if not overwrite:
                raise LogFormatError(f"{self.root}: session directory exists and is not empty (pass overwrite=True)")
            for name in _SESSION_ENTRIES:
                p = self.root / name
                shutil.rmtree(p) if p.is_dir() else p.unlink(missing_ok=True)
        self.calibration, self._files, self._last_ns = calibration, {}, {}
        for kind in KINDS:
            (self.root / kind).mkdir(parents=True, exist_ok=True)
        meta = {"format": FORMAT, "version": VERSION, **calibration.to_dict()}
        (self.root / "calibration.json").write_text(json.dumps(meta, indent=2))
        for kind in KINDS:
            self._line(f"{kind}.txt", f"# rgbd-envmap {kind} packets\n# timestamp_s filename\n")
            self._line(f"{kind}_poses.txt", f"# T_world_from_{kind}\n# timestamp_s tx ty tz qx qy qz qw\n")

    def _line(self, name: str, text: str) -> None:
        if name not in self._files:  # line-buffered append: every finished line reaches the disk
            (self.root / name).parent.mkdir(parents=True, exist_ok=True)
            self._files[name] = open(self.root / name, "a", buffering=1, newline="\n")
        self._files[name].write(text)

    def write(self, packet: DepthPacket | ColourPacket, *, true_pose: RigidTransform | None = None,
              groundtruth: Mapping[str, np.ndarray] | None = None) -> None:
        """Append one packet, optionally with its true pose and named ground-truth arrays.

        Raises:
            InvalidInputError: timestamp not strictly after the stream's previous one, or writer closed.
            ShapeError: a colour packet whose size differs from ``calibration.colour``.
        """
        if self._files is None:
            raise InvalidInputError(f"{self.root}: SessionWriter is closed")
        kind, ns = packet.kind, packet.timestamp_ns
        stamp = format_timestamp(ns)
        if kind in self._last_ns and ns <= self._last_ns[kind]:
            raise InvalidInputError(f"{kind} timestamp_ns: expected > previous {self._last_ns[kind]}, got {ns}")
        arrays = {k: np.asarray(v) for k, v in (groundtruth or {}).items()}
        if any(a.dtype.kind == "O" for a in arrays.values()):
            raise InvalidInputError("groundtruth: object arrays cannot be stored without pickle")
        rel = f"{kind}/{ns}.{_EXT[kind]}"
        if kind == "depth":
            (self.root / rel).write_bytes(_ply_bytes(packet.points_m, packet.confidence))
            T = packet.T_world_from_depth
        else:
            want = (self.calibration.colour.height * 3 // 2, self.calibration.colour.width)
            if packet.nv21.shape != want:
                raise ShapeError(f"nv21: expected shape {want} from calibration.colour, got {packet.nv21.shape}")
            ok, png = cv2.imencode(".png", packet.nv21)
            if not ok:
                raise InvalidInputError(f"{rel}: PNG encoding failed")
            (self.root / rel).write_bytes(png.tobytes())
            T = packet.T_world_from_colour
            if packet.exposure_s is not None and packet.iso is not None:
                self._line("colour_exposure.txt", f"{stamp} {packet.exposure_s:.17g} {packet.iso:.17g} {int(packet.bracketed)}\n")
            if packet.white_balance is not None:
                self._line("colour_white_balance.txt", stamp + "".join(f" {w:.17g}" for w in packet.white_balance) + "\n")
        if arrays:  # an .npz by hand: np.savez(**arrays) would take keys "file" / "allow_pickle" as arguments
            (self.root / "groundtruth" / kind).mkdir(parents=True, exist_ok=True)
            with zipfile.ZipFile(self.root / "groundtruth" / kind / f"{ns}.npz", "w") as zf:
                for name, a in arrays.items():
                    with zf.open(f"{name}.npy", "w", force_zip64=True) as f:
                        np.lib.format.write_array(f, a, allow_pickle=False)
        if true_pose is not None:
            self._line(f"groundtruth/{kind}_poses.txt", _pose_line(ns, true_pose))
        self._line(f"{kind}_poses.txt", _pose_line(ns, T))
        self._line(f"{kind}.txt", f"{stamp} {rel}\n")
        self._last_ns[kind] = ns

    def close(self) -> None:
        """Close every open file; idempotent."""
        for f in (self._files or {}).values():
            f.close()
        self._files = None

    def __enter__(self) -> "SessionWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SessionLog:
    """A recorded session opened for reading; packet files are read lazily.

    Attributes:
        root: the session directory.
        calibration: the device calibration.
        depth_timestamps_ns, colour_timestamps_ns: (N,) int64, strictly increasing, read-only.
        dropped_points: {depth file relative to root: points dropped as NaN or inf} for the packets
            read so far (:meth:`read_depth`).
        warnings: what :meth:`open` found suspicious but readable (an empty index).
    """

    def __init__(self, root: Path, calibration: Calibration, entries: dict[str, list[tuple[int, str, RigidTransform]]]):
        """Use :meth:`open`. ``entries[kind]``: (timestamp_ns, path relative to root, pose) per packet."""
        self.root, self.calibration, self._entries = root, calibration, entries
        self._exposure: dict[int, tuple[float, float, bool]] = {}  # colour_exposure.txt, when the log has it
        self._white_balance: dict[int, tuple[float, float, float]] = {}  # colour_white_balance.txt, likewise
        self.dropped_points: dict[str, int] = {}
        self.warnings: list[str] = [f"{root / (kind + '.txt')}: empty index (no {kind} packets)"
                                    for kind in KINDS if not entries[kind]]
        self.depth_timestamps_ns, self.colour_timestamps_ns = (
            np.array([e[0] for e in entries[k]], dtype=np.int64) for k in KINDS)
        for ts in (self.depth_timestamps_ns, self.colour_timestamps_ns):
            ts.setflags(write=False)

    @classmethod
    def open(cls, root: str | Path) -> "SessionLog":
        """Validate ``calibration.json`` and read the indices and poses (not the packet files)."""
        root = Path(root)
        path = root / "calibration.json"
        try:
            d = json.loads(_read_bytes(path))
            if d.get("format") != FORMAT or d.get("version") != VERSION:
                raise ValueError(f"expected format {FORMAT!r} version {VERSION}, got {d.get('format')!r} {d.get('version')!r}")
            calibration = Calibration.from_dict(d)
        except json.JSONDecodeError as exc:
            raise LogFormatError(f"{path}, line {exc.lineno}: invalid JSON ({exc.msg})") from None
        except (ValueError, KeyError, TypeError, AttributeError, RgbdEnvmapError) as exc:
            raise LogFormatError(f"{path}: invalid calibration ({type(exc).__name__}: {exc})") from None
        entries = {}
        for kind in KINDS:
            poses, index, entries[kind] = _read_poses(root / f"{kind}_poses.txt", kind), root / f"{kind}.txt", []
            for lineno, ns, (rel,) in read_timestamped_table(index, 2):
                if ns not in poses:
                    raise LogFormatError(f"{index}, line {lineno}: no pose for {format_timestamp(ns)} in {kind}_poses.txt")
                entries[kind].append((ns, rel, poses[ns]))
        log = cls(root, calibration, entries)
        log._exposure = _read_exposure(root / "colour_exposure.txt")
        log._white_balance = _read_white_balance(root / "colour_white_balance.txt")
        return log

    def __len__(self) -> int:
        return sum(len(v) for v in self._entries.values())

    def entries(self) -> Iterator[tuple[str, int, int]]:
        """(kind, index within its stream, timestamp_ns) of every packet in delivery order: timestamp
        order, depth before colour on equal timestamps."""
        n_depth = len(self.depth_timestamps_ns)
        stamps = np.concatenate([self.depth_timestamps_ns, self.colour_timestamps_ns])
        for j in np.argsort(stamps, kind="stable"):
            j = int(j)
            yield ("depth", j, int(stamps[j])) if j < n_depth else ("colour", j - n_depth, int(stamps[j]))

    def __iter__(self) -> Iterator[DepthPacket | ColourPacket]:
        """All packets in delivery order (see :meth:`entries`)."""
        for kind, i, _ in self.entries():
            yield self.read_depth(i) if kind == "depth" else self.read_colour(i)

    def read_depth(self, i: int, *, strict: bool = False) -> DepthPacket:
        """The ``i``-th depth packet (points in metres, depth sensor frame).

        Points with a NaN or infinite coordinate or confidence are dropped, and their count kept in
        :attr:`dropped_points` under the file's path relative to the log. A packet whose every point
        is dropped raises :class:`LogFormatError` (a replay skips and counts it); with ``strict`` any
        non-finite point does, naming the file and the count."""
        ns, rel, T = self._entries["depth"][i]
        path = self.root / rel
        points, confidence = _read_ply(path)
        finite = np.isfinite(points).all(axis=1) & np.isfinite(confidence)
        n_bad = int(len(finite) - np.count_nonzero(finite))
        if n_bad:
            if strict or n_bad == len(finite):
                raise LogFormatError(f"{path}: {n_bad} of {len(finite)} points hold NaN or inf"
                                     + (" (every point)" if n_bad == len(finite) else ""))
            self.dropped_points[str(rel)] = n_bad
            points, confidence = points[finite], confidence[finite]
        return _packet(path, DepthPacket, ns, points, confidence, T)

    def read_colour(self, i: int) -> ColourPacket:
        """The ``i``-th colour packet; its (H*3/2, W) uint8 NV21 buffer must match the calibration."""
        ns, rel, T = self._entries["colour"][i]
        path = self.root / rel
        img = cv2.imdecode(np.frombuffer(_read_bytes(path), np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise LogFormatError(f"{path}: unreadable or truncated PNG")
        want = (self.calibration.colour.height * 3 // 2, self.calibration.colour.width)
        if img.dtype != np.uint8 or img.shape != want:
            raise LogFormatError(f"{path}: expected a {want} uint8 NV21 image, got {img.shape} {img.dtype}")
        return _packet(path, ColourPacket, ns, img, T, *self._exposure.get(ns, (None, None, False)),
                       self._white_balance.get(ns))

    def groundtruth(self, kind: str, timestamp_ns: int) -> dict[str, np.ndarray]:
        """Named ground-truth arrays stored with the ``kind`` packet at ``timestamp_ns``; {} if none."""
        path = self.root / "groundtruth" / _check_kind(kind) / f"{int(timestamp_ns)}.npz"
        if not path.is_file():
            return {}
        try:
            with np.load(path, allow_pickle=False) as npz:
                return {k: npz[k] for k in npz.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise LogFormatError(f"{path}: unreadable NPZ ({exc})") from None

    def true_poses(self, kind: str) -> dict[int, RigidTransform]:
        """{timestamp_ns: true T_world_from_<kind>} from ``groundtruth/<kind>_poses.txt``; {} if none."""
        path = self.root / "groundtruth" / f"{_check_kind(kind)}_poses.txt"
        return _read_poses(path, kind) if path.is_file() else {}


def _read_exposure(path: Path) -> dict[int, tuple[float, float, bool]]:
    """{timestamp_ns: (exposure_s, iso, bracketed)} of ``colour_exposure.txt``; {} when the log has
    none (logs written before exposure metadata)."""
    if not path.is_file():
        return {}
    out = {}
    for lineno, ns, (t, iso, br) in read_timestamped_table(path, 4):
        try:
            out[ns] = (float(t), float(iso), {"0": False, "1": True}[br])
        except (ValueError, KeyError):
            raise LogFormatError(f"{path}, line {lineno}: expected <exposure_s> <iso> <0|1>, got {t!r} {iso!r} {br!r}") from None
    return out


def _read_white_balance(path: Path) -> dict[int, tuple[float, float, float]]:
    """{timestamp_ns: (r, g, b)} of ``colour_white_balance.txt``; {} when the log has none."""
    if not path.is_file():
        return {}
    out = {}
    for lineno, ns, fields in read_timestamped_table(path, 4):
        try:
            out[ns] = tuple(float(f) for f in fields)
        except ValueError:
            raise LogFormatError(f"{path}, line {lineno}: expected <r> <g> <b> gains, got {fields!r}") from None
    return out


def _check_kind(kind: str) -> str:
    if kind not in KINDS:
        raise InvalidInputError(f"kind: expected one of {list(KINDS)}, got {kind!r}")
    return kind
