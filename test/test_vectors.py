"""core.vectors: the batched cross product against numpy's, for any broadcast shapes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from positioning_cell.core.vectors import cross

FINITE = st.floats(-1e3, 1e3, allow_nan=False)


@given(st.data())
def test_cross_is_numpys_for_any_broadcast_shapes(data: st.DataObject) -> None:
    shapes = data.draw(hnp.mutually_broadcastable_shapes(num_shapes=2, min_dims=0, max_dims=3))
    a = data.draw(hnp.arrays(np.float64, shapes.input_shapes[0] + (3,), elements=FINITE))
    b = data.draw(hnp.arrays(np.float64, shapes.input_shapes[1] + (3,), elements=FINITE))
    got = cross(a, b)
    want = np.cross(a, b)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)


def test_cross_refuses_what_is_not_a_3_vector() -> None:
    with pytest.raises(ValueError, match=r'\(\.\.\., 3\) vectors'):
        cross(np.zeros((2, 2)), np.zeros((2, 3)))
