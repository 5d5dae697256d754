"""Suite-wide: caches (PRT transfer, extracted meshes) go to a per-session temporary folder, so the
tests neither depend on nor write to the user's ~/.cache."""

import os

from apps.process import configure_process

# The suite runs with the apps' process settings (one BLAS and one OpenCV thread), as the CLI does.
configure_process()

import pytest  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    old = os.environ.get("RGBD_ENVMAP_CACHE")
    os.environ["RGBD_ENVMAP_CACHE"] = str(tmp_path_factory.mktemp("rgbd-envmap-cache"))
    yield
    if old is None:
        os.environ.pop("RGBD_ENVMAP_CACHE", None)
    else:
        os.environ["RGBD_ENVMAP_CACHE"] = old
