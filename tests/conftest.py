"""Suite-wide: caches (PRT transfer, extracted meshes, bakes) go to a per-session temporary folder, so
the tests neither depend on nor write to the user's ~/.cache.

Under pytest-xdist (``scripts/test.sh`` runs two workers) the workers share that folder, so a scene is
baked and a PRT transfer computed once per session (the bake takes a lock per cache entry), and they
share compile locks (:mod:`apps.compile_once`), so each numba kernel compiles once on a cold cache.
"""

import os

from apps.process import configure_process

# The suite runs with the apps' process settings (one BLAS and one OpenCV thread), as the CLI does.
configure_process()

import pytest  # noqa: E402


def _session_dir(tmp_path_factory, name: str):
    """A folder for this test session, shared by the xdist workers of one run."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        path = tmp_path_factory.getbasetemp().parent / name  # basetemp is <run>/popen-gwN per worker
        path.mkdir(exist_ok=True)
        return path
    return tmp_path_factory.mktemp(name)


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    old = os.environ.get("RGBD_ENVMAP_CACHE")
    os.environ["RGBD_ENVMAP_CACHE"] = str(_session_dir(tmp_path_factory, "rgbd-envmap-cache"))
    if os.environ.get("PYTEST_XDIST_WORKER"):
        from apps.compile_once import install

        install(_session_dir(tmp_path_factory, "compile-locks"))
    yield
    if old is None:
        os.environ.pop("RGBD_ENVMAP_CACHE", None)
    else:
        os.environ["RGBD_ENVMAP_CACHE"] = old
