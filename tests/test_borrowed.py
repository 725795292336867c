"""``core.borrowed``: the borrowed array is the owner's memory (reads and writes go through), with the
owner's shape and strides, for contiguous and strided arrays of the dtypes the kernels borrow."""

import numpy as np
import pytest
from numba import njit

from lazyvis_addon.core.borrowed import borrowed


@njit(cache=False)
def _sum_and_double_first(array):
    view = borrowed(array)
    total = 0.0
    for i in range(view.shape[0]):
        for j in range(view.shape[1]):
            total += view[i, j]
    view[0, 0] = view[0, 0] * 2  # written through the borrowed array: the owner must see it
    return total, view.shape[0], view.strides[0]


@pytest.mark.parametrize("dtype", [np.float64, np.int64])
def test_a_borrowed_array_is_the_owners_memory(dtype):
    owner = np.arange(12, dtype=dtype).reshape(4, 3) + 1
    total, rows, stride = _sum_and_double_first(owner)
    assert (total, rows, stride) == (78, 4, owner.strides[0])
    expected = np.arange(12, dtype=dtype).reshape(4, 3) + 1
    expected[0, 0] = 2
    np.testing.assert_array_equal(owner, expected)


def test_a_strided_view_keeps_its_strides_when_borrowed():
    base = np.arange(24, dtype=np.float64).reshape(8, 3) + 1
    every_other = base[::2]
    total, rows, stride = _sum_and_double_first(every_other)
    assert (total, rows, stride) == ((np.arange(24).reshape(8, 3) + 1)[::2].sum(), 4, 2 * base.strides[0])
    assert base[0, 0] == 2.0 and base[1, 0] == 4.0 and base[2, 0] == 7.0  # only the view's first element
