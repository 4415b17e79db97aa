"""The random numbers the population optimisers draw ahead."""

from __future__ import annotations

import numpy as np
import pytest

from formation_bench.optimizers.population import COMPILED_NORMALS_FROM, standard_normals


@pytest.mark.parametrize(
    "shape",
    [(3,), (COMPILED_NORMALS_FROM - 1,), (COMPILED_NORMALS_FROM,), (40, 30, 10), (64, 10, 10)],
)
def test_standard_normals_are_numpys_and_leave_the_generator_where_numpy_does(shape):
    for seed in range(3):
        ours, numpys = np.random.default_rng(seed), np.random.default_rng(seed)
        ours.random(seed)  # any position of the stream
        numpys.random(seed)
        drawn = standard_normals(ours, shape)
        expected = numpys.standard_normal(shape)
        assert drawn.shape == expected.shape and drawn.dtype == expected.dtype
        np.testing.assert_array_equal(drawn, expected)
        np.testing.assert_array_equal(ours.random(5), numpys.random(5))
        assert ours.bit_generator.state == numpys.bit_generator.state
