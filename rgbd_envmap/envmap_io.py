"""HDR environment-map files: Radiance RGBE (``.hdr``) and OpenEXR (``.exr``), and the orientation
conventions of the tools that read them.

Every map inside the library is in **our** equirect orientation (docs/reference/conventions.md: row 0
is the zenith, azimuth φ = 2π(u + 0.5)/W − π from +x towards +y, world z up). Other renderers place
the world's directions elsewhere in the image (docs/reference/export.md, with a figure):

- ``"ours"``: the map as the pipeline holds it; column fraction f = (u + 0.5)/W = φ/2π + 1/2.
- ``"blender"``: Blender's World with an Environment Texture node (Equirectangular, vector
  unconnected): Cycles maps a direction d to u = (atan2(d.y, d.x) − π)/(−2π) = 1/2 − φ/2π and
  v = 1 − acos(d.z)/π with v = 0 at the image's bottom (``direction_to_equirectangular`` in
  ``intern/cycles/kernel/camera/projection.h``). The rows are ours; the columns are mirrored:
  column c holds our column W − 1 − c (+x in the middle, +y at W/4).
- ``"mitsuba"``: Mitsuba 3's ``envmap`` emitter with its default ``to_world`` (identity) in a
  Mitsuba scene whose +y is up, our world mapped into it by the usual z-up → y-up rotation
  (x, y, z) ↦ (x, z, −y). The emitter maps a local direction d to u = atan2(d.x, −d.z)/2π,
  v = acos(d.y)/π (``direction_to_uv`` in ``src/emitters/envmap.cpp``), so f = 1/4 − φ/2π: Blender's
  image turned a quarter (column c holds Blender's column c + W/4). Mitsuba puts its first and last
  rows *on* the poles (row r at θ = π r/(H − 1)) where ours are pixel centres (θ = π(r + 0.5)/H); the
  rows are kept as they are, so a row sits up to half a row off in Mitsuba (none at the horizon, half
  a row at the poles: 0.09° for a 1000-row map).

The conversions only reorder columns (exact, and undone exactly by :func:`from_convention`) except
Mitsuba's with W not divisible by 4, where the quarter turn is half a column off a pixel: there the
two neighbours are averaged (``valid`` where both are).

Files:

- ``.hdr`` (Radiance RGBE, linear, "-Y H +X W": the first scanline is row 0): three 8-bit mantissas
  and a shared exponent per pixel, written run-length encoded. The encoder truncates, as Radiance's
  ``setcolr`` and the common writers (OpenCV's, Mitsuba's) do; the stored value of a channel x with the pixel's largest
  channel M in [2^(e−1), 2^e) is x̂ = m · 2^(e−8), m = ⌊x · 2^(8−e)⌋ ∈ 0…255, so 0 ≤ x − x̂ < 2^(e−8) ≤
  2^-7 · M for readers that decode m · 2^(e−8) (OpenCV, Mitsuba), and |x − x̂| ≤ 2^(e−9) ≤ 2^-8 · M for
  those that decode (m + 0.5) · 2^(e−8) (Radiance, Blender). RGBE holds neither negative values nor
  validity: negative channels and invalid pixels are written as 0 (black).
- ``.exr`` (OpenEXR, scanline, ZIP): channels ``R``, ``G``, ``B`` (float32, or half with
  ``half=True``: relative error ≤ 2^-11, values above 65504 clamped), ``valid`` (half, 1 or 0) and
  ``depth`` (float32, the distance from the map's origin in metres; 0 where invalid). Invalid pixels
  have radiance 0. The header records ``rgbd_envmap_convention`` and, when given, the map's
  ``rgbd_envmap_origin`` (world metres).

Reading (:func:`read_envmap`) gives the map back in our orientation, from the convention given or, for
files this module wrote, the one they record. ``.hdr`` files are decoded by OpenCV after this module
has checked the header ("-Y H +X W" only; ``EXPOSURE`` is divided out); every pixel of an ``.hdr`` is
valid. ``.exr`` files need ``R``, ``G``, ``B`` (or ``Y``); ``valid`` and ``depth`` are used when there.
Non-finite pixels are invalid.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rgbd_envmap.checks import check_array, check_method, check_path
from rgbd_envmap.errors import InvalidInputError

__all__ = [
    "CONVENTIONS", "FORMATS", "EnvmapFile", "to_convention", "from_convention", "write_hdr", "read_hdr",
    "write_exr", "read_exr", "write_envmap", "read_envmap", "format_of",
]

#: the orientations :func:`to_convention` knows (see the module docstring).
CONVENTIONS = ("ours", "blender", "mitsuba")
#: the file formats, by file name extension.
FORMATS = ("hdr", "exr")

_CONVENTION_KEY = "rgbd_envmap_convention"
_ORIGIN_KEY = "rgbd_envmap_origin"
_HDR_CONVENTION = "RGBD_ENVMAP_CONVENTION"
_HDR_ORIGIN = "RGBD_ENVMAP_ORIGIN"
_HALF_MAX = 65504.0


@dataclass(frozen=True)
class EnvmapFile:
    """A map read from a file, in our orientation.

    Attributes:
        radiance: (H, W, 3) float32 linear radiance; 0 where not ``valid``.
        valid: (H, W) bool.
        depth_m: (H, W) float32 distance from the map's origin in metres (0 where not ``valid``), or
            None when the file has none (``.hdr``, foreign ``.exr``).
        convention: the orientation the file was read in.
        origin: (3,) float64 world position of the map's origin when the file records it, else None.
    """

    radiance: np.ndarray
    valid: np.ndarray
    depth_m: np.ndarray | None
    convention: str
    origin: np.ndarray | None


# ------------------------------------------------------------------------------------ orientation

def _roll_columns(a: np.ndarray, shift2: int, mask: bool) -> np.ndarray:
    """``a`` rolled right by ``shift2 / 2`` columns (out[c] = a[c − shift2/2]); a half-column roll
    averages the two neighbours (masks: both)."""
    if shift2 % 2 == 0:
        return np.roll(a, shift2 // 2, axis=1)
    lo, hi = np.roll(a, (shift2 - 1) // 2, axis=1), np.roll(a, (shift2 + 1) // 2, axis=1)
    if mask:
        return lo & hi
    return ((lo.astype(np.float64) + hi) * 0.5).astype(a.dtype)


def to_convention(image: np.ndarray, convention: str) -> np.ndarray:
    """Our equirect ``image`` in the orientation ``convention`` (one of :data:`CONVENTIONS`).

    Args:
        image: (H, W) or (H, W, C) array in our orientation (float, or bool for a mask).
        convention: "ours" (a copy), "blender" (columns mirrored) or "mitsuba" (mirrored, then turned
            a quarter: column c holds our column 3W/4 − 1 − c, modulo W).

    Returns:
        A new array of the same shape and dtype. Values are only moved, never computed: NaN stays NaN
        at its moved position.
    """
    check_method(convention, CONVENTIONS, "convention")
    a = check_array(image, "image", dtype=("float", "int", "bool"))
    if a.ndim not in (2, 3) or a.shape[0] == 0 or a.shape[1] == 0:
        raise InvalidInputError(f"image: expected a non-empty (H, W) or (H, W, C) array, got shape {a.shape}")
    if convention == "ours":
        return a.copy()
    mirrored = a[:, ::-1]
    if convention == "blender":
        return np.ascontiguousarray(mirrored)
    # Mitsuba's column c sits at Blender's c + W/4: roll left by W/4 (2·shift = −W/2 half-columns).
    return _roll_columns(mirrored, -(a.shape[1] // 2), a.dtype == bool)


def from_convention(image: np.ndarray, convention: str) -> np.ndarray:
    """The inverse of :func:`to_convention`: an ``image`` in ``convention``'s orientation in ours."""
    check_method(convention, CONVENTIONS, "convention")
    a = check_array(image, "image", dtype=("float", "int", "bool"))
    if a.ndim not in (2, 3) or a.shape[0] == 0 or a.shape[1] == 0:
        raise InvalidInputError(f"image: expected a non-empty (H, W) or (H, W, C) array, got shape {a.shape}")
    if convention == "ours":
        return a.copy()
    if convention == "mitsuba":
        a = _roll_columns(a, a.shape[1] // 2, a.dtype == bool)
    return np.ascontiguousarray(a[:, ::-1])


# ------------------------------------------------------------------------------------ Radiance RGBE

def _rgbe(radiance: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 RGBE of finite (H, W, 3) radiance (negative → 0), truncating as Radiance does."""
    rgb = np.maximum(np.asarray(radiance, np.float32), np.float32(0))
    m = rgb.max(axis=2)
    _, e = np.frexp(m)  # m = f · 2^e, f in [0.5, 1)
    # Darker than the writers' threshold (1e-32, e ≥ −105): black; brighter than the biased byte
    # holds (e > 127): the largest value.
    ok = m >= np.float32(1e-32)
    big = e > 127
    e = np.clip(e, -106, 127).astype(np.int32)
    # Exact in float32: a power-of-two scaling of values below 2^e, then the floor.
    mant = np.floor(np.ldexp(rgb, (8 - e)[..., None]))
    out = np.empty((*m.shape, 4), np.uint8)
    out[..., :3] = np.minimum(mant, 255)
    out[big, :3] = 255
    out[..., 3] = e + 128
    out[~ok] = 0
    return out


def _chunks(starts: np.ndarray, lengths: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Segments (starts, lengths) split into chunks of at most ``size``: (chunk starts, lengths)."""
    k = -(-lengths // size)
    cs = np.repeat(starts, k) + size * (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k))
    return cs, np.minimum(size, np.repeat(starts + lengths, k) - cs)


def _rle_scanlines(planes: np.ndarray) -> bytes:
    """Run-length encoded scanlines of (H, 4, W) uint8 RGBE planes (8 ≤ W ≤ 0x7FFF): per scanline
    the marker (2, 2, W >> 8, W & 255), then each of R, G, B, E as packets: runs of ≥ 4 equal bytes
    as (128 + n, byte), n ≤ 127, everything else as literals (n, n bytes), n ≤ 128."""
    H, _, W = planes.shape
    x = planes.reshape(-1)
    n = x.size
    seq = np.zeros(n, bool)  # where each channel of each scanline starts
    seq[::W] = True
    brk = seq.copy()
    brk[1:] |= x[1:] != x[:-1]
    starts = np.flatnonzero(brk)
    lengths = np.diff(np.r_[starts, n])
    long = lengths >= 4
    run_s, run_l = _chunks(starts[long], lengths[long], 127)
    lit = ~np.repeat(long, lengths)
    first = np.flatnonzero(lit & (seq | np.r_[True, ~lit[:-1]]))
    last = np.flatnonzero(lit & np.r_[seq[1:] | ~lit[1:], True])
    lit_s, lit_l = _chunks(first, last + 1 - first, 128)
    s = np.r_[run_s, lit_s]
    ln = np.r_[run_l, lit_l]
    is_run = np.r_[np.ones(run_s.size, bool), np.zeros(lit_s.size, bool)]
    order = np.argsort(s, kind="stable")
    s, ln, is_run = s[order], ln[order], is_run[order]
    size = np.where(is_run, 2, 1 + ln)
    row = s // (4 * W)
    off = np.cumsum(size) - size + 4 * (row + 1)  # each scanline's marker comes before its packets
    out = np.empty(int(size.sum()) + 4 * H, np.uint8)
    row_first = np.searchsorted(row, np.arange(H))
    out[(off[row_first] - 4)[:, None] + np.arange(4)] = (2, 2, W >> 8, W & 0xFF)
    out[off] = np.where(is_run, 128 + ln, ln)
    out[off[is_run] + 1] = x[s[is_run]]
    ls, ll, lo = s[~is_run], ln[~is_run], off[~is_run] + 1
    within = np.arange(ll.sum()) - np.repeat(np.cumsum(ll) - ll, ll)
    out[np.repeat(lo, ll) + within] = x[np.repeat(ls, ll) + within]
    return out.tobytes()


def _map_to_write(radiance: np.ndarray, valid: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The checked (H, W, 3) radiance of a map file to write and the (H, W) pixels it keeps: finite,
    and valid where ``valid`` is given."""
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    H, W = rad.shape[:2]
    if H == 0 or W == 0:
        raise InvalidInputError(f"radiance: expected a non-empty map, got {H}×{W} pixels")
    keep = np.isfinite(rad).all(axis=2)
    if valid is not None:
        keep &= check_array(valid, "valid", shape=(H, W), dtype="bool")
    return rad, keep


def write_hdr(path: str | Path, radiance: np.ndarray, valid: np.ndarray | None = None, *,
              convention: str = "ours", origin: np.ndarray | None = None) -> Path:
    """Write (H, W, 3) linear ``radiance`` as a Radiance RGBE file (run-length encoded).

    Args:
        path: the file to write.
        radiance: (H, W, 3) float linear radiance, in the orientation the file is to have.
        valid: (H, W) bool or None; invalid pixels are written as 0.
        convention: the orientation ``radiance`` is in, recorded in the header
            (``RGBD_ENVMAP_CONVENTION=``); the pixels are written as given.
        origin: (3,) world metres of the map's origin, recorded in the header, or None.

    Returns:
        ``path`` as a Path.
    """
    check_method(convention, CONVENTIONS, "convention")
    rad, keep = _map_to_write(radiance, valid)
    rad = np.asarray(rad, np.float32)
    keep &= np.isfinite(rad).all(axis=2)  # float64 beyond float32's range is inf now
    H, W = rad.shape[:2]
    rgbe = _rgbe(np.where(keep[..., None], rad, np.float32(0)))
    lines = ["#?RADIANCE", "SOFTWARE=rgbd-envmap", f"{_HDR_CONVENTION}={convention}"]
    if origin is not None:
        o = check_array(origin, "origin", shape=(3,), dtype=("float", "int"), finite=True)
        lines.append(f"{_HDR_ORIGIN}=" + " ".join(repr(float(x)) for x in o))
    # FORMAT last: readers derived from Bruce Walter's rgbe.c (OpenCV's) want the blank line next.
    lines += ["FORMAT=32-bit_rle_rgbe", "", f"-Y {H} +X {W}", ""]
    chunks = ["\n".join(lines).encode("ascii")]
    if 8 <= W <= 0x7FFF:
        chunks.append(_rle_scanlines(np.ascontiguousarray(rgbe.transpose(0, 2, 1))))
    else:  # the format allows no run-length encoding at these widths: flat pixels
        chunks.append(rgbe.tobytes())
    path = check_path(path)
    path.write_bytes(b"".join(chunks))
    return path


def _hdr_header(path: Path) -> tuple[dict[str, str], float, int, int]:
    """(header variables, product of EXPOSURE values, H, W) of a Radiance file, checked."""
    try:
        with open(path, "rb") as f:
            head = f.read(65536)
    except OSError as exc:
        raise InvalidInputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not head.startswith(b"#?"):
        raise InvalidInputError(f"{path}: not a Radiance HDR file (it does not start with '#?')")
    end = head.find(b"\n\n")
    if end < 0:
        raise InvalidInputError(f"{path}: Radiance header without its blank line (or longer than 64 KiB)")
    variables: dict[str, str] = {}
    exposure = 1.0
    for raw in head[:end].split(b"\n")[1:]:
        line = raw.decode("latin-1").strip()
        if "=" not in line or line.startswith("#"):
            continue
        key, value = (s.strip() for s in line.split("=", 1))
        variables[key] = value
        if key == "EXPOSURE":
            try:
                exposure *= float(value)
            except ValueError:
                raise InvalidInputError(f"{path}: unreadable header line {line!r}") from None
    fmt = variables.get("FORMAT", "32-bit_rle_rgbe")
    if fmt != "32-bit_rle_rgbe":
        raise InvalidInputError(f"{path}: FORMAT={fmt} is not supported (only 32-bit_rle_rgbe)")
    res_end = head.find(b"\n", end + 2)
    res = head[end + 2:res_end if res_end >= 0 else None].decode("latin-1").strip()
    m = re.fullmatch(r"-Y\s+(\d+)\s+\+X\s+(\d+)", res)
    if m is None:
        raise InvalidInputError(f"{path}: resolution line {res!r} is not supported (only '-Y H +X W': top row "
                                "first, left to right)")
    if not exposure > 0 or not np.isfinite(exposure):
        raise InvalidInputError(f"{path}: EXPOSURE must be a positive number, got {exposure}")
    return variables, exposure, int(m.group(1)), int(m.group(2))


def read_hdr(path: str | Path) -> tuple[np.ndarray, dict[str, str]]:
    """A Radiance RGBE file's pixels and header variables.

    Returns:
        (radiance (H, W, 3) float32 linear, as stored divided by the header's EXPOSURE; header
        variables as strings, e.g. ``FORMAT``, ``RGBD_ENVMAP_CONVENTION``).

    Raises:
        InvalidInputError: unreadable file, a header this reader does not support, or broken pixel data.
    """
    import cv2

    path = check_path(path)
    variables, exposure, H, W = _hdr_header(path)
    img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if img is None or img.shape[:2] != (H, W) or img.ndim != 3 or img.shape[2] != 3:
        raise InvalidInputError(f"{path}: cannot decode the RGBE pixels of a {W}×{H} map")
    rad = np.ascontiguousarray(img[..., ::-1], dtype=np.float32)
    if exposure != 1.0:
        rad = (rad / np.float32(exposure)).astype(np.float32)
    return rad, variables


# ------------------------------------------------------------------------------------ OpenEXR

def write_exr(path: str | Path, radiance: np.ndarray, valid: np.ndarray | None = None,
              depth_m: np.ndarray | None = None, *, half: bool = False, convention: str = "ours",
              origin: np.ndarray | None = None) -> Path:
    """Write an OpenEXR file with channels R, G, B, ``valid`` and (when given) ``depth``.

    Args:
        path: the file to write.
        radiance: (H, W, 3) float linear radiance, in the orientation the file is to have.
        valid: (H, W) bool or None (every finite pixel valid). Invalid pixels get radiance and depth 0.
        depth_m: (H, W) float distance from the map's origin in metres, or None (no ``depth`` channel).
        half: R, G, B as half floats (values clamped to ±65504) instead of float32.
        convention: the orientation ``radiance`` is in, recorded as the ``rgbd_envmap_convention``
            attribute; the pixels are written as given.
        origin: (3,) world metres of the map's origin, recorded as ``rgbd_envmap_origin``, or None.

    Returns:
        ``path`` as a Path.
    """
    import OpenEXR

    check_method(convention, CONVENTIONS, "convention")
    rad, ok = _map_to_write(radiance, valid)
    H, W = rad.shape[:2]
    if depth_m is not None:
        depth = check_array(depth_m, "depth_m", shape=(H, W), dtype=("float", "int"))
        ok &= np.isfinite(depth)
    rgb = np.where(ok[..., None], rad, 0.0)
    if half:
        rgb = np.clip(rgb, -_HALF_MAX, _HALF_MAX)
    dtype = np.float16 if half else np.float32
    channels = {name: np.ascontiguousarray(rgb[..., i], dtype=dtype) for i, name in enumerate("RGB")}
    channels["valid"] = ok.astype(np.float16)
    if depth_m is not None:
        channels["depth"] = np.ascontiguousarray(np.where(ok, depth, 0.0), dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, _CONVENTION_KEY: convention}
    if origin is not None:
        header[_ORIGIN_KEY] = check_array(origin, "origin", shape=(3,), dtype=("float", "int"), finite=True).astype(np.float64)
    path = check_path(path)
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))
    return path


def read_exr(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """An OpenEXR file's channels (each (H, W), as stored) and header attributes.

    Raises:
        InvalidInputError: an unreadable or multi-part file.
    """
    import OpenEXR

    path = check_path(path)
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such file")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            if len(f.parts) != 1:
                raise InvalidInputError(f"{path}: a multi-part OpenEXR file ({len(f.parts)} parts); expected one image")
            header = dict(f.header())
            channels = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except InvalidInputError:
        raise
    except Exception as exc:  # OpenEXR raises plain RuntimeError / ValueError on broken files
        raise InvalidInputError(f"{path}: cannot read as OpenEXR: {exc}") from None
    return channels, header


# ------------------------------------------------------------------------------------ maps

def format_of(path: str | Path) -> str:
    """"hdr" or "exr" from ``path``'s extension (case-insensitive); InvalidInputError otherwise."""
    ext = check_path(path).suffix.lower().lstrip(".")
    if ext not in FORMATS:
        raise InvalidInputError(f"{path}: expected a .hdr or .exr file, got {Path(path).suffix or 'no extension'!r}")
    return ext


def write_envmap(path: str | Path, radiance: np.ndarray, valid: np.ndarray, depth_m: np.ndarray | None = None, *,
                 convention: str = "ours", origin: np.ndarray | None = None, half: bool = False) -> Path:
    """Write a map given in our orientation to ``path`` (``.hdr`` or ``.exr``, by its extension) in
    the orientation ``convention``.

    Args:
        radiance: (H, W, 3) float linear radiance, ours. valid: (H, W) bool.
        depth_m: (H, W) float distance from the origin in metres, or None (``.exr`` only; an
            ``.hdr`` has no room for it).
        convention: one of :data:`CONVENTIONS`.
        origin: (3,) world metres, recorded in the file, or None.
        half: ``.exr`` only: R, G, B as half floats.
    """
    fmt = format_of(path)
    check_method(convention, CONVENTIONS, "convention")
    rad = check_array(radiance, "radiance", shape=("H", "W", 3), dtype=("float", "int"))
    ok = check_array(valid, "valid", shape=rad.shape[:2], dtype="bool")
    rad_c, ok_c = to_convention(rad, convention), to_convention(ok, convention)
    if fmt == "hdr":
        return write_hdr(path, rad_c, ok_c, convention=convention, origin=origin)
    depth_c = None
    if depth_m is not None:
        depth_c = to_convention(check_array(depth_m, "depth_m", shape=rad.shape[:2], dtype=("float", "int")), convention)
    return write_exr(path, rad_c, ok_c, depth_c, half=half, convention=convention, origin=origin)


def _recorded(value: object) -> str | None:
    value = value.decode() if isinstance(value, bytes) else value
    return value if isinstance(value, str) and value in CONVENTIONS else None


def read_envmap(path: str | Path, convention: str | None = None) -> EnvmapFile:
    """Read an ``.hdr`` or ``.exr`` equirect map and turn it into our orientation.

    Args:
        path: the file (its extension says the format).
        convention: the file's orientation, one of :data:`CONVENTIONS`; None: the one the file
            records (files written by :func:`write_envmap`), else "ours".

    Returns:
        :class:`EnvmapFile`.

    Raises:
        InvalidInputError: a missing or unreadable file, an unknown convention, an EXR without colour
            channels, or a map with no finite pixel.
    """
    path = check_path(path)
    fmt = format_of(path)
    if convention is not None:
        check_method(convention, CONVENTIONS, "convention")
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such file")
    depth = None
    origin = None
    if fmt == "hdr":
        rad, variables = read_hdr(path)
        recorded = _recorded(variables.get(_HDR_CONVENTION))
        valid = np.ones(rad.shape[:2], bool)
        if _HDR_ORIGIN in variables:
            try:
                o = np.array([float(x) for x in variables[_HDR_ORIGIN].split()], np.float64)
                origin = o if o.shape == (3,) and np.isfinite(o).all() else None
            except ValueError:
                origin = None
    else:
        channels, header = read_exr(path)
        if all(c in channels for c in "RGB"):
            rad = np.stack([channels[c] for c in "RGB"], axis=-1).astype(np.float32)
        elif "Y" in channels:
            rad = np.repeat(channels["Y"][..., None], 3, axis=-1).astype(np.float32)
        else:
            raise InvalidInputError(f"{path}: no R, G, B (or Y) channels; the file has {sorted(channels)}")
        valid = np.asarray(channels["valid"], np.float32) > 0.5 if "valid" in channels else np.ones(rad.shape[:2], bool)
        if "depth" in channels:
            depth = np.asarray(channels["depth"], np.float32)
        recorded = _recorded(header.get(_CONVENTION_KEY))
        o = header.get(_ORIGIN_KEY)
        if o is not None:
            o = np.asarray(o, np.float64).reshape(-1)
            origin = o if o.shape == (3,) and np.isfinite(o).all() else None
    if rad.shape[0] == 0 or rad.shape[1] == 0:
        raise InvalidInputError(f"{path}: an empty image")
    valid = valid & np.isfinite(rad).all(axis=2)
    if depth is not None:
        valid &= np.isfinite(depth)
        depth = np.where(valid, depth, 0.0).astype(np.float32)
    if not valid.any():
        raise InvalidInputError(f"{path}: no valid (finite) pixel")
    rad = np.where(valid[..., None], rad, 0.0).astype(np.float32)
    conv = convention if convention is not None else (recorded or "ours")
    return EnvmapFile(
        radiance=from_convention(rad, conv), valid=from_convention(valid, conv),
        depth_m=None if depth is None else from_convention(depth, conv), convention=conv, origin=origin,
    )
