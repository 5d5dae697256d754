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
from rgbd_envmap.colour.hdr import HDRConfig
from rgbd_envmap.envmap.translation import TRANSLATE_METHODS
from rgbd_envmap.envmap_io import CONVENTIONS
from rgbd_envmap.errors import InvalidInputError
from rgbd_envmap.ingest.kinect import KinectMergeConfig
from rgbd_envmap.ingest.tango import TangoIngestConfig
from rgbd_envmap.pipeline.capture import CaptureConfig
from rgbd_envmap.prt import MAX_PRT_DIRS
from rgbd_envmap.lights import METHODS as _LIGHT_SAMPLERS
from rgbd_envmap.render.composite import COMPOSITE_MODES
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


#: the light samplers the differential composite can use (those of rgbd_envmap.lights).
LIGHT_METHODS = tuple(_LIGHT_SAMPLERS)
#: how the differential composite shades the object (RenderConfig.object_shading).
OBJECT_SHADING = ("prt", "lights")


@dataclass(frozen=True)
class RenderConfig:
    """Compositing: ``enabled=False`` skips the object entirely (capture only)."""

    enabled: bool = True
    #: "numba" (own rasteriser) or "pyrender" (the reference, OpenGL through EGL): docs/design/render.md.
    backend: str = "numba"
    shadow_grey: float = 0.15
    #: "differential" (lights + SH with shadow rays onto the real geometry from the map's depth, papers
    #: 000 / 001; docs/design/differential.md; the default: lower composite error on the lit office's
    #: reference frames) or "paper003" (PRT-shaded object + shadow plane alpha, paper 003 §7).
    composite: str = "differential"
    #: differential: lights asked of the sampler on the map's direct part (the Q2-Tree gives 12 + 3k ≥ n).
    lights: int = 12
    #: differential: the sampler of the direct part, a method of :func:`rgbd_envmap.lights.sample_lights`
    #: ("val", "q2tree", "pharr" or "hemigon"; the stateful ones keep their state from relight to relight).
    #: "val", virtual area lights on the emitters' surfaces with soft shadows, measured best
    #: (docs/design/differential.md).
    light_method: str = "val"
    #: differential, light_method "val": points per virtual area light, each with its own shadow ray
    #: (the light's penumbra).
    light_points: int = 4
    #: differential: how the object itself is shaded. "prt": PRT of the whole map's SH (paper 003; its
    #: transfer self-shadows softly), the lights only cast its shadows onto the real surfaces; "lights":
    #: the lights with a self-shadow ray per vertex plus PRT of the indirect SH (docs/design/differential.md
    #: compares the two).
    object_shading: str = "prt"
    #: differential: the fraction τ of the map's energy given to the lights (paper 000 §4.2), the rest to SH.
    tau: float = 0.1
    #: differential: the split and the light sampler read every this-many-th map row and column (8 on a
    #: 2000×1000 map: 250×125 pixels, 1.4° each; the lamp still spans a few dozen; the composite's errors
    #: equal 4's to four digits at 40 % of the lights' time: docs/design/differential.md).
    light_grid_stride: int = 8
    #: differential: the lights of the last sampling are kept while the direct part's SH coefficients
    #: differ from theirs by at most this fraction (Frobenius norm): a lamp that stays put is not
    #: resampled, nor its shadow terms recomputed, on every depth frame. 0 resamples on every relight.
    lights_tolerance: float = 0.02
    #: differential: the real geometry: map points within this distance of the object's centre, one per
    #: cube of side ``receiver_spacing_m`` (12 mm: the main session's shadow 5 % closer to the reference
    #: than at 8 mm, the same in a poorly mapped one, the receivers' shading and raster half the work;
    #: 16 mm is 11 % worse: docs/design/differential.md); rebuilt every ``geometry_every`` relights.
    receiver_radius_m: float = 0.4
    receiver_spacing_m: float = 0.012
    geometry_every: int = 10
    #: differential: relights between a rebuild's snapshot of the map and its use. With ``threads`` ≥ 2
    #: the rebuild (mesh and occlusion rays, a few hundred ms) runs on the second core meanwhile, so that
    #: no depth frame stalls for it; with one thread it runs at the snapshot, with the same result. 0:
    #: rebuilt and used in the same relight. Less than ``geometry_every``.
    geometry_lag: int = 2
    #: differential: the largest albedo a real surface may have: the receivers' irradiance without the
    #: object is kept at least π × the map's radiance there / this (light the map missed, taken as
    #: uniform; DifferentialShader.set_receivers). 0 turns the floor off.
    max_albedo: float = 1.0
    #: differential: rays per receiver vertex into the object's bounding cone (its SH occlusion).
    occlusion_samples: int = 32

    def __post_init__(self) -> None:
        check_flag(self.enabled, "render.enabled")
        check_method(self.backend, BACKENDS, "render.backend")
        check_number(self.shadow_grey, "render.shadow_grey", low=0.0, high=1.0)
        check_method(self.composite, COMPOSITE_MODES, "render.composite")
        check_number(self.lights, "render.lights", low=1, high=10_000, integer=True)
        check_method(self.light_method, LIGHT_METHODS, "render.light_method")
        check_number(self.light_points, "render.light_points", low=1, high=256, integer=True)
        check_number(self.max_albedo, "render.max_albedo", low=0.0)
        check_method(self.object_shading, OBJECT_SHADING, "render.object_shading")
        check_number(self.tau, "render.tau", low=0.0, high=1.0)
        check_number(self.light_grid_stride, "render.light_grid_stride", low=1, high=64, integer=True)
        check_number(self.lights_tolerance, "render.lights_tolerance", low=0.0, high=1.0)
        check_number(self.receiver_radius_m, "render.receiver_radius_m", low=0.0, low_open=True, high=10.0)
        check_number(self.receiver_spacing_m, "render.receiver_spacing_m", low=1e-4, high=1.0)
        check_number(self.geometry_every, "render.geometry_every", low=1, high=1_000_000, integer=True)
        check_number(self.geometry_lag, "render.geometry_lag", low=0, high=self.geometry_every - 1, integer=True)
        check_number(self.occlusion_samples, "render.occlusion_samples", low=1, high=4096, integer=True)


@dataclass(frozen=True)
class PoseCheckConfig:
    """Which reported poses a depth packet may not be projected with (ours; the paper trusts the
    tracker). A hand-held device moves continuously: a pose that moved more than ``max_speed_m_s``
    × Δt + ``slack_m`` or turned more than ``max_turn_deg_s`` × Δt + ``slack_deg`` since the previous
    packet's (either stream, through the calibration) is a jump. Depth packets are skipped from the
    jump until ``jump_hold_s`` after it: which side of a jump is right is unknown, and a wrong pose
    that snaps back within the hold never reaches the map (a jump that stays is accepted after it).
    A depth pose bit for bit equal to the previous depth packet's is a frozen tracker
    (``skip_frozen``); with it, a jump straight after a frozen pose is the tracker catching up
    and is taken without a hold or map check (the frozen side is known to be wrong). The slacks
    cover tracking noise of about a centimetre and a degree.

    **The map check** (``map_check``) catches an offset that outlasts the hold. After a jump, each
    depth packet's points (``map_check_points`` of them) are placed twice, by the reported pose and
    with the jump undone (the device's motion before the jump, continued), and compared with the
    map's distance in their directions (:mod:`rgbd_envmap.pipeline.consistency`); a point agrees
    within ``map_tol_m`` + ``map_tol_rel`` × its distance from the origin (with at least
    ``map_min_compared`` points on valid map pixels). Once the undone pose agrees on ``map_margin``
    × the probed points more than the reported one, that packet and every one up to the next jump
    (the snap back) are skipped (``depth_inconsistent_with_map``). When the reported pose agrees
    better by that margin, the jump was real and the check ends; until either happens, packets are
    skipped too (a pose stays suspect until the map vouches for it). ``map_accept_after_s`` after the jump
    the check ends anyway: a relocalisation that lasts is taken as the truth and the map as what
    is wrong (None: never). Without a detected jump nothing is checked, so a fault-free session is
    unchanged. docs/design/faults.md gives the measured figures."""

    enabled: bool = True
    max_speed_m_s: float = 2.0
    max_turn_deg_s: float = 720.0
    slack_m: float = 0.03
    slack_deg: float = 3.0
    jump_hold_s: float = 1.0
    skip_frozen: bool = True
    map_check: bool = True
    map_check_points: int = 2000
    map_tol_m: float = 0.02
    map_tol_rel: float = 0.02
    map_min_compared: int = 200
    map_margin: float = 0.1
    map_accept_after_s: float | None = 10.0

    def __post_init__(self) -> None:
        check_flag(self.enabled, "pose_check.enabled")
        check_flag(self.skip_frozen, "pose_check.skip_frozen")
        check_flag(self.map_check, "pose_check.map_check")
        for name in ("max_speed_m_s", "max_turn_deg_s"):
            check_number(getattr(self, name), f"pose_check.{name}", low=0.0, low_open=True)
        for name in ("slack_m", "slack_deg", "jump_hold_s"):
            check_number(getattr(self, name), f"pose_check.{name}", low=0.0)
        check_number(self.map_check_points, "pose_check.map_check_points", low=1, high=1_000_000, integer=True)
        check_number(self.map_tol_m, "pose_check.map_tol_m", low=0.0, high=10.0)
        check_number(self.map_tol_rel, "pose_check.map_tol_rel", low=0.0, high=1.0)
        check_number(self.map_min_compared, "pose_check.map_min_compared", low=1, high=1_000_000, integer=True)
        check_number(self.map_margin, "pose_check.map_margin", low=0.0, high=1.0)
        check_number(self.map_accept_after_s, "pose_check.map_accept_after_s", low=0.0, optional=True)


@dataclass(frozen=True)
class PipelineConfig:
    """Every setting of the pipeline (loadable from YAML: :mod:`rgbd_envmap.config`). Defaults are the
    paper's where it gives one; docs/guide.md lists which are ours."""

    ingest: TangoIngestConfig = field(default_factory=TangoIngestConfig)
    #: the Kinect path's warp + merge (sensor "kinect": registered depth + colour images).
    kinect: KinectMergeConfig = field(default_factory=KinectMergeConfig)
    capture: CaptureConfig = field(default_factory=CaptureConfig)
    #: HDR capture (ours): frames brought to the reference exposure, clipped colours kept as lower
    #: bounds in the map, bracketed frames fused into the map and not composited (docs/design/hdr.md).
    hdr: HDRConfig = field(default_factory=HDRConfig)
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
    #: ... and when that frame never comes (lost, frozen), with the nearest usable frame on either
    #: side within this lag (50: the neighbours one colour period away, with jitter; ours). The
    #: depth packet's own pose places its points, so the other frame's colours still register.
    #: None: such a depth packet is dropped (``depth_no_colour``).
    colour_fallback_lag_ms: float | None = 50.0
    #: Kinect path: warp + merge run on every frame (30 Hz); correction, the EM update and SH run on
    #: every n-th merged frame (6: 5 Hz, the Tango's depth rate) ...
    kinect_em_every: int = 6
    #: ... on the merged frame subsampled by this stride (2: 320×240 samples, 307k → 77k per update;
    #: the update's footprint splat scales with the focal length, so coverage holds).
    kinect_em_stride: int = 2
    #: reported poses the pipeline does not trust (jumps, a frozen tracker; ours).
    pose_check: PoseCheckConfig = field(default_factory=PoseCheckConfig)

    def __post_init__(self) -> None:
        sections = (("ingest", TangoIngestConfig), ("kinect", KinectMergeConfig), ("capture", CaptureConfig), ("hdr", HDRConfig),
                    ("shading", ShadingConfig), ("object", ObjectConfig), ("render", RenderConfig),
                    ("pose_check", PoseCheckConfig))
        for name, cls in sections:  # a dict or a wrong section fails here, not deep in a stage
            check_instance(getattr(self, name), cls, name)
        check_method(self.translation_method, TRANSLATE_METHODS, "translation_method")
        check_positive_int(self.threads, "PipelineConfig.threads")
        check_number(self.max_colour_lag_ms, "max_colour_lag_ms", low=0.0)
        check_number(self.colour_fallback_lag_ms, "colour_fallback_lag_ms", low=0.0, high=1000.0, optional=True)
        check_positive_int(self.kinect_em_every, "kinect_em_every")
        check_positive_int(self.kinect_em_stride, "kinect_em_stride")
