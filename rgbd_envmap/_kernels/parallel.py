"""Running the two-thread kernels: numba's threading layer and its compile-time note.

Nothing here runs at import. :func:`parallel_call` is how API modules call a kernel compiled with
``parallel=PRANGE_ONLY``:

- **Threading layer.** numba tries TBB first, and the TBB that some packages install is too old for
  it (a warning on every run). Before the first parallel launch of the process, and only if the
  environment does not choose (``NUMBA_THREADING_LAYER`` or ``NUMBA_THREADING_LAYER_PRIORITY``), the
  priority becomes OpenMP, TBB, workqueue. numba reads the setting once, at its first parallel launch,
  so setting it later changes nothing; this is the one global setting the library makes, and it makes
  it on first use, not on import.
- **The compile note.** With only ``prange`` enabled, numba says of each prange body, compiled on its
  own, that nothing in it could be parallelised: true, and not a problem. The note is silenced for the
  call that compiles, not process-wide.
"""

from __future__ import annotations

import os
import warnings
from typing import Any, Callable

import numba
from numba.core.errors import NumbaPerformanceWarning

__all__ = ["parallel_call", "configure_threading_layer", "usable_threads"]

_NOTE = r"\s*The keyword argument 'parallel=True' was specified but no transformation"
_configured = False


def configure_threading_layer() -> None:
    """Prefer OpenMP for numba's parallel kernels unless the environment chooses (idempotent)."""
    global _configured
    if _configured:
        return
    _configured = True
    if "NUMBA_THREADING_LAYER" in os.environ or "NUMBA_THREADING_LAYER_PRIORITY" in os.environ:
        return
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


def parallel_call(kernel: Callable[..., Any], *args: Any, threads: int | None = None) -> Any:
    """``kernel(*args)`` for a kernel compiled with ``parallel=PRANGE_ONLY`` (see the module
    docstring), on at most ``threads`` threads (None: numba's thread count). The kernels give the
    same results on any number of threads; ``threads`` only says how many cores they may take."""
    configure_threading_layer()
    before = numba.get_num_threads()
    n = before if threads is None else max(1, min(int(threads), before))
    if n != before:
        numba.set_num_threads(n)  # this thread's next parallel regions only
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=_NOTE, category=NumbaPerformanceWarning)
            return kernel(*args)
    finally:
        if n != before:
            numba.set_num_threads(before)


def usable_threads(requested: int) -> int:
    """Threads a kernel may use: ``requested``, at most numba's thread count (asking numba for it
    starts its threading layer, so the layer is chosen first)."""
    configure_threading_layer()
    return min(int(requested), numba.get_num_threads())
