"""Command-line apps and reports of rgbd-envmap."""

import os

# One BLAS thread unless the user says otherwise (set before numpy loads OpenBLAS): the pipeline's
# products are small and memory-bound, and on this 2-core box OpenBLAS's threads contend with the
# simulator's ray casting and the numba kernels (the map's SH shading took 8–16 ms with them, 0.35
# without; docs/prt.md).
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
