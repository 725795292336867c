"""EXR writing and reading: exact float32 round trips, row order, half precision and clear errors."""

import numpy as np
import pytest

from lazyvis_addon.core.exr import read_exr, write_exr


def test_round_trip_is_exact_for_float32_with_dotted_names(tmp_path):
    rng = np.random.default_rng(0)
    height, width = 7, 11  # not square, so a transposition would show
    channels = {
        "R": rng.random((height, width), dtype=np.float32),
        "G": rng.normal(size=(height, width)).astype(np.float32),
        "B": np.full((height, width), np.float32(1e-30)),
        "A": np.ones((height, width), dtype=np.float32),
        "BlockerCount": rng.integers(0, 1000, (height, width)).astype(np.float64),  # any dtype is accepted
        "Depth": np.where(rng.random((height, width)) < 0.3, np.inf, rng.random((height, width)) * 100),
        "Normal.X": rng.uniform(-1, 1, (height, width)).astype(np.float32),
        "Normal.Y": rng.uniform(-1, 1, (height, width)).astype(np.float32),
    }
    path = tmp_path / "multi.exr"
    write_exr(path, channels)
    read = read_exr(path)
    assert set(read) == set(channels)
    for name, values in channels.items():
        assert read[name].dtype == np.float32 and read[name].shape == (height, width)
        np.testing.assert_array_equal(read[name], values.astype(np.float32))
    assert isinstance(channels["R"], np.ndarray)  # the caller's dict is left alone


def test_row_zero_stays_row_zero(tmp_path):
    height, width = 5, 3
    gradient = np.repeat(np.arange(height, dtype=np.float32)[:, None], width, axis=1)  # row index as value
    fortran_ordered = np.asfortranarray(gradient + 100)
    path = tmp_path / "gradient.exr"
    write_exr(str(path), {"Y": gradient, "Z": fortran_ordered})
    read = read_exr(str(path))
    np.testing.assert_array_equal(read["Y"][:, 0], np.arange(height))
    np.testing.assert_array_equal(read["Y"], gradient)
    np.testing.assert_array_equal(read["Z"], gradient + 100)


def test_half_rounds_to_float16(tmp_path):
    rng = np.random.default_rng(1)
    values = rng.normal(size=(4, 6)) * 100
    path = tmp_path / "half.exr"
    write_exr(path, {"R": values, "Depth": np.float32(1e5) * np.ones((4, 6))}, half=True)
    read = read_exr(path)
    assert read["R"].dtype == np.float32
    np.testing.assert_array_equal(read["R"], values.astype(np.float16).astype(np.float32))
    assert not np.array_equal(read["R"], values.astype(np.float32))  # precision really was reduced
    assert np.all(np.isinf(read["Depth"]))  # beyond the half range


def test_shape_mismatch_and_empty_input_raise_clearly(tmp_path):
    path = tmp_path / "bad.exr"
    with pytest.raises(ValueError, match=r"one shape.*'R' is 4 x 5.*'G' is 5 x 4"):
        write_exr(path, {"R": np.zeros((4, 5)), "G": np.zeros((5, 4))})
    with pytest.raises(ValueError, match="empty dict"):
        write_exr(path, {})
    with pytest.raises(ValueError, match="2-D"):
        write_exr(path, {"RGB": np.zeros((4, 5, 3))})
    with pytest.raises(ValueError, match="2-D"):
        write_exr(path, {"R": np.zeros((0, 5))})
    assert not path.exists()
