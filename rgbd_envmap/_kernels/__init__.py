"""The compiled (numba) kernels behind the library's stages.

Private: nothing outside ``rgbd_envmap`` should import from here. Each module holds the hot loops of
one stage and is called from that stage's public module only (for example
:mod:`rgbd_envmap.envmap.map_update` calls :mod:`rgbd_envmap._kernels.envmap_update`), which checks the
inputs, prepares the arrays and documents the contract. What each kernel must compute is written, in
plain numpy, in :mod:`rgbd_envmap.reference`; the tests compare the two bit for bit.

Importing this package compiles nothing and changes no global state: numba compiles a kernel on its
first call (or loads it from its on-disk cache), and :func:`rgbd_envmap._kernels.parallel.parallel_call`
picks numba's threading layer when a two-thread kernel first runs.
"""
