"""Plain-numpy references: what each compiled kernel of the library computes, written to be read.

Each function here does one stage's work one sample or one pixel at a time, in the most direct
form, and is the spec of that stage's kernels: the tests compare the kernels with these bit for bit
(or, where a kernel uses fast-math, within a stated tolerance). A newcomer who wants to know what a
stage computes reads its reference, then the stage's public module for the contract; the kernels in
:mod:`rgbd_envmap._kernels` only make the same computation fast.

The references are slow (Python loops) and meant for small inputs: tests, and checking a change.
Where a kernel and its reference must agree to the last bit on continuous coordinates (a pixel
index depends on them), the reference takes them from the public function that computes them
(:func:`rgbd_envmap.envmap.map_update.map_coordinates`,
:func:`rgbd_envmap.envmap.translation.reprojected_coordinates`), and the tests check those against
closed forms separately.

This package imports numpy and the library's public modules only, never the kernels.
"""
