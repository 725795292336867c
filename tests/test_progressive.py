"""The viewport's progressive renderer (issue 19): each step is a plain render at its resolution, the last
one the render at the given settings, a new start cancels the old, errors end up as a message."""

import dataclasses
import threading
import time

import numpy as np
import pytest

from lazyvis_addon.core import Settings, demo_scenes, render
from lazyvis_addon.core.camera import camera_rays
from lazyvis_addon.core.progressive import DIVISORS, ProgressiveRenderer, refinement_steps, scaled_camera


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


def test_every_step_equals_a_plain_render_at_its_resolution_and_the_last_the_full_render():
    scene = demo_scenes.floating_boxes(resolution=40)
    settings = Settings(aa_samples=4)
    images = []
    renderer = ProgressiveRenderer(on_image=images.append)
    generation = renderer.start(scene, settings)
    assert renderer.wait(600.0) and renderer.error is None
    assert [image.divisor for image in images] == [8, 4, 2, 1, 1]
    assert all(image.generation == generation for image in images)
    assert [image.seconds for image in images] == sorted(image.seconds for image in images)
    for image, (divisor, step, final) in zip(images, refinement_steps(settings)):
        plain = render(dataclasses.replace(scene, camera=scaled_camera(scene.camera, divisor)), step)
        assert image.image.shape == (-(-40 // divisor), -(-40 // divisor), 4) and image.final == final
        np.testing.assert_array_equal(image.image, plain.combined)
    np.testing.assert_array_equal(renderer.latest.image, render(scene, settings).combined)
    # The steps differ: the coarse image is not the fine one subsampled by chance.
    assert not np.array_equal(images[-2].image, images[-1].image)


class _Slow:
    """A render function that signals when a render starts and counts the calls (the render itself is the
    real one)."""

    def __init__(self):
        self.started = threading.Event()
        self.calls = []

    def __call__(self, scene, settings, progress):
        self.calls.append(scene.camera.width)
        self.started.set()
        return render(scene, settings, progress)


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

    def fails_at_the_second_step(step_scene, step_settings, progress):
        if step_scene.camera.width > 2:
            raise exception
        return render(step_scene, step_settings, progress)

    renderer = ProgressiveRenderer(render_function=fails_at_the_second_step)
    renderer.start(scene, Settings(aa_samples=1))
    assert renderer.wait(600.0)
    assert renderer.latest.divisor == 8 and not renderer.latest.final
    assert str(exception) in renderer.error
