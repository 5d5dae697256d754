"""Shared fixtures for simulator tests: small scenes built in code, with closed-form answers."""

from __future__ import annotations

import pytest

from sim.scene import load_scene, scene_from_dict
from tests.sim.helpers import box_room


@pytest.fixture(scope="session")
def office():
    return load_scene("office_unlit")


@pytest.fixture(scope="session")
def cube_scene():
    return scene_from_dict(box_room())
