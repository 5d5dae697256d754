"""The capture loop: reference frame, colour pairs → matrix → gate → projection."""

import numpy as np
import pytest

from rgbd_envmap.pipeline.capture import CaptureConfig, EnvironmentCapture
from rgbd_envmap.geometry import look_at, pixel_rays
from rgbd_envmap.types import Intrinsics, RGBDFrame, RigidTransform
from sim.raycast import SceneRaycaster
from sim.scene import scene_from_dict
from tests.sim.helpers import box_room

INTR = Intrinsics(96, 72, 70.0, 70.0, 47.5, 35.5)
SMALL = CaptureConfig(height=200, width=400, min_pairs=200)


@pytest.fixture(scope="module")
def colourful_room():
    patches = {"texture": "patches", "cells": [3, 2], "colours": [[0.8, 0.2, 0.1], [0.2, 0.7, 0.2], [0.1, 0.2, 0.8],
                                                                  [0.7, 0.7, 0.2], [0.6, 0.3, 0.6], [0.3, 0.6, 0.7]]}
    extra = [{"name": "chart", "shape": "quad", "corner": [1.99, -1.5, -1.0], "u": [0, 3.0, 0], "v": [0, 0, 2.0], "radiance": patches}]
    return SceneRaycaster(scene_from_dict(box_room(radiance=(0.4, 0.4, 0.4), extra=extra)))


def _frame(rc, T: RigidTransform, gains=(1.0, 1.0, 1.0), ts=0) -> RGBDFrame:
    rays = pixel_rays(INTR).reshape(-1, 3)
    dirs = T.rotate(rays / np.linalg.norm(rays, axis=1, keepdims=True))
    hits = rc.cast(T.translation, dirs, 0.0)
    z = (hits.distance_m / np.linalg.norm(rays, axis=1)).reshape(INTR.shape)
    rgb = np.clip(hits.radiance * np.asarray(gains, np.float32), 0, 1).reshape(*INTR.shape, 3)
    return RGBDFrame(rgb, z, hits.hit.reshape(INTR.shape), T, INTR, ts)


def _step(cap, frame):
    return cap.process(frame, frame.known, frame)


def test_first_frame_is_the_reference_and_later_gains_are_undone(colourful_room):
    cap = EnvironmentCapture(np.zeros(3), SMALL)
    T = look_at([0.0, 0.0, 0.0], [2.0, 0.1, 0.0])
    first = _step(cap, _frame(colourful_room, T))
    assert first.reference and first.projected and cap.em.valid.any()
    gains = np.array([1.6, 1.0, 0.7])
    second = _step(cap, _frame(colourful_room, look_at([0.0, 0.0, 0.0], [2.0, 0.2, 0.05]), gains, 1))
    assert second.projected and second.n_pairs > 1000
    # Within 5 %: the two views differ by ~6°, so pairs straddling patch edges mismatch (plain least
    # squares lands on the same matrix to 1e-3; the ridge prior is not what limits it).
    np.testing.assert_allclose(second.matrix, np.diag(1.0 / gains), atol=0.05 * (1.0 / gains).max())
    # The map stays in the reference colour space (the first frame's: gains 1, i.e. true radiance).
    wall = cap.em.valid & (np.abs(cap.em.radiance - 0.4).max(axis=-1) < 0.05)
    assert wall.sum() > 100



@pytest.mark.parametrize("method", ["least_squares", "ridge", "Cheung 2004"])
def test_the_fit_from_fused_sums_is_estimate_ccm_of_the_collected_pairs(colourful_room, method):
    """least_squares and ridge fit from sums accumulated in the pair pass; the colour-science methods
    from the pair arrays. Either way the step carries estimate_ccm's result for the frame's pairs."""
    from rgbd_envmap.colour import estimate_ccm
    from rgbd_envmap.envmap import frame_pairs

    cap = EnvironmentCapture(np.zeros(3), CaptureConfig(height=200, width=400, min_pairs=200, ccm_method=method))
    _step(cap, _frame(colourful_room, look_at([0.0, 0.0, 0.0], [2.0, 0.1, 0.0])))
    frame = _frame(colourful_room, look_at([0.0, 0.0, 0.0], [2.0, 0.2, 0.05]), (1.6, 1.0, 0.7), 1)
    src, dst = frame_pairs(cap.em, frame.depth_m, frame.known, INTR, frame.T_world_from_cam, frame.rgb, 0.01)
    expected = estimate_ccm(src, dst, method=method, min_pairs=200)
    step = _step(cap, frame)
    assert step.n_pairs == len(src) > 1000 and step.ccm.accepted == expected.accepted
    np.testing.assert_allclose(step.ccm.matrix, expected.matrix, rtol=1e-12, atol=1e-12)
    assert step.ccm.mse == pytest.approx(expected.mse, rel=1e-9) and step.ccm.n_pairs == expected.n_pairs


@pytest.mark.parametrize("bad", [{"ccm_method": "svd"}, {"max_mse": -1.0}, {"max_mse": float("nan")}, {"min_pairs": 0}])
def test_bad_colour_settings_are_refused_when_the_config_is_made(bad):
    from rgbd_envmap.errors import RangeError, UnknownMethodError

    with pytest.raises((RangeError, UnknownMethodError)):
        CaptureConfig(**bad)

def test_no_overlap_is_rejected_and_leaves_map_and_matrix_alone(colourful_room):
    cap = EnvironmentCapture(np.zeros(3), SMALL)
    _step(cap, _frame(colourful_room, look_at([0.0, 0.0, 0.0], [2.0, 0.0, 0.0])))
    before = cap.em.valid.copy()
    step = _step(cap, _frame(colourful_room, look_at([0.0, 0.0, 0.0], [-2.0, 0.0, 0.0]), (2.0, 2.0, 2.0), 1))
    assert not step.projected and step.reason.startswith("too few pairs")
    np.testing.assert_array_equal(cap.em.valid, before)
    np.testing.assert_array_equal(step.matrix, np.eye(3))


def test_correction_off_projects_every_frame_uncorrected(colourful_room):
    cap = EnvironmentCapture(np.zeros(3), CaptureConfig(height=200, width=400, colour_correction=False))
    _step(cap, _frame(colourful_room, look_at([0.0, 0.0, 0.0], [2.0, 0.0, 0.0])))
    step = _step(cap, _frame(colourful_room, look_at([0.0, 0.0, 0.0], [-2.0, 0.0, 0.0]), (0.5, 0.5, 0.5), 1))
    assert step.projected and step.ccm is None
    back = cap.em.valid & (cap.em.depth_m > 0)
    assert np.isclose(cap.em.radiance[back][:, 0], 0.2, atol=0.01).any()  # the halved wall went in as is


def test_freeze_keeps_the_map(colourful_room):
    cap = EnvironmentCapture(np.zeros(3), CaptureConfig(height=200, width=400, min_pairs=200, freeze=True))
    step = _step(cap, _frame(colourful_room, look_at([0.0, 0.0, 0.0], [2.0, 0.0, 0.0])))
    assert step.reference and not step.projected and not cap.em.valid.any()


def test_empty_frame_cannot_be_a_reference(colourful_room):
    cap = EnvironmentCapture(np.zeros(3), SMALL)
    frame = _frame(colourful_room, look_at([0.0, 0.0, 0.0], [2.0, 0.0, 0.0]))
    empty = RGBDFrame(frame.rgb, frame.depth_m, np.zeros(INTR.shape, bool), frame.T_world_from_cam, INTR, 0)
    step = _step(cap, empty)
    assert not step.reference and not step.projected and not cap.has_reference


@pytest.mark.parametrize("distance_m, projected", [(0.5, False), (0.099, True), (0.0, True)])
def test_fills_across_depth_edges_go_in_only_from_inside_the_trusted_sphere(colourful_room, distance_m, projected):
    """``across_edges`` pixels are left out of the map unless the device is within
    ``update.trusted_radius_m`` (0.1 m) of the origin; the other pixels go in either way."""
    origin = np.array([0.3, 0.0, 0.0])
    cap = EnvironmentCapture(origin, SMALL)
    frame = _frame(colourful_room, look_at(origin + [0.0, distance_m, 0.0], [2.0, 0.1, 0.0]))
    across = np.zeros(INTR.shape, bool)
    across[20:40, 30:60] = True
    mask = cap.projected_mask(frame, frame, across)
    np.testing.assert_array_equal(mask[~across], frame.known[~across])
    assert mask[across].all() == projected and mask[across].any() == projected
    np.testing.assert_array_equal(cap.projected_mask(frame, frame, None), frame.known)
    # Through process: the reference frame projects what the mask says.
    step = cap.process(frame, frame.known, frame, across_edges=across)
    ref = EnvironmentCapture(origin, SMALL)
    ref.process(frame, frame.known, frame)
    assert step.projected and (cap.em.valid.sum() == ref.em.valid.sum()) == projected


def test_across_edges_must_match_the_frame(colourful_room):
    from rgbd_envmap.errors import RgbdEnvmapError
    cap = EnvironmentCapture(np.zeros(3), SMALL)
    frame = _frame(colourful_room, look_at([0.0, 0.5, 0.0], [2.0, 0.1, 0.0]))
    with pytest.raises(RgbdEnvmapError):
        cap.process(frame, frame.known, frame, across_edges=np.zeros((3, 3), bool))
