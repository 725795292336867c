"""The render engine's plumbing with a stand-in core (passes, row order, border, errors, cancel,
settings), then whole renders through Blender with the real core (bad input). Agreement with Cycles is
test_cycles_agreement.py, against committed references."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import add_area_light, add_camera, add_light, render_to_exr  # noqa: E402

from lazyvis_addon.blender import engine as engine_module  # noqa: E402
from lazyvis_addon.core import Settings  # noqa: E402
from lazyvis_addon.core.progress import RenderCancelled  # noqa: E402



class FakeOutput:
    """A RenderOutput whose pixels say where they are: R = full-frame x, G = full-frame row from the top."""

    def __init__(self, camera):
        x0, y0, x1, y1 = camera.window
        ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
        self.combined = np.stack([xs, ys, np.zeros_like(xs), np.ones_like(xs)], axis=2)
        self.depth = 100.0 + ys
        self.normal = np.stack([xs, ys, -np.ones_like(xs)], axis=2)
        self.blocker_count = (xs + 1000 * ys).astype(np.int32)
        self.sample_count = (1 + xs % 2 * 15).astype(np.int32)
        self.umbra = np.zeros(xs.shape + (0,), bool)
        self.warnings, self.stats = [], {"seconds": 0.0}


@pytest.fixture
def fake_core(monkeypatch):
    """Replace the core with a recorder; ``calls`` holds (scene, settings) of every render."""
    calls = []

    def render(scene, settings, progress):
        calls.append((scene, settings))
        progress.begin_stage("Fake stage", 2)
        progress.advance(2)
        return FakeOutput(scene.camera)

    monkeypatch.setattr(engine_module, "core_render", render)
    return calls


def simple_scene(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    add_area_light(location=(0.0, 0.0, 2.0), size=1.0, energy=20.0)


# -- plumbing ------------------------------------------------------------------------------------------


def test_passes_are_written_top_row_first_in_the_exr(scene, fake_core, tmp_path):
    simple_scene(scene)
    layer = scene.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = True
    layer.lazyvis.use_pass_sample_count = True
    channels = render_to_exr(scene, tmp_path / "passes.exr", multilayer=True)
    prefix = layer.name + "."
    combined = channels[prefix + "Combined"]
    height, width = 24, 32
    assert combined.shape == (height, width, 4)
    ys, xs = np.mgrid[0:height, 0:width]
    np.testing.assert_array_equal(combined[..., 0], xs)
    np.testing.assert_array_equal(combined[..., 1], ys)  # EXR rows are top first, like the core's
    np.testing.assert_array_equal(channels[prefix + "Depth.Z"], 100.0 + ys)
    np.testing.assert_array_equal(channels[prefix + "Normal.Y"], ys)
    np.testing.assert_array_equal(channels[prefix + "Blocker Count.X"], xs + 1000 * ys)
    np.testing.assert_array_equal(channels[prefix + "Sample Count.X"], 1 + xs % 2 * 15)


def test_every_view_layer_gets_its_own_render(scene, fake_core, tmp_path):
    simple_scene(scene)
    second = scene.view_layers.new("Second")
    second.use_pass_z = True
    channels = render_to_exr(scene, tmp_path / "layers.exr", multilayer=True)
    assert len(fake_core) == 2
    first = scene.view_layers[0].name
    np.testing.assert_array_equal(channels[first + ".Combined"], channels["Second.Combined"])
    assert "Second.Depth.Z" in channels and first + ".Depth.Z" not in channels


def test_optional_passes_follow_the_view_layer(scene, fake_core, tmp_path):
    simple_scene(scene)
    layer = scene.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = False
    layer.lazyvis.use_pass_blocker_count = False
    channels = render_to_exr(scene, tmp_path / "few.exr", multilayer=True)
    assert sorted(channels) == [layer.name + ".Combined"]


@pytest.mark.parametrize("crop", [False, True])
def test_border_render_places_the_window(scene, fake_core, tmp_path, crop):
    simple_scene(scene)
    render = scene.render
    render.use_border, render.use_crop_to_border = True, crop
    render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y = 0.25, 0.75, 0.1, 0.6
    combined = render_to_exr(scene, tmp_path / "border.exr")["RGBA"]
    x0, y0, x1, y1 = fake_core[0][0].camera.window
    assert (x0, x1) == (8, 24) and (24 - y1, 24 - y0) == (2, 14)
    region = combined if crop else combined[y0:y1, x0:x1]
    assert region.shape[:2] == (y1 - y0, x1 - x0)
    ys, xs = np.mgrid[y0:y1, x0:x1]
    np.testing.assert_array_equal(region[..., 0], xs)  # full-frame coordinates at the right place
    np.testing.assert_array_equal(region[..., 1], ys)
    if not crop:
        outside = np.ones(combined.shape[:2], bool)
        outside[y0:y1, x0:x1] = False
        assert (combined[outside] == 0).all()


@pytest.mark.parametrize("border", [False, True])
def test_the_image_before_anti_aliasing_shows_then_gives_way_to_the_final(scene, monkeypatch, tmp_path, border):
    """In the render window (not a background render) the core's preview is written into the result while
    anti-aliasing runs; the final image replaces it everywhere (a border's window too)."""
    asked = []

    def render(scene, settings, progress):
        asked.append(progress.wants_preview)
        if progress.wants_preview:
            preview = FakeOutput(scene.camera)
            preview.combined = np.full_like(preview.combined, -7.0)
            progress.on_preview(preview)
        return FakeOutput(scene.camera)

    monkeypatch.setattr(engine_module, "core_render", render)
    simple_scene(scene)
    scene.render.use_border = border
    scene.render.border_min_x, scene.render.border_max_x = 0.25, 0.75
    combined = render_to_exr(scene, tmp_path / "final.exr")["RGBA"]
    assert asked == [False]  # tests render in the background: no preview asked for
    monkeypatch.setattr(engine_module, "showing_previews", lambda: True)
    assert (render_to_exr(scene, tmp_path / "previewed.exr")["RGBA"] == combined).all()
    assert asked == [False, True] and (combined != -7.0).all()


def test_border_of_any_fraction_matches_blenders_result(scene, fake_core):
    """Blender truncates border fraction x size computed in float32 (7/96 x 96 gives 7, not 6.9999...):
    the window must have exactly the render result's size for every border, or the render fails."""
    simple_scene(scene)
    render = scene.render
    render.resolution_x, render.resolution_y = 8, 96
    render.use_border, render.use_crop_to_border = True, True
    for first in range(0, 96, 3):
        render.border_min_y, render.border_max_y = first / 96, (first + 1) / 96
        bpy.ops.render.render()  # raises if the window and Blender's result differ in size
        x0, y0, x1, y1 = fake_core[-1][0].camera.window
        assert (y1 - y0, 96 - y1) == (1, first)


def test_resolution_percentage_and_settings_reach_the_core(scene, fake_core, tmp_path):
    simple_scene(scene)
    scene.render.resolution_percentage = 50
    scene.render.film_transparent = True
    scene.lazyvis.integrator = "standard_mc"
    scene.lazyvis.mc_samples = 9
    scene.frame_current = 7
    render_to_exr(scene, tmp_path / "half.exr")
    core_scene, settings = fake_core[0]
    assert (core_scene.camera.width, core_scene.camera.height) == (16, 12)
    assert settings.integrator == "standard_mc" and settings.mc_samples == 9
    assert settings.transparent_background and settings.frame == 7


def test_render_depsgraph_drops_hidden_objects_and_instancers(scene, fake_core, tmp_path):
    simple_scene(scene)  # a plane: 2 triangles
    bpy.ops.mesh.primitive_cube_add(location=(5.0, 0.0, 0.0))
    bpy.context.object.hide_render = True
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, location=(0.0, 0.0, 5.0))
    ico = bpy.context.object
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=1, y_subdivisions=1, size=1.0, location=(0.0, 0.0, 5.0))
    grid = bpy.context.object  # one face
    grid.instance_type = "FACES"
    grid.show_instancer_for_render = False
    ico.parent = grid
    render_to_exr(scene, tmp_path / "hidden.exr")
    core_scene = fake_core[0][0]
    # plane + the icosphere on the grid's face; no cube, no grid, and (measured: unlike a viewport
    # depsgraph) a render depsgraph does not show the instanced child itself either.
    assert len(core_scene.triangles) == 2 + 20


def test_bad_input_is_reported_as_an_error_without_traceback(scene, monkeypatch, capfd):
    simple_scene(scene)

    def render(scene, settings, progress):
        raise ValueError("light polygons must be planar")

    monkeypatch.setattr(engine_module, "core_render", render)
    with pytest.raises(RuntimeError, match="LazyVis: light polygons must be planar"):
        bpy.ops.render.render()
    assert "Traceback" not in capfd.readouterr().err


def test_internal_error_is_reported_not_raised(scene, monkeypatch, capfd):
    simple_scene(scene)

    def render(scene, settings, progress):
        raise KeyError("oops")

    monkeypatch.setattr(engine_module, "core_render", render)
    with pytest.raises(RuntimeError, match="LazyVis internal error \\(KeyError"):
        bpy.ops.render.render()


@pytest.mark.parametrize("where", ["export", "core", "result"])
def test_a_crash_anywhere_leaves_blender_rendering(scene, monkeypatch, capfd, tmp_path, where):
    """Issue 17's crash safety: an exception in the export, the core or the writing of Blender's result ends
    the render with a red report (no traceback raised into Blender, the details on the console), and a
    second render right after, with nothing patched, renders the scene."""
    simple_scene(scene)
    target = {"export": "export_depsgraph", "core": "core_render", "result": "write_result"}[where]

    def broken(*args, **kwargs):
        raise ZeroDivisionError(f"a bug in the {where}")

    with monkeypatch.context() as patch:
        patch.setattr(engine_module, target, broken)
        with pytest.raises(RuntimeError, match=f"LazyVis internal error \\(ZeroDivisionError: a bug in the {where}\\)"):
            bpy.ops.render.render()
    assert "ZeroDivisionError" in capfd.readouterr().err  # the console has the details
    pixels = render_to_exr(scene, tmp_path / "after.exr")["RGBA"]
    assert np.isfinite(pixels).all() and pixels[..., :3].max() > 0.01


def test_cancel_stops_quietly(scene, monkeypatch):
    simple_scene(scene)
    seen = []

    def render(scene, settings, progress):
        progress.begin_stage("Illumination", 10)
        monkeypatch.setattr(engine_module.EngineProgress, "is_cancelled", lambda self: True)
        try:
            progress.advance(1)
        except RenderCancelled:
            seen.append("cancelled")
            raise
        raise AssertionError("advance did not see the cancel")

    monkeypatch.setattr(engine_module, "core_render", render)
    bpy.ops.render.render()  # no error: a cancel is not a failure
    assert seen == ["cancelled"]


def test_cancel_during_export_stops_before_the_core(scene, monkeypatch):
    """Esc while the scene is exported (between objects) ends the render quietly; the core never starts."""
    simple_scene(scene)
    started, asked = [], []

    def is_cancelled(self):  # the stage's own check passes; Esc comes once the export is under way
        asked.append(1)
        return len(asked) > 1

    monkeypatch.setattr(engine_module.EngineProgress, "is_cancelled", is_cancelled)
    monkeypatch.setattr(engine_module, "core_render", lambda *args: started.append(1))
    bpy.ops.render.render()  # no error: a cancel is not a failure
    assert started == []


def test_core_warnings_reach_blender_reports(scene, monkeypatch, reports):
    simple_scene(scene)

    def render(scene, settings, progress):
        progress.warn("dropped 3 zero-area triangle(s)")
        return FakeOutput(scene.camera)

    monkeypatch.setattr(engine_module, "core_render", render)
    bpy.ops.render.render()
    assert "dropped 3 zero-area triangle(s)" in reports


# -- with the real core --------------------------------------------------------------------------------


def test_no_lights_warns_and_renders_black(scene, reports, tmp_path):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=20.0)
    combined = render_to_exr(scene, tmp_path / "dark.exr")["RGBA"]
    assert any("no lights" in message for message in reports)
    np.testing.assert_array_equal(combined[..., :3], 0.0)
    np.testing.assert_array_equal(combined[..., 3], 1.0)


def test_point_lights_light_the_plane_and_the_camera_sees_them(scene, reports, tmp_path):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=20.0)
    for name in ("Bulb", "Lamp"):
        bpy.ops.object.light_add(type="POINT", location=(0.0, 0.0, 2.0))
        bpy.context.object.name = name
        bpy.context.object.data.shadow_soft_size = 0.5
        bpy.context.object.visible_camera = True
    scene.cycles.filter_width = 0.01  # pixel centres: the lamps' middle pixels see them whole
    combined = render_to_exr(scene, tmp_path / "points.exr")["RGBA"]
    # Cycles draws lamps the camera sees, over what lies behind them: so does LazyVis, without a warning.
    assert not any("Bulb" in m for m in reports)
    assert combined[..., :3].min() > 0 and np.isfinite(combined).all()
    power = bpy.data.objects["Bulb"].data.energy
    drawn = 2 * power / (4 * np.pi) / (np.pi * 0.5 ** 2)  # two lamps' radiance I / (pi r^2), one in front
    assert drawn < combined[..., 0].max() < 1.01 * drawn


def test_odd_point_spot_and_sun_lights_give_warnings_and_a_sensible_image(scene, reports, tmp_path):
    """A lamp inside a closed box, a sun of Angle 180 degrees, spots of size 0 and 180 degrees, negative power
    and a NaN transform: one warning each where LazyVis departs from Cycles, finite pixels, no traceback."""
    import math
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=20.0)
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(1.0, 1.0, 0.5))
    add_light("POINT", location=(1.0, 1.0, 0.5), name="Boxed", energy=100.0, shadow_soft_size=0.1)
    add_light("SUN", name="Wide Sun", energy=1.0, angle=math.pi)
    add_light("SPOT", location=(0.0, 0.0, 3.0), name="Pin", energy=100.0, spot_size=0.0)
    add_light("SPOT", location=(0.0, 0.0, 3.0), name="Open", energy=100.0, spot_size=math.pi, shadow_soft_size=0.2)
    add_light("POINT", location=(0.0, 0.0, 2.0), name="Negative", energy=-50.0)
    add_light("POINT", location=(float("nan"), 0.0, 2.0), name="Lost", energy=50.0)
    combined = render_to_exr(scene, tmp_path / "odd.exr")["RGBA"]
    assert np.isfinite(combined).all() and combined[..., :3].min() >= 0 and combined[..., :3].max() > 0
    assert any("Wide Sun" in m and "degrees" in m for m in reports)
    assert any("Negative" in m and "negative power" in m for m in reports)
    assert any("Lost" in m and "NaN" in m for m in reports)


def test_zero_size_light_warns(scene, reports, tmp_path):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=20.0)
    add_area_light(name="Sliver", size=0.0, energy=100.0)
    render_to_exr(scene, tmp_path / "sliver.exr")
    assert any("zero size" in m and "Sliver" in m for m in reports)


def test_nan_vertex_is_an_error_through_report(scene, capfd):
    simple_scene(scene)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    cube.name = "Corrupt"
    cube.data.vertices[3].co = (0.0, float("inf"), float("nan"))
    with pytest.raises(RuntimeError, match="'Corrupt' has NaN or infinite vertex coordinates"):
        bpy.ops.render.render()
    assert "Traceback" not in capfd.readouterr().err


def test_depth_and_normal_passes_are_cycles(scene, tmp_path):
    """The real core's Depth (planar distance from the camera, m) and Normal (world shading normal) passes
    against Cycles' on a tilted plane and a smooth sphere, pixel centres both (filter 0.01 px, Cycles at one
    sample: its passes are those of the surface at the centre): equal where both see the same surface, and
    the background at the same pixels."""
    from blender_helpers import cycles_reference_tool

    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=6.0, rotation=(0.3, -0.2, 0.0))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(0.4, 0.3, 1.0))
    bpy.ops.object.shade_smooth()
    add_area_light(location=(0.0, 0.0, 3.0), size=1.0, energy=20.0)
    scene.render.resolution_x, scene.render.resolution_y = 48, 36
    layer = scene.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = True
    scene.cycles.filter_width = 0.01
    prefix = layer.name + "."

    def passes(path):
        channels = render_to_exr(scene, path, multilayer=True)
        normal = np.stack([channels[prefix + f"Normal.{axis}"] for axis in "XYZ"], axis=2)
        return channels[prefix + "Depth.Z"], normal, channels[prefix + "Combined"][..., 3]

    depth, normal, _ = passes(tmp_path / "lazyvis.exr")
    cycles_reference_tool().configure_cycles(scene, samples=1, seed=1, filter_width=0.01)
    scene.render.film_transparent = True  # alpha says where Cycles hit something
    cycles_depth, cycles_normal, cycles_alpha = passes(tmp_path / "cycles.exr")
    hit = cycles_alpha > 0.5
    assert 0.3 < hit.mean() < 1.0  # the plane does not fill the frame
    assert (hit == (depth < 1e9)).mean() > 0.98  # the same pixels see something (an outline may differ)
    both = hit & (depth < 1e9)
    close = np.abs(depth - cycles_depth) < 1e-4 * cycles_depth
    close &= np.abs(normal - cycles_normal).max(axis=2) < 1e-3
    assert close[both].mean() > 0.97, close[both].mean()  # silhouette pixels: either surface
    assert np.abs(np.linalg.norm(normal[both], axis=1) - 1.0).max() < 1e-4


def test_transparent_film_clears_background_alpha(scene, tmp_path):
    add_camera(scene)
    # A plane ~15 px across: its centre pixel lies beyond the 1.5 px filter's reach of the background,
    # whose samples would otherwise (rightly) pull the filtered alpha below 1.
    bpy.ops.mesh.primitive_plane_add(size=2.5)
    add_area_light(location=(0.0, 0.0, 2.0), size=1.0, energy=20.0)
    scene.render.film_transparent = True
    combined = render_to_exr(scene, tmp_path / "alpha.exr")["RGBA"]
    assert combined[0, 0, 3] == 0.0 and combined[12, 16, 3] == 1.0


def test_border_render_equals_the_full_frame_region(scene, tmp_path):
    simple_scene(scene)
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.0, 0.0, 0.3))
    # The default settings, anti-aliasing on: a border's pixels are the full frame's bit for bit (the core
    # renders the border's margin and allocates samples at the frame's scale), through the export of the
    # border, the core's window and Blender's result.
    assert scene.lazyvis.aa_samples > 1 and scene.lazyvis.window_margin == Settings().window_margin
    full = render_to_exr(scene, tmp_path / "full.exr")["RGBA"]
    assert (full[..., 3] > 0).any() and len(np.unique(full[..., 0])) > 20  # edges to anti-alias
    render = scene.render
    render.use_border, render.use_crop_to_border = True, True
    render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y = 0.3, 0.7, 0.2, 0.7
    region = render_to_exr(scene, tmp_path / "region.exr")["RGBA"]
    x0, x1 = int(np.float32(0.3) * 32), int(np.float32(0.7) * 32)
    bottom, top = int(np.float32(0.2) * 24), int(np.float32(0.7) * 24)
    np.testing.assert_array_equal(region, full[24 - top:24 - bottom, x0:x1])


def test_memory_error_is_reported(scene, monkeypatch):
    simple_scene(scene)

    def render(scene, settings, progress):
        raise MemoryError()

    monkeypatch.setattr(engine_module, "core_render", render)
    with pytest.raises(RuntimeError, match="LazyVis: out of memory"):
        bpy.ops.render.render()


def test_status_line_names_the_slowest_stages():
    """The render's status line after a frame: the total and up to four stages, slowest first."""
    stats = {"seconds": 3.0, "stage_seconds": {"Camera rays": 0.3, "Illumination": 2.5, "Validating scene": 0.001,
                                               "Building BVH": 0.1, "Building edge tree": 0.05, "Composing": 0.02}}
    assert engine_module.done_message(stats) == ("LazyVis | Done in 3.00 s (Illumination 2.50 s, Camera rays "
                                                 "0.30 s, Building BVH 0.10 s, Building edge tree 0.05 s)")
    assert engine_module.done_message({}) == "LazyVis | Done"


# -- material and light previews -----------------------------------------------------------------------

def _generated_preview(data_block, timeout: float = 120.0) -> np.ndarray:
    """Blender's preview of ``data_block`` (a material or a light) rendered through its preview path
    (``ed.lib_id_generate_preview``: a job off the main thread, here too), as (H, W, 4) float32 once it has
    pixels; fails after ``timeout`` seconds."""
    import time
    with bpy.context.temp_override(id=data_block):
        assert bpy.ops.ed.lib_id_generate_preview() == {'FINISHED'}
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        time.sleep(0.1)  # the job's thread renders meanwhile
        width, height = data_block.preview.image_size
        pixels = np.array(data_block.preview.image_pixels_float[:], np.float32)
        if width and pixels.size and pixels.max() > 0:
            return pixels.reshape(height, width, 4)
    raise AssertionError(f"no preview of {data_block.name} within {timeout} s")


def test_material_and_light_previews_are_rendered_by_lazyvis(scene, monkeypatch, reports):
    """Thumbnails come from LazyVis (``is_preview``), at Blender's preview size, in the material's and the
    light's own colours, with fewer anti-aliasing samples and none of the preview scene's warnings."""
    seen = []
    render_frame = engine_module.render_frame

    def recorded(engine, depsgraph, preview=False):
        seen.append((engine.is_preview, preview, engine.resolution_x, engine.resolution_y))
        render_frame(engine, depsgraph, preview=preview)

    monkeypatch.setattr(engine_module, "render_frame", recorded)
    used = []
    core_render = engine_module.core_render
    monkeypatch.setattr(engine_module, "core_render",
                        lambda scene_, settings, progress: used.append(settings) or core_render(scene_, settings, progress))

    red = bpy.data.materials.new("Red")
    red.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.8, 0.02, 0.02, 1.0)
    image = _generated_preview(red)
    assert seen and seen[-1] == (True, True, 128, 128)
    assert image.shape == (128, 128, 4)
    assert used[-1].aa_samples == engine_module.PREVIEW_AA_SAMPLES < Settings().aa_samples
    # The preview's sphere fills its middle: lit, and red there (display values: Cycles' preview has a
    # median red / green of 2.43 there, LazyVis' 2.47), while the background, the preview world's grey, is not.
    middle = image[40:88, 40:88, :3].reshape(-1, 3)
    lit = middle[middle.sum(axis=1) > 0.05]
    assert len(lit) > 0.5 * len(middle)
    assert np.median(lit[:, 0] / np.maximum(lit[:, 1], 1e-6)) > 1.8
    corner = image[:8, :8, :3].reshape(-1, 3)
    assert np.abs(corner[:, 0] - corner[:, 1]).max() < 0.05
    assert reports == []  # the preview scene's world and floor nodes warn in a render, not in a thumbnail

    seen.clear()
    light = bpy.data.lights.new("Green", "AREA")
    light.color = (0.05, 1.0, 0.05)
    image = _generated_preview(light)
    assert seen and seen[-1][:2] == (True, True)
    rgb = image[..., :3].reshape(-1, 3)
    lit = rgb[rgb.sum(axis=1) > 0.05]
    assert len(lit) > 0.1 * len(rgb)
    # The preview's floor under the green light (1.22 measured; a light's colour ignored gives 1).
    assert np.median(lit[:, 1] / np.maximum(lit[:, 0], 1e-6)) > 1.1
