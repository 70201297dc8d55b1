"""`interp_axis` (the gather form of linear interpolation along one axis) gives the dense
`linear_weights` product's numbers, including clamped positions past either end."""

import numpy as np
import pytest

from globeview.terrain.interpolate import interp_axis, linear_weights


@pytest.mark.parametrize("axis", [0, 1])
def test_interp_axis_equals_the_weight_matrix_product(axis: int) -> None:
    rng = np.random.default_rng(7)
    values = rng.normal(size=(13, 9)).astype(np.float32)
    n = values.shape[axis]
    pos = np.concatenate([rng.uniform(-2.0, n + 1.0, 40), np.arange(n, dtype=np.float64)])
    w = linear_weights(pos, n)
    dense = w @ values.astype(np.float64) if axis == 0 else values.astype(np.float64) @ w.T
    got = interp_axis(values, pos, axis)
    assert got.shape == dense.shape
    np.testing.assert_allclose(got, dense, rtol=0, atol=1e-12)
    # At whole node positions it returns the nodes themselves.
    nodes = interp_axis(values, np.arange(n, dtype=np.float64), axis)
    np.testing.assert_array_equal(nodes, values.astype(np.float64))
