"""The Rendered viewport (issue 19), headless: the view's camera against the F12 camera, which updates
export again, the session's renders against F12's, failures as a message. Drawing needs a GPU context
and is tested only where one exists."""

from __future__ import annotations

import dataclasses
import itertools
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import add_area_light, add_camera, assign, node_material, render_to_exr  # noqa: E402

from lazyvis_addon.blender import viewport  # noqa: E402
from lazyvis_addon.blender.export import export_depsgraph  # noqa: E402
from lazyvis_addon.blender.properties import settings_from_scene  # noqa: E402
from lazyvis_addon.core.camera import camera_rays  # noqa: E402
from lazyvis_addon.core.progressive import ViewportImage, scaled_camera  # noqa: E402
from lazyvis_addon.core.render import render  # noqa: E402


def camera_view(camera, scene, width, height):
    """What a 3D view looking through ``camera`` hands the engine: its view and projection matrices (the
    camera's own, as Blender computes them) and the region's size."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    projection = camera.calc_matrix_camera(depsgraph, x=width, y=height, scale_x=scene.render.pixel_aspect_x,
                                           scale_y=scene.render.pixel_aspect_y)
    return SimpleNamespace(region=SimpleNamespace(width=width, height=height),
                           region_data=SimpleNamespace(view_matrix=camera.matrix_world.inverted(),
                                                       window_matrix=projection),
                           preferences=bpy.context.preferences)


@pytest.mark.parametrize("kind, shift, size", list(itertools.product(
    ["PERSP", "ORTHO"], [(0.0, 0.0), (0.1, -0.2)], [(64, 48), (30, 50)])))
def test_the_view_through_a_camera_is_the_f12_camera(scene, kind, shift, size):
    """Camera rays of the view (from its matrices) and of the exported camera (from lens, sensor and shift)
    agree pixel for pixel, clipping included."""
    camera = add_camera(scene, type=kind, lens=35.0, sensor_width=36.0, ortho_scale=7.0, shift_x=shift[0],
                        shift_y=shift[1], clip_start=0.5, clip_end=40.0)
    scene.render.resolution_x, scene.render.resolution_y = size
    context = camera_view(camera, scene, *size)
    view = viewport.viewport_camera(context.region_data.view_matrix, context.region_data.window_matrix, *size)
    f12 = export_depsgraph(bpy.context.evaluated_depsgraph_get()).scene.camera
    assert (view.width, view.height, view.projection) == (f12.width, f12.height, f12.projection)
    ys, xs = np.mgrid[0:size[1]:7, 0:size[0]:5]
    got_origin, got = camera_rays(view, xs.ravel(), ys.ravel())
    want_origin, want = camera_rays(f12, xs.ravel(), ys.ravel())
    np.testing.assert_allclose(got, want, atol=1e-6)
    np.testing.assert_allclose(got_origin, want_origin, atol=1e-5)
    np.testing.assert_allclose((view.clip_start, view.clip_end), (f12.clip_start, f12.clip_end), rtol=1e-5)


def test_an_orthographic_view_clipping_behind_its_origin_steps_back():
    """Blender's orthographic views clip from -far to far around the view's origin: the camera moves back
    to the near plane, and its rays cover the same span."""
    projection = np.diag([0.2, 0.25, -2.0 / 200.0, 1.0])  # x, y half-widths 5 and 4; z from -100 to 100
    projection[2, 3] = 0.0
    view = viewport.viewport_camera(np.eye(4), projection, 40, 32)
    assert view.projection == "orthographic"
    np.testing.assert_allclose(view.screen_window, (-5.0, 5.0, -4.0, 4.0))
    np.testing.assert_allclose(view.world_from_camera[:3, 3], (0.0, 0.0, 100.0))
    np.testing.assert_allclose((view.clip_start, view.clip_end), (0.0, 200.0))


class FakeUpdate:
    def __init__(self, id_type):
        self.id = SimpleNamespace(id_type=id_type)


@pytest.mark.parametrize("types, export", [
    (["OBJECT"], True), (["MESH"], True), (["MATERIAL"], True), (["LIGHT"], True), (["WORLD"], True),
    (["NODETREE"], True), (["SCENE"], True), (["COLLECTION"], True), (["IMAGE"], True),
    (["SCREEN"], False), (["WORKSPACE", "BRUSH"], False), ([], False), (["TEXT", "OBJECT"], True)])
def test_which_updates_export_the_scene_again(types, export):
    assert viewport.needs_export([FakeUpdate(kind) for kind in types]) is export


def test_a_moved_object_is_an_update_that_exports_again(scene):
    """The depsgraph's own updates after an object moves name it (caught by a depsgraph handler)."""
    bpy.ops.mesh.primitive_cube_add()
    seen = []

    def handler(_scene, depsgraph):
        seen.append(viewport.needs_export(depsgraph.updates))

    bpy.app.handlers.depsgraph_update_post.append(handler)
    try:
        bpy.context.object.location.x += 1.0
        bpy.context.view_layer.update()
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(handler)
    assert seen and seen[-1]


class FakeEngine:
    """The engine's side the viewport functions use, without a window."""

    def __init__(self):
        self.session = viewport.ViewportSession()
        self.stats, self.redraws = [], 0

    def viewport_session(self):
        return self.session

    def update_stats(self, _stats, info):
        self.stats.append(info)

    def tag_redraw(self):
        self.redraws += 1


def lit_scene(scene):
    bpy.ops.mesh.primitive_plane_add(size=6.0)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 1.0))
    add_area_light(location=(0.5, 0.3, 3.0))
    return add_camera(scene)


def test_the_final_viewport_image_through_the_camera_is_the_f12_render(scene, tmp_path):
    """``view_update`` exports, the session renders coarse to fine, and its final image equals the engine's
    F12 render of the scene (through the camera at the render size)."""
    camera = lit_scene(scene)
    engine = FakeEngine()
    context = camera_view(camera, scene, 32, 24)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    viewport.view_update(engine, context, depsgraph)
    session = engine.session
    assert session.message is None and session.scene is not None
    assert session.renderer.wait(600.0)
    final = session.latest
    assert final.final and final.image.shape == (24, 32, 4)
    f12 = render_to_exr(scene, tmp_path / "f12.exr")["RGBA"]
    # The cameras agree to float rounding (above), which can move a pixel's filter samples across an
    # edge: the images agree to the EXR's float32 everywhere else.
    close = np.isclose(final.image, f12, rtol=1e-4, atol=1e-5).all(axis=-1)
    assert close.mean() > 0.99, f"{(~close).sum()} of {close.size} pixels differ"
    assert np.abs(final.image - f12).mean() < 1e-4 * np.abs(f12).mean()


def test_the_viewport_pixel_size_sets_the_finest_step(scene):
    """Render Properties > Performance > Viewport > Pixel Size: with 2 the steps stop at 1/2 and the final
    image is the render at half the region's size (each pixel over 2 x 2 region pixels); a change of it
    restarts the render; Automatic follows the interface's pixel size."""
    camera = lit_scene(scene)
    engine = FakeEngine()
    session = engine.session
    context = camera_view(camera, scene, 32, 24)
    scene.render.preview_pixel_size = '2'
    assert viewport.viewport_pixel_size(context, scene) == 2
    viewport.view_update(engine, context, bpy.context.evaluated_depsgraph_get())
    assert session.renderer.wait(600.0) and session.message is None
    final = session.latest
    assert final.final and final.divisor == 2 and final.image.shape == (12, 16, 4)
    want = render(dataclasses.replace(session.scene, camera=scaled_camera(session.camera, 2)), session.settings)
    np.testing.assert_array_equal(final.image, want.combined)
    generation = session.renderer.generation
    scene.render.preview_pixel_size = '1'
    session.view(session.camera, settings_from_scene(scene), viewport.viewport_pixel_size(context, scene))
    assert session.renderer.generation == generation + 1
    assert session.renderer.wait(600.0) and session.latest.divisor == 1 and session.latest.final
    scene.render.preview_pixel_size = 'AUTO'
    assert viewport.viewport_pixel_size(context, scene) == max(1, round(bpy.context.preferences.system.pixel_size))


def test_a_new_view_renders_again_and_the_same_view_does_not(scene):
    camera = lit_scene(scene)
    engine = FakeEngine()
    session = engine.session
    depsgraph = bpy.context.evaluated_depsgraph_get()
    viewport.view_update(engine, camera_view(camera, scene, 32, 24), depsgraph)
    first = session.renderer.generation
    same = viewport.viewport_camera(camera.matrix_world.inverted(), camera_view(camera, scene, 32, 24)
                                    .region_data.window_matrix, 32, 24)
    session.view(same, settings_from_scene(scene))
    assert session.renderer.generation == first
    camera.location.x += 0.5
    bpy.context.view_layer.update()  # matrix_world follows
    session.view(viewport.viewport_camera(camera.matrix_world.inverted(), camera_view(camera, scene, 32, 24)
                                          .region_data.window_matrix, 32, 24), settings_from_scene(scene))
    assert session.renderer.generation == first + 1
    assert session.renderer.wait(600.0) and session.latest.generation == first + 1
    # A render setting changed in the panel restarts it too.
    scene.lazyvis.aa_samples = 1
    session.view(session.camera, settings_from_scene(scene))
    assert session.renderer.generation == first + 2
    assert session.renderer.wait(600.0)


def test_a_new_export_after_a_change_of_lights_or_materials_keeps_the_ray_tracer(scene):
    """The session's restarts after the scene is exported again: a light's strength keeps the ray tracer
    (equal triangles) and the edge tree (lights of the same shapes), its size the ray tracer only, a
    material's change also the light frames and edge tree, a moved object builds them again; each final
    image is a plain render of the new export, and stopping the session lets go of them."""
    camera = lit_scene(scene)
    paint = node_material("Paint", "ShaderNodeBsdfDiffuse", Color=(0.8, 0.8, 0.8))
    assign(bpy.data.objects["Plane"], paint)
    engine = FakeEngine()
    session = engine.session
    viewport.view_update(engine, camera_view(camera, scene, 32, 24), bpy.context.evaluated_depsgraph_get())
    assert session.renderer.wait(600.0) and session.message is None
    first = session.renderer.prepared

    def exported_after(change):
        change()
        exported = export_depsgraph(bpy.context.evaluated_depsgraph_get(), camera=session.camera,
                                    disk_vertices=scene.lazyvis.disk_vertices)
        session.exported(exported.scene, settings_from_scene(scene))
        assert session.renderer.wait(600.0) and session.message is None and session.latest.final
        plain = render(dataclasses.replace(session.scene, camera=session.camera), session.settings)
        np.testing.assert_array_equal(session.latest.image, plain.combined)
        return session.renderer.prepared

    light = next(obj for obj in scene.objects if obj.type == "LIGHT").data
    lit = exported_after(lambda: setattr(light, "energy", light.energy * 2.0))
    assert lit.reused == ("tracer", "edge tree") and lit.tracer is first.tracer and first.closed
    assert lit.edges is first.edges and lit.frames is not first.frames
    grown = exported_after(lambda: setattr(light, "size", light.size * 1.5))
    assert grown.reused == ("tracer",) and grown.tracer is first.tracer and grown.edges is not first.edges
    colour = paint.node_tree.nodes["Diffuse BSDF"].inputs["Color"]
    painted = exported_after(lambda: setattr(colour, "default_value", (0.2, 0.5, 0.8, 1.0)))
    assert painted.reused == ("tracer", "lights") and painted.edges is grown.edges
    cube = bpy.data.objects["Cube"]
    moved = exported_after(lambda: setattr(cube, "location", (0.4, 0.0, 1.0)))
    assert moved.reused == () and moved.tracer is not lit.tracer
    session.stop()
    assert moved.closed and session.renderer.prepared is None


def test_an_export_failure_is_the_viewports_message_not_a_traceback(scene):
    camera = lit_scene(scene)
    bpy.data.objects["Cube"].location.x = float("nan")
    engine = FakeEngine()
    viewport.view_update(engine, camera_view(camera, scene, 32, 24), bpy.context.evaluated_depsgraph_get())
    assert engine.session.message and "NaN" in engine.session.message
    assert engine.session.latest is None


def test_display_rows_are_bottom_up():
    image = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)
    rows = viewport.display_rows(ViewportImage(image, 1, (0, 0, 3, 2), True, 1, 0.0))
    np.testing.assert_array_equal(rows.reshape(2, 3, 4), image[::-1])


def test_drawing_needs_a_gpu_context_and_draws_where_there_is_one(scene):
    gpu = pytest.importorskip("gpu")
    try:
        gpu.types.GPUTexture((1, 1), format="RGBA16F")
    except Exception as error:  # headless bpy: no GPU context
        pytest.skip(f"no GPU context here ({error})")
    calls = []
    engine = SimpleNamespace(bind_display_space_shader=lambda s: calls.append("bind"),
                             unbind_display_space_shader=lambda: calls.append("unbind"))
    session = viewport.ViewportSession()
    image = ViewportImage(np.ones((3, 4, 4), np.float32), 8, (0, 0, 4, 3), False, 1, 0.0)
    viewport.draw_image(engine, SimpleNamespace(scene=scene), image, 20, session)
    assert calls == ["bind", "unbind"] and session.texture[0] == (1, 8, False)


def test_the_views_render_region_is_the_window_rendered(scene):
    """View > Render Region outside the camera view: the fractions of the region, rows from the top."""
    context = SimpleNamespace(region=SimpleNamespace(width=40, height=30),
                              region_data=SimpleNamespace(view_perspective="PERSP"),
                              space_data=SimpleNamespace(use_render_border=True, render_border_min_x=0.25,
                                                         render_border_max_x=0.5, render_border_min_y=0.0,
                                                         render_border_max_y=0.4))
    assert viewport.render_region(context, scene) == (10, 18, 20, 30)
    context.space_data.use_render_border = False
    assert viewport.render_region(context, scene) is None
    context.space_data.use_render_border = True
    context.space_data.render_border_min_x = context.space_data.render_border_max_x = 0.5
    with pytest.raises(ValueError, match="render region"):
        viewport.render_region(context, scene)


def test_in_the_camera_view_the_scenes_render_border_is_the_window_rendered(scene):
    """Through the camera (the region showing exactly its frame), the scene's render border gives the
    F12 border's pixels, to the rounding of the frame's projected corners (a pixel at most)."""
    from lazyvis_addon.tiles import border_window

    camera = add_camera(scene, lens=35.0)
    scene.render.resolution_x, scene.render.resolution_y = 64, 48
    scene.render.use_border = True
    fractions = (0.2, 0.7, 0.1, 0.6)
    scene.render.border_min_x, scene.render.border_max_x, scene.render.border_min_y, \
        scene.render.border_max_y = fractions
    context = camera_view(camera, scene, 64, 48)
    context.region_data.view_perspective = "CAMERA"
    got = np.array(viewport.render_region(context, scene))
    want = np.array(border_window(64, 48, fractions))
    assert np.abs(got - want).max() <= 1
    # The session renders that window: its image covers those pixels.
    camera_core = viewport._region_camera(context, scene)
    assert camera_core.window == tuple(got)


def test_a_coarse_image_is_drawn_over_its_block_of_region_pixels():
    """Rows count down from the region's top in the image's window, up from the bottom in Blender's."""
    image = ViewportImage(np.zeros((3, 3, 4), np.float32), 4, (2, 1, 5, 4), False, 1, 0.0)
    assert viewport.image_rectangle(image, 20) == (8, 4, 12, 12)
    whole = ViewportImage(np.zeros((3, 4, 4), np.float32), 8, (0, 0, 4, 3), False, 1, 0.0)
    assert viewport.image_rectangle(whole, 20) == (0, -4, 32, 24)  # reaches past the right and bottom edges
