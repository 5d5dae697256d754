"""The Tango-like device: ToF depth camera + colour camera on one rigid body, and tracking noise."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from rgbd_envmap.types import Calibration, RigidTransform
from sim.colour_camera import ColourCameraConfig
from sim.tof import ToFConfig

__all__ = ["TangoDeviceConfig", "default_T_colour_from_depth"]


def default_T_colour_from_depth() -> RigidTransform:
    """The depth sensor sits 1.2 cm beside the colour camera, rotated by about half a degree."""
    r = Rotation.from_euler("xyz", [0.3, -0.4, 0.2], degrees=True).as_matrix()
    return RigidTransform.from_rt(r, np.array([-0.012, 0.002, 0.001]), "colour", "depth")


@dataclass(frozen=True)
class TangoDeviceConfig:
    """Both sensors, their extrinsics, and the device's tracking noise.

    ``tracking_noise_m`` / ``tracking_noise_deg`` perturb the *reported* poses of each packet (white,
    per packet); the true poses stay exact in the ground truth.
    """

    tof: ToFConfig = field(default_factory=ToFConfig)
    colour: ColourCameraConfig = field(default_factory=ColourCameraConfig)
    T_colour_from_depth: RigidTransform = field(default_factory=default_T_colour_from_depth)
    tracking_noise_m: float = 0.0
    tracking_noise_deg: float = 0.0

    def calibration(self) -> Calibration:
        return Calibration(
            sensor="tango",
            depth=self.tof.intrinsics,
            colour=self.colour.intrinsics,
            T_colour_from_depth=self.T_colour_from_depth,
            depth_rate_hz=self.tof.rate_hz,
            colour_rate_hz=self.colour.rate_hz,
        )

    def reported(self, T_true: RigidTransform, rng: np.random.Generator) -> RigidTransform:
        """The pose the device reports for a true pose (tracking noise applied)."""
        if self.tracking_noise_m == 0.0 and self.tracking_noise_deg == 0.0:
            return T_true
        dt = rng.normal(0.0, self.tracking_noise_m, 3)
        drot = Rotation.from_rotvec(rng.normal(0.0, np.radians(self.tracking_noise_deg), 3)).as_matrix()
        return RigidTransform.from_rt(T_true.rotation @ drot, T_true.translation + dt, T_true.dst, T_true.src)
