"""The pipeline's configuration tree: :class:`PipelineConfig` and its sections.

Each stage's own settings live beside the stage (:class:`~rgbd_envmap.ingest.tango.TangoIngestConfig`,
:class:`~rgbd_envmap.ingest.kinect.KinectMergeConfig`, :class:`~rgbd_envmap.pipeline.capture.CaptureConfig`
with its :class:`~rgbd_envmap.envmap.map_update.UpdateConfig`); this module nests them. Every config is a
frozen dataclass that checks its values at construction; :mod:`rgbd_envmap.config` reads and writes
the tree as YAML and applies ``section.key=value`` overrides.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from rgbd_envmap.assets import OBJECT_NAMES
from rgbd_envmap.checks import check_flag, check_instance, check_method, check_number, check_positive_int
from rgbd_envmap.envmap.translation import TRANSLATE_METHODS
from rgbd_envmap.envmap_io import CONVENTIONS
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.ingest.kinect import KinectMergeConfig
from rgbd_envmap.ingest.tango import TangoIngestConfig
from rgbd_envmap.pipeline.capture import CaptureConfig
from rgbd_envmap.prt import MAX_PRT_DIRS
from rgbd_envmap.render.raster import BACKENDS
from rgbd_envmap.sh import check_bands

#: the shadow plane's grid, vertices per side (the PRT transfer is computed per vertex).
MAX_PLANE_RESOLUTION = 4096

__all__ = ["ShadingConfig", "ObjectConfig", "RenderConfig", "PoseCheckConfig", "PipelineConfig"]


@dataclass(frozen=True)
class ShadingConfig:
    """SH lighting: ``bands`` (5 = 25 coefficients per channel, the paper's), or the fewest bands whose
    shading of the object stays within ``band_tolerance`` of ``max_bands`` (``auto_bands``).

    ``lighting_file``: an HDR map (``.hdr`` / ``.exr``, equirect; :mod:`rgbd_envmap.envmap_io`) that
    lights the object instead of the captured map; its SH coefficients are projected once, and the
    map is still captured. ``lighting_convention``: the file's orientation ("ours", "blender",
    "mitsuba"; docs/reference/export.md), None for the one the file records, else "ours"."""

    bands: int = 5
    auto_bands: bool = False
    band_tolerance: float = 0.01
    max_bands: int = 8
    lighting_file: str | None = None
    lighting_convention: str | None = None

    def __post_init__(self) -> None:
        check_bands(self.bands, "shading.bands")  # at most sh.MAX_BANDS; the message says why
        check_flag(self.auto_bands, "shading.auto_bands")
        check_number(self.band_tolerance, "shading.band_tolerance", low=0.0)
        check_bands(self.max_bands, "shading.max_bands")
        if self.lighting_convention is not None:
            check_method(self.lighting_convention, CONVENTIONS, "shading.lighting_convention")
        if self.lighting_file is not None and not (isinstance(self.lighting_file, str) and self.lighting_file):
            raise InvalidInputError(f"shading.lighting_file: expected a file name or None, got {self.lighting_file!r}")


@dataclass(frozen=True)
class ObjectConfig:
    """The virtual object and its shadow plane (PRT precomputed once, cached on disk)."""

    name: str = "bunny"
    height_m: float = 0.12
    #: the object's base sits this far below the EM origin (the default scene's table top is 5 cm
    #: under the virtual-object position).
    base_below_origin_m: float = 0.05
    prt_dirs: int = 1024
    #: side of the square shadow plane; None: 4 × the object's larger horizontal extent.
    plane_size_m: float | None = 0.5
    #: the shadow plane's grid vertices per side (2 to :data:`MAX_PLANE_RESOLUTION`).
    plane_resolution: int = 48

    def __post_init__(self) -> None:
        check_method(self.name, OBJECT_NAMES, "object.name")
        check_number(self.height_m, "object.height_m", low=0.0, low_open=True)
        check_number(self.base_below_origin_m, "object.base_below_origin_m")
        check_number(self.prt_dirs, "object.prt_dirs", low=1, high=MAX_PRT_DIRS, integer=True)
        check_number(self.plane_size_m, "object.plane_size_m", low=0.0, low_open=True, high=1e6, optional=True)
        check_number(self.plane_resolution, "object.plane_resolution", low=2, high=MAX_PLANE_RESOLUTION, integer=True)


@dataclass(frozen=True)
class RenderConfig:
    """Compositing: ``enabled=False`` skips the object entirely (capture only)."""

    enabled: bool = True
    #: "numba" (own rasteriser) or "pyrender" (the reference, OpenGL through EGL): docs/design/render.md.
    backend: str = "numba"
    shadow_grey: float = 0.15

    def __post_init__(self) -> None:
        check_flag(self.enabled, "render.enabled")
        check_method(self.backend, BACKENDS, "render.backend")
        check_number(self.shadow_grey, "render.shadow_grey", low=0.0, high=1.0)


@dataclass(frozen=True)
class PoseCheckConfig:
    """Which reported poses a depth packet may not be projected with (ours; the paper trusts the
    tracker). A hand-held device moves continuously: a pose that moved more than ``max_speed_m_s``
    × Δt + ``slack_m`` or turned more than ``max_turn_deg_s`` × Δt + ``slack_deg`` since the previous
    packet's (either stream, through the calibration) is a jump. Depth packets are skipped from the
    jump until ``jump_hold_s`` after it: which side of a jump is right is unknown, and a wrong pose
    that snaps back within the hold never reaches the map (a jump that stays is accepted after it).
    A depth pose bit for bit equal to the previous depth packet's is a frozen tracker
    (``skip_frozen``). The slacks cover tracking noise of about a centimetre and a degree."""

    enabled: bool = True
    max_speed_m_s: float = 2.0
    max_turn_deg_s: float = 720.0
    slack_m: float = 0.03
    slack_deg: float = 3.0
    jump_hold_s: float = 1.0
    skip_frozen: bool = True

    def __post_init__(self) -> None:
        check_flag(self.enabled, "pose_check.enabled")
        check_flag(self.skip_frozen, "pose_check.skip_frozen")
        for name in ("max_speed_m_s", "max_turn_deg_s"):
            check_number(getattr(self, name), f"pose_check.{name}", low=0.0, low_open=True)
        for name in ("slack_m", "slack_deg", "jump_hold_s"):
            check_number(getattr(self, name), f"pose_check.{name}", low=0.0)


@dataclass(frozen=True)
class PipelineConfig:
    """Every setting of the pipeline (loadable from YAML: :mod:`rgbd_envmap.config`). Defaults are the
    paper's where it gives one; docs/guide.md lists which are ours."""

    ingest: TangoIngestConfig = field(default_factory=TangoIngestConfig)
    #: the Kinect path's warp + merge (sensor "kinect": registered depth + colour images).
    kinect: KinectMergeConfig = field(default_factory=KinectMergeConfig)
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    shading: ShadingConfig = field(default_factory=ShadingConfig)
    object: ObjectConfig = field(default_factory=ObjectConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    #: EM translation when the object moves: "depth" (paper §6.2) or "gardner" (sphere baseline).
    translation_method: str = "depth"
    #: threads of the map update, the colour pairs and the map translation (1 or 2; more are used as
    #: 2). Every result is the same bit for bit on one thread; two are faster on two free cores.
    threads: int = 2
    #: a depth packet pairs with the colour frame nearest in time, if within this lag.
    max_colour_lag_ms: float = 20.0
    #: Kinect path: warp + merge run on every frame (30 Hz); correction, the EM update and SH run on
    #: every n-th merged frame (6: 5 Hz, the Tango's depth rate) ...
    kinect_em_every: int = 6
    #: ... on the merged frame subsampled by this stride (2: 320×240 samples, 307k → 77k per update;
    #: the update's footprint splat scales with the focal length, so coverage holds).
    kinect_em_stride: int = 2
    #: reported poses the pipeline does not trust (jumps, a frozen tracker; ours).
    pose_check: PoseCheckConfig = field(default_factory=PoseCheckConfig)

    def __post_init__(self) -> None:
        sections = (("ingest", TangoIngestConfig), ("kinect", KinectMergeConfig), ("capture", CaptureConfig),
                    ("shading", ShadingConfig), ("object", ObjectConfig), ("render", RenderConfig),
                    ("pose_check", PoseCheckConfig))
        for name, cls in sections:  # a dict or a wrong section fails here, not deep in a stage
            check_instance(getattr(self, name), cls, name)
        check_method(self.translation_method, TRANSLATE_METHODS, "translation_method")
        check_positive_int(self.threads, "PipelineConfig.threads")
        check_number(self.max_colour_lag_ms, "max_colour_lag_ms", low=0.0)
        check_positive_int(self.kinect_em_every, "kinect_em_every")
        check_positive_int(self.kinect_em_stride, "kinect_em_stride")
