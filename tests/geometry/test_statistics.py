"""geometry.statistics.median against np.median, value and type."""

import numpy as np
import pytest

from annotate_rgbd.geometry.statistics import median


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("size", [1, 2, 3, 4, 7, 100, 101, 1000, 1001])
def test_the_same_number_as_numpy(dtype, size):
    rng = np.random.default_rng(size)
    for values in (rng.normal(size=size), rng.integers(0, 5, size=size) * 0.1, np.full(size, 3.25)):
        values = values.astype(dtype)
        before = values.copy()
        got, expected = median(values), np.median(values)
        assert got == expected and type(got) is type(expected)
        np.testing.assert_array_equal(values, before)  # not sorted in place


def test_nan_anywhere_gives_nan_like_numpy():
    for size in (7, 8):
        for where in (0, 3, size - 1):
            values = np.arange(size, dtype=np.float64)
            values[where] = np.nan
            assert np.isnan(median(values)) and np.isnan(np.median(values))
    rng = np.random.default_rng(5)
    for size in (101, 102, 1001):
        for _ in range(20):
            values = rng.normal(size=size)
            values[rng.integers(size)] = np.nan
            assert np.isnan(median(values))


def test_the_middle_two_of_an_even_count_without_overflow_of_an_odd_one():
    assert median(np.array([1.0, 4.0, 2.0, 3.0])) == 2.5
    huge = np.finfo(np.float64).max
    assert median(np.array([huge, huge, 0.0])) == huge  # (x + x) / 2 would overflow


def test_other_input_goes_to_numpy():
    assert median(np.array([1, 2, 3, 4])) == 2.5
    halves = np.array([1.0, 60000.0, 65504.0, 65504.0], dtype=np.float16)  # np.median averages in float32
    assert median(halves) == np.median(halves) and type(median(halves)) is type(np.median(halves))
    assert median(np.array([[1.0, 5.0], [3.0, 4.0]])) == 3.5
    with pytest.warns(RuntimeWarning):
        assert np.isnan(median(np.array([], dtype=np.float64)))
