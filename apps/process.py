"""Process-wide settings of the command-line apps, made by their entry points (never on import).

The library itself sets nothing process-wide; an application decides how its process runs.
:func:`configure_process` is called first thing by :func:`apps.cli.main` and :func:`apps.warmup.main`,
before numpy, OpenCV or the library are imported:

- **One BLAS thread** (``OPENBLAS_NUM_THREADS``, ``MKL_NUM_THREADS``), unless the user set one: the
  pipeline's matrix products are small and memory-bound, and on a 2-core machine OpenBLAS's threads
  contend with the simulator's ray casting and the numba kernels (the map's SH shading was many
  times slower with them; docs/design/prt.md).
- **One OpenCV thread** (``OPENCV_FOR_THREADS_NUM``): its workers spin after every parallel call,
  and with the simulator's ray-casting threads and the video encoder a third runnable thread on two
  cores preempts the pipeline's.

Both are read by the libraries when they load, hence environment variables set before the imports.
Child processes (the sweep's workers) inherit them.
"""

from __future__ import annotations

import os

__all__ = ["configure_process", "PROCESS_ENV"]

#: environment defaults of the apps' processes (a value the user set is kept).
PROCESS_ENV = {"OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1"}


def configure_process() -> None:
    """Set :data:`PROCESS_ENV`'s defaults in ``os.environ`` (idempotent)."""
    for name, value in PROCESS_ENV.items():
        os.environ.setdefault(name, value)
