"""``rgbd-envmap export``: a run's final map as an HDR file in the orientation another tool expects;
and the ``--envmap FILE`` option of ``simulate`` / ``replay`` (lighting from an HDR file).

``export RUN --convention blender|mitsuba|ours [--out FILE] [--format hdr|exr] [--half]`` reads
``RUN/envmap.npz`` and writes it with :func:`rgbd_envmap.envmap_io.write_envmap`: Radiance RGBE
(``.hdr``, linear, invalid pixels 0) or OpenEXR (``.exr``: R, G, B, ``valid``, ``depth``), turned into
Blender's world orientation, Mitsuba 3's ``envmap`` emitter's, or kept in ours. The mappings, with a
figure: docs/reference/export.md.

``--envmap FILE.hdr|exr [--envmap-convention ...]`` sets ``shading.lighting_file`` (an absolute
path, so the run's ``config.yaml`` replays anywhere on this machine) and ``shading.lighting_convention``:
the pipeline still captures the map (and reports its accuracy), but the object is lit by the file's
map, projected to SH once.

The command line (:mod:`apps.cli`) wires these in with :func:`add_export_parser` / :func:`run_export`
and :func:`add_envmap_args` / :func:`envmap_config`.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from rgbd_envmap.envmap_io import CONVENTIONS, FORMATS, format_of, read_envmap, write_envmap
from rgbd_envmap.errors import InvalidInputError

__all__ = ["add_export_parser", "run_export", "export_envmap", "add_envmap_args", "envmap_config"]

_NPZ_KEYS = ("radiance", "depth_m", "valid", "origin")


def add_export_parser(subparsers, formatter_class=argparse.HelpFormatter) -> argparse.ArgumentParser:
    """Define the ``export`` subcommand on ``subparsers`` (from ``add_subparsers``); returns its parser."""
    p = subparsers.add_parser(
        "export", formatter_class=formatter_class, help="write a run's map as .hdr / .exr in another tool's orientation",
        description="Write the final environment map of RUN (its envmap.npz) as a Radiance RGBE (.hdr, linear; invalid "
        "pixels 0) or OpenEXR (.exr: R, G, B, valid, depth = distance from the origin in metres) file, in the "
        "orientation of Blender's world (Environment Texture, equirectangular), of Mitsuba 3's envmap emitter "
        "(default to_world, +y up; our world mapped by (x, y, z) -> (x, z, -y)), or ours (row 0 = zenith, +x at "
        "column W/2, +y at 3W/4). docs/reference/export.md has the mappings and a figure.",
    )
    p.add_argument("run", type=Path, metavar="RUN", help="a run folder written by simulate or replay, or an envmap.npz file")
    p.add_argument("--convention", choices=CONVENTIONS, required=True,
                   help="orientation of the written map: blender, mitsuba or ours")
    p.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="the file to write (default: RUN/envmap_CONVENTION.FORMAT)")
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="file format (default: from --out's extension, else exr)")
    p.add_argument("--half", action="store_true", help="exr only: R, G, B as half floats instead of float32")
    return p


def _load_npz(run: Path) -> tuple[Path, dict[str, np.ndarray]]:
    path = run / "envmap.npz" if run.is_dir() else run
    if not path.is_file():
        raise InvalidInputError(f"{path}: no such file (expected a run folder holding envmap.npz, or an .npz file)")
    try:
        with np.load(path) as z:
            missing = [k for k in _NPZ_KEYS if k not in z.files]
            if missing:
                raise InvalidInputError(f"{path}: missing arrays {missing} (a run folder's envmap.npz has {list(_NPZ_KEYS)})")
            return path, {k: z[k] for k in _NPZ_KEYS}
    except InvalidInputError:
        raise
    except (OSError, ValueError) as exc:
        raise InvalidInputError(f"{path}: cannot read as .npz: {exc}") from None


def export_envmap(run: Path, convention: str, out: Path | None = None, fmt: str | None = None, *,
                  half: bool = False) -> Path:
    """Write ``run``'s map (a run folder or an envmap.npz) in ``convention``'s orientation; returns the
    file written (default ``RUN/envmap_<convention>.<fmt>``, fmt default "exr")."""
    run = Path(run)
    src, arrays = _load_npz(run)
    if out is not None:
        out_fmt = format_of(out)
        if fmt is not None and fmt != out_fmt:
            raise InvalidInputError(f"--format {fmt} does not match --out {out} (a .{out_fmt} file)")
        fmt = out_fmt
    fmt = fmt or "exr"
    if half and fmt != "exr":
        raise InvalidInputError("--half: only for .exr files (RGBE has its own 8-bit mantissas)")
    if out is None:
        out = src.parent / f"envmap_{convention}.{fmt}"
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    return write_envmap(out, arrays["radiance"], arrays["valid"].astype(bool), arrays["depth_m"],
                        convention=convention, origin=arrays["origin"], half=half)


def run_export(args: argparse.Namespace) -> int:
    """The ``export`` subcommand; returns the exit status (errors raise :class:`RgbdEnvmapError`)."""
    path = export_envmap(args.run, args.convention, args.out, args.format, half=args.half)
    print(f"wrote {path} ({args.convention} orientation)")
    return 0


def add_envmap_args(parser) -> None:
    """``--envmap FILE.hdr|exr`` and ``--envmap-convention`` on a parser or argument group."""
    parser.add_argument("--envmap", type=Path, default=None, metavar="FILE.hdr|exr",
                        help="light the virtual object from this HDR map (equirect) instead of the captured one; "
                        "the map is still captured and its accuracy reported (sets shading.lighting_file)")
    parser.add_argument("--envmap-convention", choices=CONVENTIONS, default=None,
                        help="orientation of the --envmap file: ours, blender or mitsuba (default: the one the file "
                        "records, for files written by rgbd-envmap, else ours; docs/reference/export.md)")


def envmap_config(cfg, args: argparse.Namespace):
    """``cfg`` (a :class:`~rgbd_envmap.pipeline.PipelineConfig`) with ``--envmap`` / ``--envmap-convention``
    applied; the file is read once here, so that a bad file fails before the run starts."""
    path = getattr(args, "envmap", None)
    convention = getattr(args, "envmap_convention", None)
    if path is None:
        if convention is not None:
            raise InvalidInputError("--envmap-convention: needs --envmap FILE")
        return cfg
    path = Path(path).expanduser().resolve()
    read_envmap(path, convention)
    return replace(cfg, shading=replace(cfg.shading, lighting_file=str(path), lighting_convention=convention))
