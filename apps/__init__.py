"""Command-line apps and reports of rgbd-envmap."""

import os

# One BLAS thread unless the user says otherwise (set before numpy loads OpenBLAS): the pipeline's
# products are small and memory-bound, and on this 2-core box OpenBLAS's threads contend with the
# simulator's ray casting and the numba kernels (the map's SH shading took 8–16 ms with them, 0.35
# without; docs/prt.md).
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# OpenCV's own thread pool likewise: its workers spin (sched_yield) after every parallel call, and
# with the simulator's ray-casting threads and the video encoder a third runnable thread on 2 cores
# preempted the pipeline's. Main job, alternating runs: depth_frame_total 9.84 / 9.89 / 9.92 ms
# median with one OpenCV thread against 9.94 / 10.09 / 10.80 with two (the NV21 decode, 0.29 →
# 0.36 ms, is the one call that was faster on two threads).
os.environ.setdefault("OPENCV_FOR_THREADS_NUM", "1")
