"""tools/make_blocker_figure.py (issue 19, the blocker map as a picture): the script runs on a sample .blend
and writes its panels; the panels follow the render's passes (false colour black exactly where Blocker
Count is 0; Detection's umbra exactly where the core says a light is wholly hidden, penumbra only where
silhouette arcs cross a light)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import ROOT  # noqa: E402

from lazyvis_addon.core import BACKGROUND_DEPTH, Settings, render  # noqa: E402
from lazyvis_addon.core.demo_scenes import floating_boxes  # noqa: E402


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("make_blocker_figure", ROOT / "tools" / "make_blocker_figure.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up while being made
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop(spec.name, None)


@pytest.fixture(scope="module")
def renders():
    """The core's floating boxes (4 lights, background above the horizon) at 40 px, one sample a pixel:
    (Silhouettes render, Blocker Map render)."""
    scene = floating_boxes(40, n_boxes=16)
    settings = Settings(aa_samples=1)
    return render(scene, settings), render(scene, settings.replace(visibility="blocker_map"))


def crop(picture: np.ndarray, corner: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    return picture[corner[0]:corner[0] + shape[0], corner[1]:corner[1] + shape[1]]


def test_panels_follow_the_passes(tool, renders):
    silhouettes, blocker_map = renders
    shape = silhouettes.blocker_count.shape
    figure = tool.compose(tool.panels(silhouettes, blocker_map, "boxes"))
    combined, arcs, pairs, detection = (crop(figure.picture, corner, shape) for corner in figure.corners)
    assert combined.mean() > 20  # lit
    # False colour: black exactly where the count is 0, for both visibilities.
    for picture, count in ((arcs, silhouettes.blocker_count), (pairs, blocker_map.blocker_count)):
        assert (count == 0).any() and (count > 0).any()
        np.testing.assert_array_equal((picture == 0).all(axis=2), count == 0)
    # Detection: the colour of every pixel is its class's, and the classes follow the passes.
    colours = tool.DETECTION_COLOURS
    is_colour = {kind: (detection == colours[kind]).all(axis=2)
                 for kind in (tool.NOTHING, tool.VISIBLE, tool.PENUMBRA, tool.UMBRA)}
    assert sum(is_colour.values()).min() == 1  # each pixel one class colour
    seen = silhouettes.depth < BACKGROUND_DEPTH
    hidden = silhouettes.umbra.any(axis=2)
    np.testing.assert_array_equal(is_colour[tool.NOTHING], ~seen)
    np.testing.assert_array_equal(is_colour[tool.UMBRA], seen & hidden)
    assert not (is_colour[tool.PENUMBRA] & (silhouettes.blocker_count == 0)).any()
    np.testing.assert_array_equal(is_colour[tool.VISIBLE], seen & ~hidden & (silhouettes.blocker_count == 0))
    for kind, mask in is_colour.items():  # the scene has every class, so the checks above mean something
        assert mask.any(), tool.DETECTION_NAMES[kind]


def test_labels_stay_in_the_strips(tool, renders):
    silhouettes, blocker_map = renders
    shape = silhouettes.blocker_count.shape
    figure = tool.compose(tool.panels(silhouettes, blocker_map, "boxes"))
    picture = tool.labelled(figure)
    assert picture.shape == figure.picture.shape and picture.dtype == np.uint8
    changed = (picture != figure.picture).any(axis=2)
    assert changed.sum() > 50  # text was drawn
    for corner in figure.corners:  # and none over a panel
        assert not crop(changed, corner, shape).any()


def test_false_colour_is_dark_at_zero_and_brightens_with_the_count(tool):
    count = np.arange(0, 33, dtype=np.int32)[None, :]
    picture, top = tool.false_colour(count)
    assert top == 32 and picture.shape == (1, 33, 3) and picture.dtype == np.uint8
    assert (picture[0, 0] == 0).all() and (picture[0, 1:].max(axis=1) > 0).all()
    luma = picture[0, 1:] @ np.array([0.2126, 0.7152, 0.0722])
    assert (np.diff(luma) >= -1e-9).all() and luma[-1] > 3 * luma[0]
    np.testing.assert_array_equal(picture[0, -1], tool.VIRIDIS[-1])
    assert tool.false_colour(np.zeros((2, 2), np.int32))[0].max() == 0


def test_script_writes_the_figure(tool, tmp_path):
    output = tmp_path / "figure.png"
    result = subprocess.run([sys.executable, str(ROOT / "tools" / "make_blocker_figure.py"), "--width", "48",
                             "--out", str(output)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "floating_boxes, 48 x 48, 4 lights" in result.stdout and "Saved" in result.stdout
    # The layout of four 48 x 48 panels, from the tool's own composer.
    layout = tool.compose([tool.Panel("", np.zeros((48, 48, 3), np.uint8), kind, 2)
                           for kind in ("text", "scale", "scale", "classes")])
    image = bpy.data.images.load(str(output))
    try:
        height, width = layout.picture.shape[:2]
        assert tuple(image.size) == (width, height)
        pixels = np.array(image.pixels[:], np.float32).reshape(height, width, image.channels)[::-1, :, :3]
    finally:
        bpy.data.images.remove(image)
    picture = np.round(pixels * 255.0).astype(np.uint8)
    combined, arcs, _, detection = (crop(picture, corner, (48, 48)) for corner in layout.corners)
    assert combined.mean() > 20
    colours = tool.DETECTION_COLOURS
    kind = np.full((48, 48), -1)
    for index, colour in enumerate(colours):
        kind[(detection == colour).all(axis=2)] = index
    assert (kind >= 0).all()  # only the four class colours
    # No arcs (black) -> no penumbra; arcs -> a light partly or wholly hidden.
    no_arcs = (arcs == 0).all(axis=2)
    assert no_arcs.any() and (~no_arcs).any()
    assert not (no_arcs & (kind == tool.PENUMBRA)).any()
    assert np.isin(kind[~no_arcs], (tool.PENUMBRA, tool.UMBRA)).all()
