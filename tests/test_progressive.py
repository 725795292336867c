"""The viewport's progressive renderer (issue 19): each step is a plain render at its resolution, the last
one the render at the given settings, a new start cancels the old, errors end up as a message; the steps
and later starts share the scene's prepared structures (``prepared.prepare``) without changing a pixel, and a
changed scene is never served stale ones."""

import dataclasses
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from fuzz_scenes import SceneRecipe

from lazyvis_addon.core import Camera, Lights, Materials, Scene, SeenLights, Settings, demo_scenes, progressive, render
from lazyvis_addon.core.camera import camera_rays
from lazyvis_addon.core.demo_scenes import icosphere_triangles, look_at, quad_triangles
from lazyvis_addon.core.emitters import group_mesh_emitters
from lazyvis_addon.core.progressive import (DIVISORS, START_RESOLUTION, ProgressiveRenderer, refinement_steps,
                                              scaled_camera, step_divisors)
from lazyvis_addon.core.prepared import prepare


def test_a_coarse_pixel_looks_where_its_block_of_viewport_pixels_does():
    """A coarse pixel's centre ray is the viewport's ray through the centre of its divisor x divisor block,
    also where the size does not divide (the last block reaches past the edge); a border window becomes
    the coarse pixels that cover it."""
    camera = dataclasses.replace(demo_scenes.floating_boxes(resolution=50).camera, height=37,
                                 screen_window=np.array([-0.4, 0.4, -0.3, 0.29]), window=(3, 5, 47, 30))
    for divisor in DIVISORS:
        coarse = scaled_camera(camera, divisor)
        assert (coarse.width, coarse.height) == (-(-50 // divisor), -(-37 // divisor))
        x0, y0, x1, y1 = coarse.window
        assert x0 * divisor <= 3 and y0 * divisor <= 5 and x1 * divisor >= 47 and y1 * divisor >= 30
        xs = np.array([0, coarse.width - 1, 2 % coarse.width])
        ys = np.array([0, coarse.height - 1, 1 % coarse.height])
        _, got = camera_rays(coarse, xs, ys)
        block_centre = np.stack([xs * divisor + divisor / 2.0, ys * divisor + divisor / 2.0], axis=1)
        whole = np.floor(block_centre).astype(np.int64)
        _, want = camera_rays(camera, whole[:, 0], whole[:, 1], block_centre - whole)
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_steps_go_coarse_to_fine_and_end_with_the_renders_own_settings():
    settings = Settings(aa_samples=8)
    steps = refinement_steps(settings)
    assert [divisor for divisor, _, _ in steps] == [8, 4, 2, 1, 1]
    assert all(step.aa_samples == 1 for _, step, final in steps if not final)
    assert [final for _, _, final in steps] == [False] * 4 + [True] and steps[-1][1] == settings
    # Without anti-aliasing the full-resolution step is already the final image.
    plain = refinement_steps(Settings(aa_samples=1))
    assert [divisor for divisor, _, _ in plain] == [8, 4, 2, 1] and plain[-1][2]


def test_a_large_view_starts_coarser_than_an_eighth_at_the_start_resolution():
    """Steps coarser than 1/8, each half the last's divisor, until the first image's longer side is at most
    START_RESOLUTION pixels: 1/32 of 1280 x 720 is 40 x 23, 1/16 would be 80 x 45."""
    assert START_RESOLUTION == 64
    assert step_divisors(1280, 720) == (32, 16, 8, 4, 2, 1)
    assert step_divisors(720, 1280) == (32, 16, 8, 4, 2, 1)
    assert step_divisors(512, 300) == (8, 4, 2, 1)  # 64 pixels at 1/8: no coarser step
    assert step_divisors(513, 300) == (16, 8, 4, 2, 1)
    assert step_divisors(3840, 2160) == (64, 32, 16, 8, 4, 2, 1)
    assert step_divisors() == DIVISORS
    steps = refinement_steps(Settings(aa_samples=4), 1280, 720)
    assert [divisor for divisor, _, _ in steps] == [32, 16, 8, 4, 2, 1, 1]
    assert [final for _, _, final in steps] == [False] * 6 + [True]


def test_the_pixel_size_is_the_finest_step():
    """Blender's viewport Pixel Size p: the steps stop at divisor p, where the final (anti-aliased) render
    is made; without anti-aliasing the plain step at p is the final one."""
    steps = refinement_steps(Settings(aa_samples=4), 1280, 720, pixel_size=2)
    assert [divisor for divisor, _, _ in steps] == [32, 16, 8, 4, 2, 2]
    assert [final for _, _, final in steps] == [False] * 5 + [True] and steps[-1][1].aa_samples == 4
    steps = refinement_steps(Settings(aa_samples=1), 1280, 720, pixel_size=8)
    assert [(divisor, final) for divisor, _, final in steps] == [(32, False), (16, False), (8, True)]
    assert [divisor for divisor, _, _ in refinement_steps(Settings(aa_samples=4), 40, 40, pixel_size=4)] == [8, 4, 4]


@pytest.mark.parametrize("start_resolution, divisors", [(START_RESOLUTION, [8, 4, 2, 1, 1]),
                                                       (2, [32, 16, 8, 4, 2, 1, 1])])
def test_every_step_equals_a_plain_render_at_its_resolution_and_the_last_the_full_render(monkeypatch,
                                                                                          start_resolution, divisors):
    """Also from a start resolution of 2 pixels: a 40 x 40 view then starts at 1/32 (2 x 2 pixels) and
    1/16 (3 x 3)."""
    monkeypatch.setattr(progressive, "START_RESOLUTION", start_resolution)
    scene = demo_scenes.floating_boxes(resolution=40)
    settings = Settings(aa_samples=4)
    images = []
    renderer = ProgressiveRenderer(on_image=images.append)
    generation = renderer.start(scene, settings)
    assert renderer.wait(600.0) and renderer.error is None
    renderer.close()
    assert [image.divisor for image in images] == divisors
    assert all(image.generation == generation for image in images)
    assert [image.seconds for image in images] == sorted(image.seconds for image in images)
    for image, (divisor, step, final) in zip(images, refinement_steps(settings, 40, 40)):
        plain = render(dataclasses.replace(scene, camera=scaled_camera(scene.camera, divisor)), step)
        assert image.image.shape == (-(-40 // divisor), -(-40 // divisor), 4) and image.final == final
        np.testing.assert_array_equal(image.image, plain.combined)
    np.testing.assert_array_equal(renderer.latest.image, render(scene, settings).combined)
    # The steps differ: the coarse image is not the fine one subsampled by chance.
    assert not np.array_equal(images[-2].image, images[-1].image)


@pytest.mark.parametrize("visibility", ["silhouettes", "blocker_map"])
def test_the_full_plain_image_comes_from_the_final_render_by_silhouettes(visibility):
    """By silhouettes the final render hands over its centres before it anti-aliases: the full resolution is
    rendered once. The blocker map's anti-aliasing changes its centres (the extended flood fill): there the
    plain full step is a render of its own."""
    scene = demo_scenes.floating_boxes(resolution=40, n_boxes=8)
    settings = Settings(aa_samples=4, visibility=visibility)
    recorder = _Slow()
    images = []
    renderer = ProgressiveRenderer(on_image=images.append, render_function=recorder)
    renderer.start(scene, settings)
    assert renderer.wait(600.0) and renderer.error is None
    renderer.close()
    assert [(image.divisor, image.final) for image in images] == [(8, False), (4, False), (2, False), (1, False),
                                                                  (1, True)]
    assert recorder.calls == ([5, 10, 20, 40] if visibility == "silhouettes" else [5, 10, 20, 40, 40])
    plain = render(scene, settings.replace(aa_samples=1))
    np.testing.assert_array_equal(images[-2].image, plain.combined)


class _Slow:
    """A render function that signals when a render starts and counts the calls (the render itself is the
    real one)."""

    def __init__(self):
        self.started = threading.Event()
        self.calls = []

    def __call__(self, scene, settings, progress, prepared=None):
        self.calls.append(scene.camera.width)
        self.started.set()
        return render(scene, settings, progress, prepared=prepared)


def test_a_new_start_cancels_the_render_in_progress_and_only_its_images_follow():
    big = demo_scenes.floating_boxes(resolution=256)
    small = demo_scenes.floating_boxes(resolution=24)
    slow = _Slow()
    images = []
    renderer = ProgressiveRenderer(on_image=images.append, render_function=slow)
    first = renderer.start(big, Settings(aa_samples=16))
    assert slow.started.wait(30.0)
    while not images:  # the coarsest step of the first render
        time.sleep(0.01)
    time.sleep(0.05)  # into its next step
    stopped = time.perf_counter()
    assert renderer.cancel(wait=True, timeout=10.0)
    waited = time.perf_counter() - stopped
    assert waited < 1.0, f"the render in progress took {waited:.2f} s to stop"
    assert all(image.generation == first for image in images) and not images[-1].final
    count = len(images)
    second = renderer.start(small, Settings(aa_samples=4))
    assert renderer.wait(600.0) and renderer.error is None
    later = images[count:]
    assert [image.generation for image in later] == [second] * 5 and later[-1].final
    assert renderer.latest is later[-1]


def test_a_start_replaces_a_render_still_under_way_without_waiting_for_it():
    scene = demo_scenes.floating_boxes(resolution=128)
    images = []
    renderer = ProgressiveRenderer(on_image=images.append)
    renderer.start(scene, Settings(aa_samples=16))
    time.sleep(0.2)
    second = renderer.start(demo_scenes.floating_boxes(resolution=16), Settings(aa_samples=1))
    assert renderer.wait(600.0)
    assert renderer.latest.generation == second and renderer.latest.final
    assert renderer.latest.image.shape == (16, 16, 4)


def test_a_budget_too_small_ends_as_the_cores_message_not_an_exception():
    renderer = ProgressiveRenderer()
    renderer.start(demo_scenes.floating_boxes(resolution=16), Settings(aa_samples=1, memory_budget_mb=1))
    assert renderer.wait(600.0)
    assert renderer.latest is None
    assert renderer.error.startswith("memory budget of 1 MB is too small")


@pytest.mark.parametrize("exception", [RuntimeError("kernel failed"), MemoryError("budget of 1 MB is too small")])
def test_a_failing_step_leaves_the_last_good_image_and_names_the_failure(exception):
    scene = demo_scenes.floating_boxes(resolution=16)

    def fails_at_the_second_step(step_scene, step_settings, progress, prepared=None):
        if step_scene.camera.width > 2:
            raise exception
        return render(step_scene, step_settings, progress, prepared=prepared)

    renderer = ProgressiveRenderer(render_function=fails_at_the_second_step)
    renderer.start(scene, Settings(aa_samples=1))
    assert renderer.wait(600.0)
    assert renderer.latest.divisor == 8 and not renderer.latest.final
    assert str(exception) in renderer.error


# -- the prepared scene the steps share ------------------------------------------------------------------------

def _lamps_and_warnings_scene():
    """Spot and sun lamps, glossy materials, smooth normals with a terminator offset and a degenerate
    triangle (validation drops it with a warning): a fuzz recipe."""
    return SceneRecipe(seed=3, scale=1.0, ground=True, kinds=("box", "degenerate", "leaves"),
                       lights=(("above", 0.4, 4),), lamps=(("spot", 0.1), ("sun", 0.05)), camera="perspective",
                       width=24, height=20, materials=("diffuse", "glossy"), smooth=True, terminator=0.1).build()


def _emitter_scene():
    """A mesh emitter grouped as a hull (its frames, ``part_of``) over a floor, and a light the camera sees."""
    sphere = icosphere_triangles((0.0, 0.0, 0.8), 0.3, level=1)
    floor = quad_triangles([(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)])
    lights, hulls, _, _ = group_mesh_emitters(Lights(sphere, np.full(len(sphere), 3), np.full((len(sphere), 3), 4.0),
                                                     np.ones(len(sphere), bool)), np.zeros(len(sphere), np.int64))
    materials = Materials(np.array([[0.8, 0.8, 0.8], [0.0, 0.0, 0.0]]), np.array([[0.0] * 3, [4.0] * 3]))
    camera = Camera.perspective(look_at((0.0, -3.0, 2.5), (0.0, 0.0, 0.4)), 22, 18, np.radians(55))
    seen = SeenLights.area((0.8, 0.5, 1.2), (0.15, 0.0, 0.0), (0.0, 0.0, 0.1), (3.0, 3.0, 3.0))
    return Scene(np.concatenate([floor, sphere]), np.r_[np.zeros(len(floor), np.int64), np.ones(len(sphere), np.int64)],
                 materials, lights, camera, hulls=hulls, seen=seen)


def _moved(camera):
    """``camera`` half a unit to the side (a turned view)."""
    world_from_camera = camera.world_from_camera.copy()
    world_from_camera[:3, 3] += world_from_camera[:3, 0] * 0.5
    return dataclasses.replace(camera, world_from_camera=world_from_camera)


def _closes(tracer) -> list:
    """Records each ``tracer.close()`` (its threads stopped) in the list returned."""
    closes, close = [], tracer.close

    def counted():
        closes.append(True)
        close()
    tracer.close = counted
    return closes


def _assert_same_output(got, want):
    for name in ("combined", "blocker_count", "umbra", "depth", "normal", "sample_count"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert got.warnings == want.warnings


@pytest.mark.parametrize("scene_of", [lambda: demo_scenes.floating_boxes(resolution=24), _lamps_and_warnings_scene,
                                      _emitter_scene])
def test_a_prepared_scene_renders_any_camera_as_a_render_without_it(scene_of):
    """Every pass, bit for bit, and the same warnings: the frame, a coarse step, a border window (whose
    margin is per render), a moved view; with and without anti-aliasing."""
    scene = scene_of()
    settings = Settings(aa_samples=4)
    camera = scene.camera
    cameras = [camera, scaled_camera(camera, 4), dataclasses.replace(camera, window=(3, 2, 17, 15)), _moved(camera)]
    with prepare(scene, settings) as prepared:
        closes = _closes(prepared.tracer)
        for view in cameras:
            for step in (settings, settings.replace(aa_samples=1)):
                seen = dataclasses.replace(scene, camera=view)
                _assert_same_output(render(seen, step, prepared=prepared), render(seen, step))
        assert not closes
    assert prepared.closed and closes == [True]  # its threads stopped


def test_renders_on_two_threads_can_share_a_prepared_scene():
    scene = demo_scenes.floating_boxes(resolution=32)
    settings = Settings(aa_samples=2)
    views = [dataclasses.replace(scene, camera=camera) for camera in (scene.camera, _moved(scene.camera))] * 2
    with prepare(scene, settings) as prepared, ThreadPoolExecutor(2) as pool:
        outputs = list(pool.map(lambda view: render(view, settings, prepared=prepared), views))
    for view, output in zip(views, outputs):
        np.testing.assert_array_equal(output.combined, render(view, settings).combined)


def test_a_changed_scene_is_refused_and_prepared_again_keeping_only_what_is_equal():
    """A prepared scene serves its own scene's arrays only (by reference): a new scene of other lights,
    triangles or materials, or of equal copies, is refused; prepared again from it (``reuse``), it keeps
    the tracer where the triangles are equal by value, the frames and edge tree where the lights are too,
    the edge tree alone where only the lights' power changed, and renders as a render without any."""
    scene = demo_scenes.floating_boxes(resolution=24)
    settings = Settings(aa_samples=1)
    lit = dataclasses.replace(scene, lights=dataclasses.replace(scene.lights, radiance=scene.lights.radiance * 2.0))
    centre = scene.lights.vertices.mean(axis=1, keepdims=True)
    grown = dataclasses.replace(scene, lights=dataclasses.replace(
        scene.lights, vertices=centre + 1.5 * (scene.lights.vertices - centre)))
    moved = dataclasses.replace(scene, triangles=scene.triangles + np.array([0.0, 0.0, 0.05]))
    painted = dataclasses.replace(scene, materials=dataclasses.replace(
        scene.materials, albedo=scene.materials.albedo[:, ::-1].copy()))
    copied = dataclasses.replace(scene, triangles=scene.triangles.copy())
    plain = render(scene, settings).combined
    with prepare(scene, settings) as first:
        closes = _closes(first.tracer)
        for changed in (lit, grown, moved, painted, copied):
            with pytest.raises(ValueError, match="prepared from another scene"):
                render(changed, settings, prepared=first)
        with pytest.raises(ValueError, match="another integrator"):
            render(scene, Settings(aa_samples=1, integrator="reference"), prepared=first)
        for changed, kept in ((lit, ("tracer", "edge tree")), (grown, ("tracer",)), (moved, ()),
                              (painted, ("tracer", "lights")), (copied, ("tracer", "lights"))):
            with prepare(changed, settings, reuse=first) as again:
                assert again.reused == kept
                assert (again.tracer is first.tracer) == ("tracer" in kept)
                assert (again.edges is first.edges) == ("lights" in kept or "edge tree" in kept)
                assert (again.frames is first.frames) == ("lights" in kept)
                want = render(changed, settings).combined
                np.testing.assert_array_equal(render(changed, settings, prepared=again).combined, want)
                assert np.array_equal(want, plain) == (changed is copied)
        # The tracer both held lives on while either does.
        assert not closes
    assert closes == [True]


def test_a_closed_prepared_scene_stays_whole_while_a_render_holds_it():
    scene = demo_scenes.floating_boxes(resolution=16)
    settings = Settings(aa_samples=1)
    prepared = prepare(scene, settings)
    closes = _closes(prepared.tracer)
    prepared.acquire()
    prepared.close()
    assert prepared.closed
    np.testing.assert_array_equal(render(scene, settings, prepared=prepared).combined, render(scene, settings).combined)
    assert not closes
    prepared.release()
    assert closes == [True]
    with pytest.raises(ValueError, match="closed"):
        render(scene, settings, prepared=prepared)


def test_later_starts_keep_the_prepared_scene_until_the_scene_changes(monkeypatch):
    """A moved view renders with the kept prepared scene; a new scene of brighter lights prepares again,
    keeping the tracer and the edge tree, and closes the old one; every image is still a plain render's;
    ``close`` lets go of it."""
    prepared_scenes = []

    def counted(*args, **kwargs):
        prepared_scenes.append(prepare(*args, **kwargs))
        return prepared_scenes[-1]

    monkeypatch.setattr(progressive, "prepare", counted)
    scene = demo_scenes.floating_boxes(resolution=32)
    settings = Settings(aa_samples=2)
    images = []
    renderer = ProgressiveRenderer(on_image=images.append)
    renderer.start(scene, settings)
    assert renderer.wait(600.0) and renderer.error is None
    first = renderer.prepared
    assert prepared_scenes == [first] and not first.closed
    closes = _closes(first.tracer)
    view = dataclasses.replace(scene, camera=_moved(scene.camera))
    renderer.start(view, settings)
    assert renderer.wait(600.0) and renderer.error is None
    assert renderer.prepared is first and len(prepared_scenes) == 1
    np.testing.assert_array_equal(renderer.latest.image, render(view, settings).combined)
    lit = dataclasses.replace(view, lights=dataclasses.replace(view.lights, radiance=view.lights.radiance * 2.0))
    count = len(images)
    generation = renderer.start(lit, settings)
    assert renderer.wait(600.0) and renderer.error is None
    second = renderer.prepared
    assert prepared_scenes == [first, second] and second.reused == ("tracer", "edge tree")
    assert second.tracer is first.tracer and second.edges is first.edges
    assert first.closed and not closes  # the tracer is the second's now
    steps = images[count:]
    assert [image.generation for image in steps] == [generation] * len(refinement_steps(settings))
    for image, (divisor, step, _) in zip(steps, refinement_steps(settings)):
        plain = render(dataclasses.replace(lit, camera=scaled_camera(lit.camera, divisor)), step)
        np.testing.assert_array_equal(image.image, plain.combined)
    renderer.close(10.0)
    assert renderer.prepared is None and second.closed and closes == [True]
