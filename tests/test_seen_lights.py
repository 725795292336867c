"""Lights the camera sees (``seen_lights``): drawn over the image as Cycles draws them (closed forms measured
against Cycles 5.0.1, see the README's light table), through the pixel filter, and the camera's clip planes."""

import math

import numpy as np
import pytest

from lazyvis_addon.core import Camera, Lights, Materials, Progress, Scene, SeenLights, Settings, render
from lazyvis_addon.core.demo_scenes import look_at, quad_triangles
from lazyvis_addon.core.facing import spread_normalisation
from lazyvis_addon.core.scene import SEEN_ARRAYS

# Cycles' smallest pixel filter: every sample within 0.01 px of the pixel centre.
POINT = Settings(aa_samples=1, filter_width=0.01)
RADIANCE = np.array([3.0, 2.0, 1.0])
# Near an outline a pixel takes 256 of the film's samples, and as in Cycles about 1 in 1023 of them strays
# anywhere over the pixel's left or lower half (``film.filter_offsets``): a pixel clear of the outline may
# still see a sample or two of the other side.
STRAYS = 0.02


def seen_scene(seen, camera, triangles=None, background=(0.0, 0.0, 0.0)):
    triangles = np.zeros((0, 3, 3)) if triangles is None else triangles
    return Scene(triangles, np.zeros(len(triangles), np.int64), Materials.diffuse([(0.5, 0.5, 0.5)]), Lights.empty(),
                 camera, np.asarray(background, np.float64), seen=seen)


def top_camera(resolution=40, width=4.0):
    """Orthographic, from z = 5 straight down, ``width`` m across: a pixel is width / resolution m."""
    return Camera.orthographic(look_at((0, 0, 5.0), (0, 0, 0), up=(0, 1, 0)), resolution, resolution, width)


def rectangle(centre=(0.3, -0.2, 1.0), half=(0.7, 0.45), up=True, **options):
    u, v = np.array([half[0], 0.0, 0.0]), np.array([0.0, half[1], 0.0])
    return SeenLights.area(centre, u, v if up else -v, RADIANCE, **options)


def test_a_rectangle_facing_the_camera_adds_its_radiance_over_what_lies_behind():
    """Cycles: a camera ray through an area light adds its radiance and goes on (the background shows through,
    +); the light's back is not seen. Through Blender's default filter the image holds the light's radiance
    times its area (the filter is normalised): one pixel row of error at most at the outline."""
    background = np.array([0.2, 0.1, 0.05])
    camera = top_camera()
    plain = render(seen_scene(SeenLights.empty(), camera, background=background), Settings()).combined
    front = render(seen_scene(rectangle(), camera, background=background), Settings()).combined
    back = render(seen_scene(rectangle(up=False), camera, background=background), Settings()).combined
    assert np.array_equal(plain, back)
    drawn = (front - plain)[..., :3]
    assert np.array_equal(front[..., 3], plain[..., 3])  # lights add no alpha
    pixel = (4.0 / 40) ** 2
    total = drawn.sum(axis=(0, 1)) * pixel
    assert np.allclose(total, RADIANCE * (1.4 * 0.9), rtol=2e-3)
    # Interior pixels (the filter's 3 px support inside the light) carry exactly the radiance.
    ys, xs = np.mgrid[0:40, 0:40]
    x, y = -2.0 + (xs + 0.5) * 0.1, 2.0 - (ys + 0.5) * 0.1
    inside = (np.abs(x - 0.3) < 0.7 - 0.16) & (np.abs(y + 0.2) < 0.45 - 0.16)
    outside = (np.abs(x - 0.3) > 0.7 + 0.16) | (np.abs(y + 0.2) > 0.45 + 0.16)
    assert inside.sum() > 40
    assert np.allclose(drawn[inside], RADIANCE, rtol=1e-6) and np.abs(drawn[outside]).max() == 0.0


def test_an_ellipse_is_drawn_as_an_ellipse():
    """A disk light is seen with its true outline (pass 2 lights with an equal-area polygon): at point filter
    the drawn pixels are those whose centre lies in the ellipse."""
    camera = top_camera(resolution=64)
    seen = SeenLights.area((0.1, 0.0, 1.0), (1.3, 0.0, 0.0), (0.0, 0.8, 0.0), RADIANCE, ellipse=True)
    drawn = render(seen_scene(seen, camera), POINT).combined[..., 0]
    ys, xs = np.mgrid[0:64, 0:64]
    x, y = -2.0 + (xs + 0.5) * 4 / 64, 2.0 - (ys + 0.5) * 4 / 64
    level = ((x - 0.1) / 1.3) ** 2 + (y / 0.8) ** 2
    clear = np.abs(np.sqrt(level) - 1.0) > 0.02  # centres more than a fiftieth of a pixel from the outline
    assert np.abs(drawn - np.where(level <= 1.0, RADIANCE[0], 0.0))[clear].max() <= STRAYS * RADIANCE[0]


@pytest.mark.parametrize("soft_falloff", [True, False])
def test_a_lamp_is_a_disk_facing_the_camera_or_a_sphere(soft_falloff):
    """A lamp of radius r at distance d fills the directions within atan(r / d) of its centre (Soft Falloff:
    a disk facing the ray's origin) or asin(r / d) (a sphere), with radiance I / (pi r^2)."""
    d, r, intensity = 2.0, 0.8, np.array([5.0, 5.0, 5.0])
    camera = Camera.perspective(look_at((0, 0, 0), (0, 0, d), up=(0, 1, 0)), 81, 81, math.radians(80.0))
    seen = SeenLights.lamp((0.0, 0.0, d), r, intensity, soft_falloff)
    drawn = render(seen_scene(seen, camera), POINT).combined[..., 0]
    left, right, bottom, top = camera.screen_window
    ys, xs = np.mgrid[0:81, 0:81]
    sx, sy = left + (xs + 0.5) / 81 * (right - left), top - (ys + 0.5) / 81 * (top - bottom)
    angle = np.arctan(np.hypot(sx, sy))
    limit = math.atan(r / d) if soft_falloff else math.asin(r / d)
    clear = np.abs(angle - limit) > 2e-3
    radiance = 5.0 / (math.pi * r * r)
    assert np.abs(drawn - np.where(angle < limit, radiance, 0.0))[clear].max() <= STRAYS * radiance


def test_the_spot_cone_and_the_spread_weigh_what_the_camera_sees():
    """Cycles' spot smoothstep on the direction from the lamp to the camera, and the Spread weight
    max(tan(s/2) - tan t, 0) / (tan(s/2) - s/2) on the direction from the light to the camera (both measured
    against Cycles 5.0.1: 0.8007 and 158.71 for these cases, as the README's light table says)."""
    camera = top_camera(resolution=9, width=0.9)  # the centre pixel looks straight down at (0, 0)
    tilt, size, blend = 0.5, math.radians(60.0), 0.5
    frame = np.linalg.inv(np.array([[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)],
                                    [0, math.sin(tilt), math.cos(tilt)]]) @ np.diag([1.0, 1.0, -1.0]))
    cos_half = math.cos(size / 2)
    spot = SeenLights.lamp((0, 0, 2.0), 0.5, np.ones(3), True, (frame, cos_half, blend * (1 - cos_half)))
    t = (math.cos(tilt) - cos_half) / (blend * (1 - cos_half))
    expected = t * t * (3 - 2 * t) / (math.pi * 0.25)
    assert render(seen_scene(spot, camera), POINT).combined[4, 4, 0] == pytest.approx(expected, rel=1e-6)

    spread, angle = math.radians(60.0), 0.3
    u, v = np.array([0.3, 0.0, 0.0]), np.array([0.0, 0.3 * math.cos(angle), 0.3 * math.sin(angle)])
    light = SeenLights.area((0, 0, 2.0), u, v, RADIANCE, spread=spread)
    weight = (math.tan(spread / 2) - math.tan(angle)) * spread_normalisation(np.array([spread]))[0]
    got = render(seen_scene(light, camera), POINT).combined[4, 4, :3]
    assert np.allclose(got, RADIANCE * weight, rtol=1e-6)


def test_the_sun_is_seen_only_where_a_ray_escapes():
    """A sun of angle a is a disc of radiance E / (pi sin^2(a/2)) in the sky; a quad in front hides it."""
    towards = np.array([0.0, 0.0, 1.0])
    half = math.radians(5.0)
    camera = Camera.perspective(look_at((0, 0, 0), (0, 0, 1), up=(0, 1, 0)), 41, 41, math.radians(40.0))
    blocker = quad_triangles([(0.0, -1.0, 3.0), (1.0, -1.0, 3.0), (1.0, 1.0, 3.0), (0.0, 1.0, 3.0)])
    seen = SeenLights.sun(towards, half, np.array([2.0, 2.0, 2.0]))
    image = render(seen_scene(seen, camera, blocker), POINT).combined[..., 0]
    left, right, bottom, top = camera.screen_window
    xs = np.arange(41)
    sx = left + (xs + 0.5) / 41 * (right - left)
    angle = np.arctan(np.abs(sx))
    row = image[20]
    radiance = 2.0 / (math.pi * math.sin(half) ** 2)
    # Looking along +z with y up, the image's right is the world's -x: the quad (x > 0) hides its left half.
    assert np.allclose(row[(angle < half - 1e-3) & (sx > 0)], radiance)
    assert np.abs(row[sx < -0.01]).max() == 0.0  # the quad (lit by nothing) hides the sun
    assert np.abs(row[angle > half + 1e-3]).max() == 0.0


def test_clip_start_and_end_cut_what_the_camera_sees():
    """Cycles starts camera rays on the clip-start plane and ends them on the clip-end plane: a quad nearer
    than Clip Start or beyond Clip End is not seen (background, background depth)."""
    def quad(z):
        return quad_triangles([(-5, -5, z), (5, -5, z), (5, 5, z), (-5, 5, z)])

    for z, visible in ((4.95, False), (4.5, True), (0.6, True), (0.4, False)):
        camera = top_camera(resolution=8)
        camera = Camera(camera.world_from_camera, 8, 8, camera.projection, camera.screen_window, None, 0.1, 4.5)
        out = render(seen_scene(SeenLights.empty(), camera, quad(z), background=(1.0, 1.0, 1.0)), POINT)
        assert (out.depth < 1e9).all() == visible and (out.depth < 1e9).any() == visible, z


def test_seen_lights_survive_a_scene_file(tmp_path):
    seen = SeenLights.concat([rectangle(spread=1.0), SeenLights.sun((0, 1, 1), 0.1, np.ones(3)),
                              SeenLights.lamp((0, 0, 1), 0.2, np.ones(3), False)])
    camera = top_camera()
    camera = Camera(camera.world_from_camera, 40, 40, camera.projection, camera.screen_window, None, 0.25, 80.0)
    scene = seen_scene(seen, camera)
    scene.save_npz(tmp_path / "scene.npz")
    loaded = Scene.load_npz(tmp_path / "scene.npz")
    assert (loaded.camera.clip_start, loaded.camera.clip_end) == (0.25, 80.0)
    for name in SEEN_ARRAYS:
        assert np.array_equal(getattr(loaded.seen, name), getattr(seen, name)), name


def test_bad_seen_lights_are_dropped_with_one_warning():
    """A NaN transform, a zero-size area light, a lamp of radius 0 or a sun of 180 degrees is not drawn (one
    warning); negative radiance is an error that names it."""
    good = rectangle()
    nan = SeenLights.area((np.nan, 0, 1), (1, 0, 0), (0, 1, 0), RADIANCE)
    flat = SeenLights.area((0, 0, 1), (1, 0, 0), (2, 0, 0), RADIANCE)
    point = SeenLights.lamp((0, 0, 1), 1.0, np.ones(3))
    point.radius[:] = 0.0
    wide = SeenLights.sun((0, 0, 1), 0.5 * math.pi, np.ones(3))
    progress = Progress()
    out = render(seen_scene(SeenLights.concat([good, nan, flat, point, wide]), top_camera()), POINT, progress)
    assert np.isfinite(out.combined).all() and out.combined[..., 0].max() == pytest.approx(RADIANCE[0])
    assert sum("seen by the camera" in w for w in progress.warnings) == 1
    negative = rectangle()
    negative.radiance[:] = -1.0
    with pytest.raises(ValueError, match="seen lights"):
        render(seen_scene(negative, top_camera()), POINT)


def test_a_scene_of_lights_only_renders_what_the_camera_sees_of_them():
    """No mesh at all (so no material either), a light that lights nothing and is seen: the background and
    the light, no error (pass 2 once indexed the empty material table)."""
    lights = Lights.from_polygons([[(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]], [(1.0, 1.0, 1.0)])
    scene = Scene(np.zeros((0, 3, 3)), np.zeros(0, np.int64), Materials(np.zeros((0, 3))), lights, top_camera(),
                  np.array([0.1, 0.1, 0.1]), seen=rectangle())
    image = render(scene, POINT).combined
    assert np.isclose(image[..., 0].min(), 0.1) and np.isclose(image[..., 0].max(), 0.1 + RADIANCE[0])


def test_a_border_render_draws_the_lights_of_the_full_frame():
    """A window (Blender's border, a farm's tile) draws exactly the full frame's pixels, outlines included:
    the outline samples are seeded by the full-frame pixel."""
    camera = Camera.perspective(look_at((0.3, -2.0, 1.0), (0, 0, 1.0), up=(0, 0, 1)), 40, 30, math.radians(50.0))
    seen = SeenLights.concat([SeenLights.area((0.0, 0.0, 1.0), (0.4, 0, 0), (0, 0, 0.3), RADIANCE, ellipse=True),
                              SeenLights.lamp((0.5, 0.5, 1.2), 0.1, np.ones(3))])
    full = render(seen_scene(seen, camera), Settings()).combined
    window = (7, 5, 29, 21)
    tile = Camera(camera.world_from_camera, 40, 30, camera.projection, camera.screen_window, window)
    part = render(seen_scene(seen, tile), Settings()).combined
    assert full[..., 0].max() > 1.0 and np.array_equal(part, full[5:21, 7:29])
