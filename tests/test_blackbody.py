"""Blender's blackbody colour from the core's table (``core.blackbody``): luminance 1 as Blender
normalises it, its trend with temperature, the flat ends and bad input. Agreement with Blender's own
function and with Cycles' Blackbody node is tested through bpy (tests/blender/test_export.py)."""

import numpy as np

from lazyvis_addon.core.blackbody import blackbody_rgb

REC709_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def test_luminance_is_one_where_no_channel_is_clipped():
    """Blender normalises the colour to luminance 1; below about 2000 K its negative blue (and lower, green)
    is clipped to 0, which leaves more than 1."""
    temperature = np.geomspace(2100.0, 12000.0, 200)
    luminance = blackbody_rgb(temperature) @ REC709_LUMINANCE
    np.testing.assert_allclose(luminance, 1.0, atol=2e-3)
    assert (blackbody_rgb(np.geomspace(800.0, 1800.0, 50)) @ REC709_LUMINANCE > 1.0).all()


def test_red_falls_and_blue_rises_with_temperature_through_white_near_6500_kelvin():
    rgb = blackbody_rgb(np.geomspace(1000.0, 11000.0, 300))
    assert (np.diff(rgb[:, 0]) <= 1e-3).all() and (np.diff(rgb[:, 2]) >= -1e-3).all()
    white = blackbody_rgb(6500.0)
    assert np.abs(white - 1.0).max() < 0.05 and white.shape == (3,)


def test_outside_the_table_the_colour_is_held_and_nan_stays_nan():
    np.testing.assert_array_equal(blackbody_rgb([0.0, -5.0, 300.0]), np.repeat(blackbody_rgb(800.0)[None], 3, 0))
    np.testing.assert_array_equal(blackbody_rgb(1e6), blackbody_rgb(12000.0))
    assert np.isnan(blackbody_rgb(np.nan)).all()
    assert blackbody_rgb(np.full((2, 5), 3000.0)).shape == (2, 5, 3)
