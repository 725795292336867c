"""``lazyvis compare`` (lazyvis_addon/compare.py): LazyVis against Cycles at equal time and equal error, as a
picture and figures. The end-to-end run uses a tiny scene and the least reference; the pieces it is made of
are checked against closed forms."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from test_cli import lazyvis, save_small_scene  # noqa: E402

from lazyvis_addon.compare import ERROR_MAP_TOP, error_map, relative_rmse, samples_for_error  # noqa: E402


def test_compare_writes_the_picture_and_the_figures(scene, tmp_path):
    blend = save_small_scene(scene, tmp_path / "small.blend")  # 32 x 24
    result = lazyvis("compare", blend, "-o", tmp_path / "c.png", "--json", tmp_path / "c.json",
                     "--reference-samples", "64")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "LazyVis" in result.stdout and "Cycles in that time" in result.stdout
    image = bpy.data.images.load(str(tmp_path / "c.png"))
    assert tuple(image.size) == (3 * 32, 2 * 24)  # three images over their three error maps
    pixels = np.array(image.pixels[:], np.float32).reshape(48, 96, image.channels)[::-1, :, :3]
    assert pixels[:24].mean() > 0.05  # the renders are lit
    figures = json.loads((tmp_path / "c.json").read_text())
    for name in ("lazyvis", "cycles_equal_time", "cycles_equal_error"):
        assert math.isfinite(figures[name]["error"]) and figures[name]["error"] >= 0.0, name
        assert figures[name]["seconds"] > 0.0, name
    assert figures["reference"]["samples"] == 64 and figures["reference"]["noise"] > 0.0
    equal_error = figures["cycles_equal_error"]
    assert 1 <= equal_error["samples"] <= 16 and equal_error["target"] >= 0.01  # a quarter of the reference at most


def test_bad_reference_samples_and_missing_file(tmp_path):
    result = lazyvis("compare", tmp_path / "none.blend", "--reference-samples", "8")
    assert result.returncode == 2 and "at least 64" in result.stderr
    result = lazyvis("compare", tmp_path / "none.blend")
    assert result.returncode == 1 and "no such file" in result.stderr and "Traceback" not in result.stderr


def test_samples_for_error_inverts_a_power_law():
    # error = 0.4 / sqrt(samples): 1 % at 1,600 samples, 2 % at 400.
    errors = {16: 0.4 / 4.0, 64: 0.4 / 8.0}
    assert samples_for_error(errors, 0.01) == 1600
    assert samples_for_error(errors, 0.02) == 400
    # error = 2 / samples: 1 % at 200 samples.
    assert samples_for_error({16: 2 / 16, 64: 2 / 64}, 0.01) == 200


def test_relative_rmse_takes_the_references_noise_out():
    rng = np.random.default_rng(1)
    truth = np.full((64, 64, 3), 2.0)
    reference = truth + rng.normal(0.0, 0.1, truth.shape)         # noise 0.1, known
    image = truth + 0.04                                           # an error of 2 % of the mean
    assert relative_rmse(image, reference) == pytest.approx(math.hypot(0.04, 0.1) / 2.0, rel=0.02)
    assert relative_rmse(image, reference, 0.1) == pytest.approx(0.02, rel=0.1)
    assert relative_rmse(truth, reference, 0.2) == 0.0             # below the noise: nothing resolved


def test_error_map_colours():
    reference = np.ones((1, 4, 3))
    image = reference + np.array([0.0, ERROR_MAP_TOP / 3, ERROR_MAP_TOP, 5.0])[None, :, None]
    colours = error_map(image, reference)
    assert colours[0, 0].tolist() == [0, 0, 0]          # no error: black
    assert colours[0, 1].tolist() == [255, 0, 0]        # a third of the top: red
    assert colours[0, 2].tolist() == [255, 255, 255]    # the top and beyond: white
    assert colours[0, 3].tolist() == [255, 255, 255]
