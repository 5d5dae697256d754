"""sh.basis normalises directions of any finite length: huge or tiny ones must not overflow or
underflow to a NaN row (found by the fuzz suite: a direction of 7.7e153 in every component)."""

import numpy as np

from rgbd_envmap.sh import basis


def test_huge_and_tiny_directions_give_the_unit_directions_basis():
    for scale in (7.7e153, 1e300, 1e-170, 1e-300):
        for d in ([1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.2, 0.9]):
            np.testing.assert_allclose(basis(np.array(d) * scale), basis(np.array(d)), rtol=1e-12, atol=1e-15)


def test_zero_and_non_finite_directions_stay_nan_rows():
    assert np.isnan(basis(np.zeros(3))).all()
    assert np.isnan(basis(np.array([np.inf, 0.0, 0.0]))).all()
