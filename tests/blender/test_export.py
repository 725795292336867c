"""The exporter against Blender's own numbers: camera frames, light areas and radiance, triangle and
instance counts, materials, visibility and bad input."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import (add_area_light, add_camera, add_light, assign, cycles_reference_tool,  # noqa: E402
                             node_material, render_to_exr)

from lazyvis_addon.core.scene import FACING_DISK, FACING_SPHERE, FACING_SUN  # noqa: E402
from lazyvis_addon.blender.export import (  # noqa: E402
    DEFAULT_ALBEDO, border_window, ellipse_polygon, export_depsgraph, polygon_area_normal, read_material,
    screen_window)
from lazyvis_addon.core.progress import Progress  # noqa: E402
from lazyvis_addon.core.scene import Scene  # noqa: E402


def export(scene, **options):
    """Export the scene's viewport depsgraph; returns (Export, warnings)."""
    progress = Progress()
    result = export_depsgraph(bpy.context.evaluated_depsgraph_get(), progress, **options)
    return result, progress.warnings


def triangle_count(obj):
    mesh = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
    mesh.calc_loop_triangles()
    count = len(mesh.loop_triangles)
    obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh_clear()
    return count


# -- camera --------------------------------------------------------------------------------------------


def view_frame_window(camera, scene):
    """(left, right, bottom, top) from Blender's Camera.view_frame (at z = -1 for perspective)."""
    corners = np.array([tuple(v) for v in camera.data.view_frame(scene=scene)])
    xy = corners[:, :2] / -corners[:, 2:3] if camera.data.type == "PERSP" else corners[:, :2]
    return np.array([xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max()])


CAMERA_CASES = list(itertools.product(
    ["PERSP", "ORTHO"], ["AUTO", "HORIZONTAL", "VERTICAL"], [(64, 48), (30, 50)], [(1.0, 1.0), (2.0, 1.0)],
    [(0.0, 0.0), (0.1, -0.25)], [100, 50]))


@pytest.mark.parametrize("kind, fit, size, aspect, shift, percentage", CAMERA_CASES)
def test_camera_screen_window_matches_view_frame(scene, kind, fit, size, aspect, shift, percentage):
    camera = add_camera(scene, type=kind, sensor_fit=fit, lens=35.0, sensor_width=36.0, sensor_height=20.0,
                        ortho_scale=7.0, shift_x=shift[0], shift_y=shift[1])
    render = scene.render
    render.resolution_x, render.resolution_y = size
    render.pixel_aspect_x, render.pixel_aspect_y = aspect
    render.resolution_percentage = percentage
    exported, _ = export(scene)
    core_camera = exported.scene.camera
    assert (core_camera.width, core_camera.height) == (size[0] * percentage // 100, size[1] * percentage // 100)
    assert core_camera.projection == ("orthographic" if kind == "ORTHO" else "perspective")
    np.testing.assert_allclose(core_camera.screen_window, view_frame_window(camera, scene), atol=2e-6)


def test_camera_transform_is_the_camera_matrix_without_scale(scene):
    camera = add_camera(scene, location=(1.0, -2.0, 3.0), rotation=(0.4, 0.2, -0.3))
    camera.scale = (2.0, 3.0, 0.5)
    exported, _ = export(scene)
    matrix = exported.scene.camera.world_from_camera
    expected = np.array(camera.matrix_world.normalized())
    np.testing.assert_allclose(matrix[:3, :3], expected[:3, :3], atol=1e-6)
    np.testing.assert_allclose(matrix[:3, 3], (1.0, -2.0, 3.0), atol=1e-6)


def test_camera_sees_along_minus_z_with_y_up(scene):
    """The centre ray of the exported camera points where Blender's camera looks."""
    add_camera(scene, location=(0.0, 0.0, 5.0), rotation=(0.0, 0.0, 0.0))
    exported, _ = export(scene)
    from lazyvis_addon.core.camera import camera_rays
    camera = exported.scene.camera
    origins, directions = camera_rays(camera, np.array([16]), np.array([0]))  # top row, middle column
    assert directions[0, 2] < 0 and directions[0, 1] > 0  # down, and towards the top of the image (+Y)


@pytest.mark.parametrize("border", [(0.25, 0.75, 0.0, 0.5), (0.1, 0.3, 0.6, 0.95), (0.0, 1.0, 0.0, 1.0)])
def test_border_window_counts_rows_from_the_top(scene, border):
    add_camera(scene)
    render = scene.render
    render.use_border = True
    render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y = border
    exported, _ = export(scene)
    x0, y0, x1, y1 = exported.scene.camera.window
    width, height = 32, 24
    assert (x0, x1) == (int(np.float32(border[0]) * width), int(np.float32(border[1]) * width))
    # Blender's border y is measured up from the bottom row.
    assert (height - y1, height - y0) == (int(np.float32(border[2]) * height), int(np.float32(border[3]) * height))


def test_border_window_too_small_is_a_clear_error():
    with pytest.raises(ValueError, match="render border selects no pixels"):
        border_window(10, 10, (0.5, 0.52, 0.0, 1.0))


def test_screen_window_auto_fit_is_the_core_camera_convention():
    """AUTO fit agrees with the core's own Camera.perspective (fov over the longer side)."""
    from lazyvis_addon.core.scene import Camera
    for width, height in ((64, 48), (30, 50)):
        window = screen_window("perspective", 50.0, 36.0, 24.0, "AUTO", 1.0, 0.1, 0.2, width, height)
        fov = 2.0 * math.atan(18.0 / 50.0)
        np.testing.assert_allclose(window, Camera.perspective(np.eye(4), width, height, fov, (0.1, 0.2)).screen_window)


def test_no_camera_is_a_clear_error(scene):
    with pytest.raises(ValueError, match="no camera"):
        export(scene)


# -- lights --------------------------------------------------------------------------------------------


def true_area(shape, size_x, size_y):
    """Area of the light's true shape with world-space side lengths / diameters size_x, size_y."""
    return size_x * size_y * (math.pi / 4 if shape in ("DISK", "ELLIPSE") else 1.0)


@pytest.mark.parametrize("shape", ["SQUARE", "RECTANGLE", "DISK", "ELLIPSE"])
@pytest.mark.parametrize("normalize", [True, False])
def test_area_light_polygon_area_and_radiance(scene, shape, normalize):
    add_camera(scene)
    scale = (1.5, 0.5, 2.0)
    light = add_area_light(location=(0.3, -0.2, 2.0), rotation=(0.3, -0.4, 0.9), scale=scale, shape=shape,
                           size=0.8, size_y=0.3, energy=40.0, color=(1.0, 0.5, 0.25), exposure=0.7,
                           normalize=normalize)
    exported, warnings = export(scene, disk_vertices=24)
    lights = exported.scene.lights
    assert len(lights) == 1 and not lights.two_sided[0]
    count = int(lights.vertex_count[0])
    assert count == (4 if shape in ("SQUARE", "RECTANGLE") else 24)
    polygon = lights.vertices[0, :count]
    area, newell = polygon_area_normal(polygon)
    square_like = shape in ("SQUARE", "DISK")
    expected_area = true_area(shape, 0.8 * scale[0], (0.8 if square_like else 0.3) * scale[1])
    assert area == pytest.approx(expected_area, rel=1e-6)
    power = 40.0 * 2.0 ** 0.7 / math.pi
    expected = np.array([1.0, 0.5, 0.25]) * power / (expected_area if normalize else 1.0)
    np.testing.assert_allclose(lights.radiance[0], expected, rtol=1e-6)
    # Counter-clockwise about the emitting normal, which is the light's local -Z.
    emit = -np.array(light.matrix_world.to_3x3().col[2])
    assert np.dot(newell, emit) > 0
    np.testing.assert_allclose(polygon.mean(axis=0), (0.3, -0.2, 2.0), atol=1e-6)
    assert not warnings


def test_area_light_vertices_are_counter_clockwise_for_the_core():
    """Lights.vertices order: normalize((v1 - v0) x (v2 - v0)) is the emitting normal (local -Z)."""
    polygon = ellipse_polygon(1.0, 0.5, 8)
    normal = np.cross(polygon[1] - polygon[0], polygon[2] - polygon[0])
    assert normal[2] < 0
    assert polygon_area_normal(polygon)[0] == pytest.approx(math.pi / 4 * 0.5)


def test_mirrored_area_light_still_emits_to_local_minus_z(scene):
    add_camera(scene)
    light = add_area_light(location=(0.0, 0.0, 2.0), scale=(-1.0, 1.0, 1.0), size=1.0, energy=10.0)
    exported, _ = export(scene)
    lights = exported.scene.lights
    polygon = lights.vertices[0, :4]
    normal = np.cross(polygon[1] - polygon[0], polygon[2] - polygon[0])
    assert np.dot(normal, -np.array(light.matrix_world.to_3x3().col[2])) > 0


def test_light_temperature_tints_the_colour(scene):
    add_camera(scene)
    light = add_area_light(size=1.0, energy=10.0, color=(1.0, 1.0, 1.0), use_temperature=True, temperature=3000)
    exported, _ = export(scene)
    expected = np.array(light.data.temperature_color[:3]) * 10.0 / math.pi
    np.testing.assert_allclose(exported.scene.lights.radiance[0], expected, rtol=1e-6)


def test_light_spread_is_exported(scene):
    add_camera(scene)
    add_area_light(name="Narrow", size=1.0, energy=10.0, spread=math.radians(60))
    add_area_light(name="Wide", size=1.0, energy=10.0)
    exported, warnings = export(scene)
    np.testing.assert_allclose(exported.scene.lights.spread, [math.radians(60), math.pi], rtol=1e-6)
    assert not any("spread" in w for w in warnings)


def test_point_spot_sun_lights_are_exported_as_cycles_renders_them(scene):
    """Intensity P / (4 pi) for lamps (a spot the same lamp with its cone), Strength as a sun's irradiance,
    Soft Falloff choosing the disk or the sphere, directions from the object's -Z (README light table)."""
    add_camera(scene)
    made = {}
    for kind in ("POINT", "SPOT", "SUN"):
        bpy.ops.object.light_add(type=kind, location=(1.0, 2.0, 3.0), rotation=(0.3, -0.2, 0.5))
        obj = bpy.context.object
        obj.name = f"My{kind.title()}"
        obj.data.energy = {"POINT": 100.0, "SPOT": 50.0, "SUN": 3.0}[kind]
        obj.data.color = (1.0, 0.5, 0.25)
        made[kind] = obj
    made["POINT"].data.shadow_soft_size = 0.3
    made["SPOT"].data.shadow_soft_size = 0.1
    made["SPOT"].data.use_soft_falloff = False
    made["SPOT"].data.spot_size = math.radians(45.0)
    made["SPOT"].data.spot_blend = 0.2
    made["SUN"].data.angle = math.radians(5.0)
    bpy.context.view_layer.update()
    exported, warnings = export(scene)
    facing = exported.scene.facing
    assert len(exported.scene.lights) == 0 and len(facing) == 3
    assert exported.light_names == ["MyPoint", "MySpot", "MySun"]
    colour = np.array([1.0, 0.5, 0.25])
    point, spot, sun = 0, 1, 2
    np.testing.assert_array_equal(facing.kind, [FACING_DISK, FACING_SPHERE, FACING_SUN])
    np.testing.assert_allclose(facing.centre[point], (1.0, 2.0, 3.0), atol=1e-6)
    np.testing.assert_allclose(facing.radius, [0.3, 0.1, math.radians(2.5)], rtol=1e-6)
    np.testing.assert_allclose(facing.intensity[point], colour * 100.0 / (4 * math.pi), rtol=1e-6)
    np.testing.assert_allclose(facing.intensity[spot], colour * 50.0 / (4 * math.pi), rtol=1e-6)
    np.testing.assert_allclose(facing.intensity[sun], colour * 3.0, rtol=1e-6)
    matrix = np.array(made["SUN"].matrix_world)
    np.testing.assert_allclose(facing.centre[sun] / np.linalg.norm(facing.centre[sun]), matrix[:3, 2], atol=1e-6)
    cos_half = math.cos(math.radians(22.5))
    np.testing.assert_allclose(facing.spot_cos_half[spot], cos_half, rtol=1e-6)
    np.testing.assert_allclose(facing.spot_smooth[spot], 0.2 * (1 - cos_half), rtol=1e-5)
    # The spot's axis, its local -Z, has cos 1 in its frame.
    axis = -np.array(made["SPOT"].matrix_world)[:3, 2]
    local = facing.spot_frame[spot] @ axis
    assert -local[2] / np.linalg.norm(local) > 1 - 1e-9
    assert facing.spot_cos_half[point] < -1 and facing.spot_cos_half[sun] < -1
    assert not any("ignored" in w and "MyPoint" in w for w in warnings)


@pytest.mark.parametrize("kind", ["AREA", "POINT"])
def test_light_node_strength_and_colour_multiply_the_light(scene, kind):
    """Cycles 5.0 multiplies a light by its node tree's Emission Color x Strength (measured: strength 3,
    colour (1, 0.5, 0.25) on a point lamp gave exactly those factors)."""
    add_camera(scene)
    bpy.ops.object.light_add(type=kind)
    light = bpy.context.object.data
    light.energy, light.shadow_soft_size = 10.0, 0.1
    plain, _ = export(scene)
    light.use_nodes = True
    emission = next(n for n in light.node_tree.nodes if n.bl_idname == "ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 3.0
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    noded, warnings = export(scene)
    before = plain.scene.lights.radiance[0] if kind == "AREA" else plain.scene.facing.intensity[0]
    after = noded.scene.lights.radiance[0] if kind == "AREA" else noded.scene.facing.intensity[0]
    np.testing.assert_allclose(after, before * 3.0 * np.array([1.0, 0.5, 0.25]), rtol=1e-6)
    assert not any("node" in w for w in warnings)


def test_lights_of_unknown_use_warn(scene):
    add_camera(scene)
    bpy.ops.object.light_add(type="POINT")
    bpy.context.object.name = "Dark"
    bpy.context.object.data.energy = 0.0
    exported, warnings = export(scene)
    assert len(exported.scene.facing) == 0
    assert any("zero or negative power" in w and "Dark" in w for w in warnings)


def test_zero_size_light_warns_and_is_skipped(scene):
    add_camera(scene)
    add_area_light(name="Flat", size=1.0, energy=10.0, scale=(1.0, 0.0, 1.0))
    add_area_light(name="Good", size=1.0, energy=10.0)
    exported, warnings = export(scene)
    assert exported.light_names == ["Good"]
    assert any("zero size" in w and "Flat" in w for w in warnings)


def test_instanced_lights_are_all_exported(scene):
    add_camera(scene)
    light = add_area_light(size=0.5, energy=5.0)
    collection = bpy.data.collections.new("Lamps")
    collection.objects.link(light)
    scene.collection.objects.unlink(light)
    for x in (-2.0, 2.0):
        bpy.ops.object.collection_instance_add(collection="Lamps", location=(x, 0.0, 0.0))
    exported, _ = export(scene)
    centres = sorted(exported.scene.lights.vertices[:, :4].mean(axis=1)[:, 0])
    np.testing.assert_allclose(centres, [-2.0, 2.0], atol=1e-6)


# -- geometry ------------------------------------------------------------------------------------------


def test_triangle_counts_match_loop_triangles_with_modifiers(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    cube.modifiers.new("sub", "SUBSURF").levels = 1
    bpy.ops.mesh.primitive_cylinder_add(vertices=7, location=(3.0, 0.0, 0.0))  # n-gon caps
    cylinder = bpy.context.object
    exported, _ = export(scene)
    assert len(exported.scene.triangles) == triangle_count(cube) + triangle_count(cylinder)
    assert exported.counts["objects"] == 2 and exported.counts["instances"] == 0


def test_world_coordinates_match_blender(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(1.0, 2.0, 3.0), rotation=(0.3, 0.2, 0.1))
    plane = bpy.context.object
    plane.scale = (2.0, 1.0, 1.0)
    exported, _ = export(scene)
    expected = np.array([tuple(plane.matrix_world @ v.co) for v in plane.data.vertices])
    got = exported.scene.triangles.reshape(-1, 3)
    # Every exported corner is one of Blender's world-space vertices.
    distance = np.linalg.norm(got[:, None, :] - expected[None, :, :], axis=2).min(axis=1)
    assert distance.max() < 1e-6


def test_curves_text_metaballs_counted_once(scene):
    """Blender 5 hands their evaluated meshes over as instances; each triangle must appear once."""
    add_camera(scene)
    bpy.ops.curve.primitive_bezier_curve_add()
    curve = bpy.context.object
    curve.data.bevel_depth = 0.1
    bpy.ops.object.text_add(location=(0.0, 3.0, 0.0))
    text = bpy.context.object
    bpy.ops.object.metaball_add(location=(0.0, 6.0, 0.0))
    ball = bpy.context.object
    expected = sum(triangle_count(obj) for obj in (curve, text, ball))
    assert expected > 0
    exported, _ = export(scene)
    assert len(exported.scene.triangles) == expected


def test_instances_are_counted_and_placed(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    cube = bpy.context.object
    collection = bpy.data.collections.new("Kit")
    collection.objects.link(cube)
    scene.collection.objects.unlink(cube)
    for z in (10.0, 20.0, 30.0):
        bpy.ops.object.collection_instance_add(collection="Kit", location=(0.0, 0.0, z))
    exported, _ = export(scene)
    assert exported.counts["instances"] == 3
    assert len(exported.scene.triangles) == 3 * 12
    centres = np.sort(np.unique(np.round(exported.scene.triangles[:, :, 2].mean(axis=1) / 10.0)))
    np.testing.assert_array_equal(centres, [1.0, 2.0, 3.0])


def test_face_instancing_with_hidden_instancer(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1)
    ico = bpy.context.object
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=2, y_subdivisions=2, size=4.0, location=(0, 0, -5))
    grid = bpy.context.object
    grid.instance_type = "FACES"
    grid.show_instancer_for_render = grid.show_instancer_for_viewport = False  # tests read a viewport depsgraph
    ico.parent = grid
    exported, _ = export(scene)
    # Four faces -> four instanced icospheres of 20 triangles; the grid itself is not rendered, and
    # Blender still shows the child icosphere itself (measured: show_self is True for it).
    assert exported.counts["instances"] == 4
    assert exported.counts["objects"] == 1
    assert len(exported.scene.triangles) == 5 * 20


def test_hide_render_is_honoured(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    bpy.ops.mesh.primitive_plane_add(location=(3.0, 0.0, 0.0))
    bpy.context.object.hide_render = True
    exported, _ = export(scene)
    assert len(exported.scene.triangles) == 12


def test_smooth_normals_only_for_smooth_faces(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=8, ring_count=4, location=(0.0, 0.0, 0.0))
    sphere = bpy.context.object
    bpy.ops.object.shade_smooth()
    sphere.rotation_euler = (0.3, 0.0, 0.5)
    sphere.scale = (1.0, 2.0, 1.0)
    bpy.ops.mesh.primitive_cube_add(location=(4.0, 0.0, 0.0))  # flat
    exported, _ = export(scene)
    triangles, normals = exported.scene.triangles, exported.scene.shading_normals
    assert normals is not None and normals.shape == triangles.shape
    np.testing.assert_allclose(np.linalg.norm(normals, axis=2), 1.0, atol=1e-6)
    centre = triangles.mean(axis=1)
    on_sphere = np.linalg.norm(centre, axis=1) < 3.0
    geometric = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    geometric /= np.linalg.norm(geometric, axis=1, keepdims=True)
    # Cube: flat, the shading normal is the geometric normal at all three corners.
    np.testing.assert_allclose(normals[~on_sphere], np.repeat(geometric[~on_sphere, None], 3, axis=1), atol=1e-6)
    # Sphere: corner normals of a smooth ellipsoid differ between corners and point outwards (M^-T n).
    assert np.abs(normals[on_sphere] - geometric[on_sphere, None]).max() > 0.05
    outward = np.einsum("tck,tck->tc", normals[on_sphere], triangles[on_sphere])
    assert (outward > 0).all()
    assert (np.einsum("tk,tck->tc", geometric[on_sphere], normals[on_sphere]) > 0).all()


def test_negative_scale_keeps_normals_and_winding_consistent(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=8, ring_count=4)
    bpy.ops.object.shade_smooth()
    bpy.context.object.scale = (-1.0, 1.0, 1.0)
    exported, _ = export(scene)
    triangles, normals = exported.scene.triangles, exported.scene.shading_normals
    geometric = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    assert (np.einsum("tk,tck->tc", geometric, normals) > 0).all()
    assert (np.einsum("tck,tck->tc", normals, triangles) > 0).all()  # still outward


def test_no_smooth_faces_means_no_shading_normals(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    exported, _ = export(scene)
    assert exported.scene.shading_normals is None



def test_shadow_terminator_geometry_offset_is_read_per_object(scene):
    """Each smooth object's Shadow Terminator Geometry Offset (Blender's default 0.1) on its triangles,
    0 on a flat object's (Cycles lifts only smooth-shaded faces); a Shading Offset is named as ignored."""
    add_camera(scene)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=8, ring_count=4, location=(0.0, 0.0, 0.0))
    bpy.ops.object.shade_smooth()
    default_sphere = bpy.context.object
    bpy.ops.mesh.primitive_uv_sphere_add(segments=8, ring_count=4, location=(4.0, 0.0, 0.0))
    bpy.ops.object.shade_smooth()
    bpy.context.object.shadow_terminator_geometry_offset = 0.35
    bpy.context.object.shadow_terminator_shading_offset = 0.2
    bpy.context.object.name = "Shifted"
    bpy.ops.mesh.primitive_cube_add(location=(-4.0, 0.0, 0.0))
    bpy.context.object.shadow_terminator_geometry_offset = 0.5  # flat: no lift whatever it says
    exported, warnings = export(scene)
    assert default_sphere.shadow_terminator_geometry_offset == pytest.approx(0.1)
    centre_x = exported.scene.triangles.mean(axis=1)[:, 0]
    offset = exported.scene.terminator_offset
    np.testing.assert_allclose(offset[np.abs(centre_x) < 2], 0.1, rtol=1e-6)
    np.testing.assert_allclose(offset[centre_x > 2], 0.35, rtol=1e-6)
    np.testing.assert_array_equal(offset[centre_x < -2], 0.0)
    assert [w for w in warnings if "Shading Offset" in w and "Shifted" in w]

def test_nan_vertex_is_a_clear_error_naming_the_object(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    cube.name = "Broken"
    cube.data.vertices[0].co = (float("nan"), 0.0, 0.0)
    with pytest.raises(ValueError, match="'Broken' has NaN or infinite vertex coordinates"):
        export(scene)


# -- materials -----------------------------------------------------------------------------------------


def test_material_table_and_slots(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    red = node_material("Red", Color=(0.8, 0.1, 0.1))
    blue = node_material("Blue", "ShaderNodeBsdfPrincipled", Base_Color=(0.1, 0.1, 0.9), Specular_IOR_Level=0.0)
    assign(cube, red, blue)
    cube.data.polygons[0].material_index = 1
    cube.data.polygons[1].material_index = 1
    bpy.ops.mesh.primitive_plane_add(location=(0.0, 0.0, -2.0))  # no material
    exported, warnings = export(scene)
    table = {m.name: i for i, m in enumerate(exported.materials)}
    albedo = exported.scene.materials.albedo
    np.testing.assert_allclose(albedo[table["Red"]], (0.8, 0.1, 0.1), rtol=1e-6)
    np.testing.assert_allclose(albedo[table["Blue"]], (0.1, 0.1, 0.9), rtol=1e-6)
    np.testing.assert_allclose(albedo[table["(no material)"]], DEFAULT_ALBEDO)
    counts = np.bincount(exported.scene.material_index, minlength=len(table))
    assert counts[table["Blue"]] == 4 and counts[table["Red"]] == 8 and counts[table["(no material)"]] == 2
    assert exported.materials[table["Blue"]].specular_ior_level == 0.0
    assert not warnings


def material_row(exported, name):
    """{field: value} of the named material's row of the exported material table."""
    row = [m.name for m in exported.materials].index(name)
    return {field: value[row] for field, value in exported.scene.materials.arrays().items()}


@pytest.mark.parametrize("distribution, multiscatter", [("MULTI_GGX", True), ("GGX", False)])
def test_principled_inputs_land_in_their_material_fields(scene, distribution, multiscatter):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    material = node_material("Copper", "ShaderNodeBsdfPrincipled", Base_Color=(0.9, 0.5, 0.3), Metallic=0.7,
                             Roughness=0.3, IOR=1.45, Specular_IOR_Level=0.25, Specular_Tint=(0.9, 0.6, 0.2))
    next(n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled").distribution = distribution
    assign(bpy.context.object, material)
    exported, warnings = export(scene)
    row = material_row(exported, "Copper")
    np.testing.assert_allclose(row["albedo"], (0.9, 0.5, 0.3), rtol=1e-6)
    np.testing.assert_allclose(row["specular_tint"], (0.9, 0.6, 0.2), rtol=1e-6)
    np.testing.assert_allclose([row["metallic"], row["roughness"], row["ior"], row["specular_level"],
                                row["diffuse_weight"]], [0.7, 0.3, 1.45, 0.25, 1.0], rtol=1e-6)
    assert row["principled"] and row["multiscatter"] == multiscatter
    np.testing.assert_array_equal(row["glossy_colour"], 0.0)
    assert row["texture_index"] == -1
    assert not warnings  # a plain Principled BSDF is rendered as it is: nothing to warn about


def test_principled_defaults_are_cycles_defaults(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    assign(bpy.context.object, node_material("Plastic", "ShaderNodeBsdfPrincipled"))
    exported, _ = export(scene)
    record = exported.materials[0]
    assert (record.metallic, record.roughness, record.specular_ior_level, record.ior) == \
        pytest.approx((0.0, 0.5, 0.5, 1.5))
    assert record.principled and record.multiscatter and record.specular_tint == (1.0, 1.0, 1.0)


@pytest.mark.parametrize("distribution, multiscatter, warned", [
    ("MULTI_GGX", True, False), ("GGX", False, False), ("BECKMANN", False, True), ("ASHIKHMIN_SHIRLEY", False, True)])
def test_glossy_bsdf(scene, distribution, multiscatter, warned):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    material = node_material("Mirror", "ShaderNodeBsdfGlossy", Color=(0.9, 0.6, 0.3), Roughness=0.2)
    node = next(n for n in material.node_tree.nodes if n.bl_idname != "ShaderNodeOutputMaterial")
    assert node.bl_idname == "ShaderNodeBsdfAnisotropic"  # Blender 4+: the Glossy BSDF's own id
    node.distribution = distribution
    assign(bpy.context.object, material)
    exported, warnings = export(scene)
    row = material_row(exported, "Mirror")
    np.testing.assert_allclose(row["glossy_colour"], (0.9, 0.6, 0.3), rtol=1e-6)
    assert row["diffuse_weight"] == 0.0 and not row["principled"]
    assert row["roughness"] == pytest.approx(0.2) and row["multiscatter"] == multiscatter
    assert exported.scene.materials.glossy[0]
    assert any("Beckmann" in w and "Mirror" in w for w in warnings) == warned
    assert len(warnings) == int(warned)


def mix_material(name, fac, glossy_first=False, diffuse_colour=(0.2, 0.4, 0.6), glossy_colour=(1.0, 0.8, 0.5)):
    """Mix Shader of a Diffuse and a Glossy BSDF (GGX, roughness 0.25) with a constant factor."""
    material = node_material(name, "ShaderNodeMixShader", Fac=fac)
    tree = material.node_tree
    mix = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeMixShader")
    diffuse, glossy = tree.nodes.new("ShaderNodeBsdfDiffuse"), tree.nodes.new("ShaderNodeBsdfGlossy")
    diffuse.inputs["Color"].default_value = (*diffuse_colour, 1.0)
    glossy.inputs["Color"].default_value = (*glossy_colour, 1.0)
    glossy.inputs["Roughness"].default_value = 0.25
    glossy.distribution = "GGX"
    first, second = (glossy, diffuse) if glossy_first else (diffuse, glossy)
    tree.links.new(first.outputs[0], mix.inputs[1])
    tree.links.new(second.outputs[0], mix.inputs[2])
    return material


@pytest.mark.parametrize("glossy_first", [False, True])
@pytest.mark.parametrize("fac", [0.3, 1.5])
def test_mix_of_diffuse_and_glossy_weights_both_closures(scene, glossy_first, fac):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    assign(bpy.context.object, mix_material("Varnish", fac, glossy_first))
    exported, warnings = export(scene)
    row = material_row(exported, "Varnish")
    clamped = min(fac, 1.0)  # Cycles clamps the factor to [0, 1]; the first shader gets 1 - fac
    glossy_weight = 1.0 - clamped if glossy_first else clamped
    np.testing.assert_allclose(row["albedo"], (0.2, 0.4, 0.6), rtol=1e-6)
    assert row["diffuse_weight"] == pytest.approx(1.0 - glossy_weight)
    np.testing.assert_allclose(row["glossy_colour"], glossy_weight * np.array([1.0, 0.8, 0.5]), rtol=1e-6)
    assert row["roughness"] == pytest.approx(0.25) and not row["multiscatter"] and not row["principled"]
    assert exported.materials[0].kind == "mix" and not warnings


def test_other_mixes_use_the_viewport_colour(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    linked = mix_material("Linked Fac", 0.5)
    tree = linked.node_tree
    tree.links.new(tree.nodes.new("ShaderNodeValue").outputs[0],
                   next(n for n in tree.nodes if n.bl_idname == "ShaderNodeMixShader").inputs[0])
    two_diffuse = mix_material("Two Diffuse", 0.5)
    tree = two_diffuse.node_tree
    mix = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeMixShader")
    tree.links.new(tree.nodes.new("ShaderNodeBsdfDiffuse").outputs[0], mix.inputs[2])
    for material in (linked, two_diffuse):
        material.diffuse_color = (0.1, 0.2, 0.3, 1.0)
    assign(bpy.context.object, linked, two_diffuse)
    bpy.context.object.data.polygons[0].material_index = 1
    exported, warnings = export(scene)
    assert [m.kind for m in exported.materials] == ["viewport", "viewport"]
    np.testing.assert_allclose(exported.scene.materials.albedo, [(0.1, 0.2, 0.3)] * 2, rtol=1e-6)
    listed = [w for w in warnings if "viewport" in w]
    assert len(listed) == 1 and "Linked Fac" in listed[0] and "Two Diffuse" in listed[0]


UNSUPPORTED_PRINCIPLED = [("Glass", {"Transmission Weight": 1.0}, "Transmission"),
                          ("Lacquer", {"Coat Weight": 0.5}, "Coat"),
                          ("Velvet", {"Sheen Weight": 1.0}, "Sheen"),
                          ("Skin", {"Subsurface Weight": 0.3}, "Subsurface"),
                          ("Chalk", {"Diffuse Roughness": 0.5}, "Oren-Nayar"),
                          ("Brushed", {"Anisotropic": 0.5}, "anisotropic"),
                          ("Cutout", {"Alpha": 0.5}, "Alpha")]


def test_unsupported_principled_inputs_warn_once_per_kind_and_keep_the_rest(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1)  # 20 faces: one per material
    sphere = bpy.context.object
    materials = []
    for name, inputs, _ in UNSUPPORTED_PRINCIPLED:
        material = node_material(name, "ShaderNodeBsdfPrincipled", Base_Color=(0.5, 0.25, 0.125), Metallic=0.5,
                                 Roughness=0.2)
        node = next(n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
        for socket, value in inputs.items():
            node.inputs[socket].default_value = value
        materials.append(material)
    bumpy = node_material("Bumpy", "ShaderNodeBsdfPrincipled", Base_Color=(0.5, 0.25, 0.125), Metallic=0.5,
                          Roughness=0.2)
    tree = bumpy.node_tree
    tree.links.new(tree.nodes.new("ShaderNodeBump").outputs["Normal"],
                   next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled").inputs["Normal"])
    assign(sphere, *materials, bumpy)
    for index in range(len(materials) + 1):
        sphere.data.polygons[index].material_index = index
    exported, warnings = export(scene)
    for name, _, word in UNSUPPORTED_PRINCIPLED:
        named = [w for w in warnings if word in w]
        assert len(named) == 1 and name in named[0], (word, warnings)
        assert not any(other in named[0] for other, *_ in UNSUPPORTED_PRINCIPLED if other != name)
    linked = [w for w in warnings if "Bumpy" in w]
    assert len(linked) == 1 and "(Normal)" in linked[0] and "constant" in linked[0]
    assert not any("diffuse base colour only" in w for w in warnings)
    assert len(warnings) == len(UNSUPPORTED_PRINCIPLED) + 1
    # What can be rendered is kept: every row is the Principled BSDF without the unsupported lobe.
    table = exported.scene.materials
    assert table.principled.all()
    np.testing.assert_allclose(table.albedo, [(0.5, 0.25, 0.125)] * len(table), rtol=1e-6)
    np.testing.assert_allclose(table.metallic, 0.5)
    np.testing.assert_allclose(table.roughness, 0.2, rtol=1e-6)


def test_unreadable_materials_use_viewport_colour_with_one_warning(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    frosted = node_material("Frosted", "ShaderNodeBsdfTranslucent")
    frosted.diffuse_color = (0.2, 0.3, 0.4, 1.0)
    glowing = node_material("Glowing", "ShaderNodeEmission")
    tree = glowing.node_tree
    tree.links.new(tree.nodes.new("ShaderNodeTexChecker").outputs["Color"],
                   next(n for n in tree.nodes if n.bl_idname == "ShaderNodeEmission").inputs["Color"])
    assign(cube, frosted, glowing)
    cube.data.polygons[0].material_index = 1
    exported, warnings = export(scene)
    listed = [w for w in warnings if "viewport" in w]
    assert len(listed) == 1 and "Frosted" in listed[0] and "Glowing" in listed[0]
    table = {m.name: i for i, m in enumerate(exported.materials)}
    np.testing.assert_allclose(exported.scene.materials.albedo[table["Frosted"]], (0.2, 0.3, 0.4), rtol=1e-6)


def test_other_nodes_on_a_base_colour_use_the_socket_colour_with_one_warning(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    checked = node_material("Checked", Color=(0.1, 0.2, 0.3))
    ramped = node_material("Ramped", "ShaderNodeBsdfPrincipled", Base_Color=(0.4, 0.5, 0.6))
    for material, socket in ((checked, "Color"), (ramped, "Base Color")):
        tree = material.node_tree
        shader = next(n for n in tree.nodes if n.bl_idname != "ShaderNodeOutputMaterial")
        tree.links.new(tree.nodes.new("ShaderNodeTexChecker").outputs["Color"], shader.inputs[socket])
    assign(cube, checked, ramped)
    cube.data.polygons[0].material_index = 1
    exported, warnings = export(scene)
    assert len(warnings) == 1 and "constant-colour fallback" in warnings[0]
    assert "Checked" in warnings[0] and "Ramped" in warnings[0]
    np.testing.assert_allclose(material_row(exported, "Checked")["albedo"], (0.1, 0.2, 0.3), rtol=1e-6)
    np.testing.assert_allclose(material_row(exported, "Ramped")["albedo"], (0.4, 0.5, 0.6), rtol=1e-6)
    assert (exported.scene.materials.texture_index == -1).all() and exported.scene.corner_uvs is None


# -- image textures ------------------------------------------------------------------------------------


# A 4 x 2 RGBA image in bytes, bottom row first (Blender's order), one texel half transparent.
TEXELS = np.array([[[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [255, 255, 255, 255]],
                   [[10, 20, 30, 255], [200, 100, 50, 255], [60, 120, 180, 128], [0, 0, 0, 255]]], np.uint8)


def byte_image(name="Tiles", texels=TEXELS, colorspace="sRGB"):
    """A generated 8-bit image holding exactly ``texels`` (H, W, 4) uint8, bottom row first."""
    height, width = texels.shape[:2]
    image = bpy.data.images.new(name, width, height, alpha=True)
    image.colorspace_settings.name = colorspace  # before the pixels: a new colour space regenerates the image
    image.pixels.foreach_set((texels.astype(np.float32) / 255.0).ravel())
    return image


def textured_material(name, image, shader="ShaderNodeBsdfPrincipled", colour=(0.2, 0.4, 0.6), **options):
    """``shader`` whose base colour (``colour`` unlinked) is an Image Texture of ``image`` through a reroute."""
    material = node_material(name, shader, **{"Base_Color" if "Principled" in shader else "Color": colour})
    tree = material.node_tree
    shader_node = next(n for n in tree.nodes if n.bl_idname == shader)
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    for key, value in options.items():
        setattr(texture, key, value)
    reroute = tree.nodes.new("NodeReroute")
    tree.links.new(texture.outputs["Color"], reroute.inputs[0])
    tree.links.new(reroute.outputs[0], shader_node.inputs["Base Color" if "Principled" in shader else "Color"])
    return material, texture


def plane_uv_expected(triangles, scale=1.0, offset=0.0):
    """Blender's default plane (size 2) maps local (x, y) in [-1, 1]^2 onto UV ((x + 1) / 2, (y + 1) / 2)."""
    return scale * (triangles[..., :2] + 1.0) / 2.0 + offset


@pytest.mark.parametrize("mirror", [False, True])
def test_image_texture_on_the_base_colour_exports_texels_options_and_uvs(scene, mirror):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.object
    if mirror:  # a mirroring transform reverses the triangles' corners: the UVs must follow
        plane.scale = (-1.0, 1.0, 1.0)
    material, _ = textured_material("Tiled", byte_image(), interpolation="Closest", extension="EXTEND")
    assign(plane, material)
    exported, warnings = export(scene)
    assert not warnings
    core = exported.scene
    assert len(core.textures) == 1 and core.materials.texture_index[0] == 0
    np.testing.assert_allclose(core.materials.albedo[0], (0.2, 0.4, 0.6), rtol=1e-6)  # the fallback colour
    texture = core.textures[0]
    assert (texture.srgb, texture.interpolation, texture.extension) == (True, "Closest", "EXTEND")
    assert texture.shape == (2, 4)
    # Opaque texels as they are, bottom row first; the half-transparent one associated as Cycles does.
    np.testing.assert_array_equal(texture.texels[0, :, :3] * 255.0, TEXELS[0, :, :3])
    np.testing.assert_allclose(texture.texels[1, 1] * 255.0, (200, 100, 50, 255), atol=1e-4)
    np.testing.assert_allclose(texture.texels[1, 2] * 255.0, (60 * 128 // 255, 120 * 128 // 255,
                                                            180 * 128 // 255, 128), atol=1e-4)
    local = core.triangles * ([-1.0, 1.0, 1.0] if mirror else 1.0)  # back to the plane's own coordinates
    assert core.corner_uvs.shape == (2, 3, 2)
    np.testing.assert_allclose(core.corner_uvs, plane_uv_expected(local), atol=1e-6)
    # The exported scene renders through the core's texture lookup: the corner (1, 1) is the top-right texel.
    np.testing.assert_allclose(texture.lookup(np.array([[0.99, 0.99]]))[0, :3], 0.0)
    assert isinstance(core.validated(Progress()), Scene)


@pytest.mark.parametrize("colorspace, srgb", [("sRGB", True), ("Non-Color", False), ("Linear Rec.709", False)])
def test_image_colour_space(scene, colorspace, srgb):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    image = byte_image(colorspace=colorspace)
    assign(bpy.context.object, textured_material("Tiled", image, "ShaderNodeBsdfDiffuse")[0])
    exported, warnings = export(scene)
    texture = exported.scene.textures[0]
    assert texture.srgb == srgb and texture.interpolation == "Linear" and texture.extension == "REPEAT"
    # Non-Color keeps the straight colour of the half-transparent texel (data is never associated).
    expected = 60 if colorspace == "Non-Color" else 60 * 128 // 255
    assert texture.texels[1, 2, 0] * 255.0 == pytest.approx(expected, abs=1e-4)
    assert not warnings


def test_float_image_is_linear_and_kept_as_blender_holds_it(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    image = bpy.data.images.new("HDR", 2, 1, float_buffer=True)
    values = np.array([[[2.5, 0.5, 0.25, 1.0], [0.1, 0.2, 0.3, 0.5]]], np.float32)
    image.pixels.foreach_set(values.ravel())
    assign(bpy.context.object, textured_material("Bright", image)[0])
    exported, _ = export(scene)
    texture = exported.scene.textures[0]
    assert not texture.srgb
    np.testing.assert_array_equal(texture.texels, values)


def test_textures_are_shared_per_image_and_options(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    image = byte_image()
    first, _ = textured_material("A", image)
    second, _ = textured_material("B", image, "ShaderNodeBsdfDiffuse")
    third, _ = textured_material("C", image, interpolation="Closest")
    smart, _ = textured_material("D", image, interpolation="Smart")  # read as Linear: the same texture as A
    assign(cube, first, second, third, smart)
    for index in range(4):
        cube.data.polygons[index].material_index = index
    exported, warnings = export(scene)
    rows = {m.name: i for i, m in enumerate(exported.materials)}
    index = exported.scene.materials.texture_index
    assert len(exported.scene.textures) == 2
    assert index[rows["A"]] == index[rows["B"]] == index[rows["D"]] != index[rows["C"]]
    assert len(warnings) == 1 and "Smart" in warnings[0] and "D" in warnings[0].split(": ")[-1]


def add_uv_map(obj, name, scale, offset):
    """A second UV map on ``obj``: the first one scaled and offset."""
    mesh = obj.data
    first = np.empty(len(mesh.loops) * 2, np.float32)
    mesh.uv_layers[0].uv.foreach_get("vector", first)
    layer = mesh.uv_layers.new(name=name)
    layer.uv.foreach_set("vector", first * scale + offset)
    return layer


@pytest.mark.parametrize("vector", ["uv_map_node", "texture_coordinate", "unlinked"])
def test_texture_reads_the_uv_map_its_vector_input_names(scene, vector):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.object
    add_uv_map(plane, "Shifted", 0.5, 0.25)
    material, texture = textured_material("Tiled", byte_image())
    tree = material.node_tree
    if vector == "uv_map_node":  # a named map, through a reroute; the render map stays the first one
        uv_node = tree.nodes.new("ShaderNodeUVMap")
        uv_node.uv_map = "Shifted"
        reroute = tree.nodes.new("NodeReroute")
        tree.links.new(uv_node.outputs["UV"], reroute.inputs[0])
        tree.links.new(reroute.outputs[0], texture.inputs["Vector"])
    else:  # the active render map, made the second one
        plane.data.uv_layers["Shifted"].active_render = True
        if vector == "texture_coordinate":
            tree.links.new(tree.nodes.new("ShaderNodeTexCoord").outputs["UV"], texture.inputs["Vector"])
    assign(plane, material)
    exported, warnings = export(scene)
    np.testing.assert_allclose(exported.scene.corner_uvs, plane_uv_expected(exported.scene.triangles, 0.5, 0.25),
                               atol=1e-6)
    assert not warnings


def test_objects_without_the_uv_map_get_zeros_and_a_warning(scene):
    add_camera(scene)
    material, texture = textured_material("Tiled", byte_image())
    tree = material.node_tree
    uv_node = tree.nodes.new("ShaderNodeUVMap")
    uv_node.uv_map = "Shifted"
    tree.links.new(uv_node.outputs["UV"], texture.inputs["Vector"])
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    with_map = bpy.context.object
    with_map.name = "Mapped"
    add_uv_map(with_map, "Shifted", 0.5, 0.25)
    assign(with_map, material)
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0.0, 0.0, -3.0))
    without = bpy.context.object
    without.name = "Unmapped"
    assign(without, material)
    bpy.ops.mesh.primitive_cube_add(location=(5.0, 0.0, 0.0))  # untextured: zeros, no warning
    exported, warnings = export(scene)
    core = exported.scene
    mapped = np.abs(core.triangles[:, :, 2]).max(axis=1) < 1e-6
    unmapped = np.abs(core.triangles[:, :, 2] + 3.0).max(axis=1) < 1e-6
    assert mapped.sum() == 2 and unmapped.sum() == 2 and len(core.triangles) == 16
    np.testing.assert_allclose(core.corner_uvs[mapped], plane_uv_expected(core.triangles[mapped], 0.5, 0.25),
                               atol=1e-6)
    np.testing.assert_array_equal(core.corner_uvs[~mapped], 0.0)
    assert len(warnings) == 1 and "Unmapped (Shifted)" in warnings[0] and "Mapped," not in warnings[0]


@pytest.mark.parametrize("case", ["missing_file", "no_image"])
def test_missing_image_falls_back_to_the_socket_colour_with_a_warning(scene, case):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    image = None
    if case == "missing_file":
        image = bpy.data.images.new("Gone", 4, 4)
        image.source = "FILE"
        image.filepath = "//does/not/exist.png"
    material, _ = textured_material("Lost", image, colour=(0.3, 0.5, 0.7))
    assign(bpy.context.object, material)
    exported, warnings = export(scene)
    core = exported.scene
    np.testing.assert_allclose(core.materials.albedo[0], (0.3, 0.5, 0.7), rtol=1e-6)
    assert core.materials.texture_index[0] == -1 and core.textures == [] and core.corner_uvs is None
    assert len(warnings) == 1 and "without image data" in warnings[0] and "Lost" in warnings[0]


def test_reroute_nodes_are_followed(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    material = node_material("Routed", Color=(0.3, 0.6, 0.9))
    tree = material.node_tree
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    diffuse = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfDiffuse")
    reroute = tree.nodes.new("NodeReroute")
    tree.links.new(diffuse.outputs[0], reroute.inputs[0])
    tree.links.new(reroute.outputs[0], output.inputs["Surface"])
    assign(bpy.context.object, material)
    exported, warnings = export(scene)
    np.testing.assert_allclose(exported.scene.materials.albedo[0], (0.3, 0.6, 0.9), rtol=1e-6)
    assert not warnings


def test_emission_plane_becomes_one_two_sided_polygon_light(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0.0, 0.0, 2.0))
    panel = bpy.context.object
    panel.modifiers.new("Subdivision", "SUBSURF").subdivision_type = "SIMPLE"  # 4 coplanar quads
    assign(panel, node_material("Glow", "ShaderNodeEmission", Color=(1.0, 0.5, 0.25), Strength=8.0))
    bpy.ops.mesh.primitive_cube_add()
    exported, _ = export(scene)
    lights = exported.scene.lights
    # Eight coplanar triangles tiling a square: one light (issue 14), of the same area and radiance.
    assert len(lights) == 1 and lights.two_sided.all() and list(lights.vertex_count) == [4]
    np.testing.assert_allclose(lights.radiance, [[8.0, 4.0, 2.0]])
    assert exported.counts["emitter_triangles"] == 8
    # The panel is also a surface the camera sees, emitting its radiance and reflecting nothing.
    assert len(exported.scene.triangles) == 20
    glow = [m.name for m in exported.materials].index("Glow")
    np.testing.assert_allclose(exported.scene.materials.emission[glow], (8.0, 4.0, 2.0))
    np.testing.assert_allclose(exported.scene.materials.albedo[glow], 0.0)
    assert exported.light_names == ["Glow"]
    assert polygon_area_normal(lights.vertices[0, :4])[0] == pytest.approx(1.0)


def test_emitters_become_hulls_convex_or_not(scene):
    """Issue 14: a subdivided UV sphere (nearly convex), two instances of an emissive cube and a torus
    (not convex: one hull of two lights, ``core/emitters.py``) with one emitting material each."""
    add_camera(scene)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=0.3, location=(0.0, 0.0, 2.0))
    sphere = bpy.context.object
    sphere.modifiers.new("Subdivision", "SUBSURF").levels = 1
    assign(sphere, node_material("Bulb", "ShaderNodeEmission", Strength=5.0))
    bpy.ops.mesh.primitive_cube_add(size=0.2, location=(1.0, 0.0, 1.0))
    cube = bpy.context.object
    assign(cube, node_material("Cube glow", "ShaderNodeEmission", Strength=3.0))
    copy = cube.copy()
    copy.location = (-1.0, 0.0, 1.0)
    scene.collection.objects.link(copy)
    bpy.ops.mesh.primitive_torus_add(major_segments=12, minor_segments=6, location=(0.0, 1.5, 1.0))
    assign(bpy.context.object, node_material("Ring", "ShaderNodeEmission", Strength=2.0))
    exported, _ = export(scene)
    hulls = exported.scene.hulls
    assert len(hulls) == 4
    assert sorted(np.bincount(hulls.hull).tolist()) == [12, 12, 12 * 6 * 2, triangle_count(sphere)]
    assert sorted(exported.light_names[-4:]) == ["Bulb", "Cube glow", "Cube glow", "Ring"]
    assert hulls.convex.tolist() == [True, True, True, False]  # the convex ones first
    assert len(exported.scene.lights) == 0 and exported.scene.light_count == 4


def test_world_background(scene):
    add_camera(scene)
    world = bpy.data.worlds.new("Sky")
    scene.world = world
    background = next(n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground")
    background.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    background.inputs["Strength"].default_value = 0.5
    exported, warnings = export(scene)
    np.testing.assert_allclose(exported.scene.background, (0.1, 0.2, 0.3), rtol=1e-6)
    assert any("does not light" in w for w in warnings)
    scene.world = None
    exported, warnings = export(scene)
    np.testing.assert_array_equal(exported.scene.background, 0.0)


def test_exported_scene_survives_core_validation(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_monkey_add()
    bpy.ops.object.shade_smooth()
    add_area_light(shape="ELLIPSE", size=1.0, size_y=0.5, energy=10.0)
    exported, _ = export(scene)
    validated = exported.scene.validated(Progress())
    assert isinstance(validated, Scene)
    assert len(validated.triangles) == len(exported.scene.triangles)
    assert len(validated.lights) == 1


def test_geometry_nodes_instances_keep_their_materials(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=3, y_subdivisions=3)  # 16 points
    grid = bpy.context.object
    group = bpy.data.node_groups.new("Scatter", "GeometryNodeTree")
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = group.nodes, group.links
    source, sink = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    on_points, cube = nodes.new("GeometryNodeInstanceOnPoints"), nodes.new("GeometryNodeMeshCube")
    set_material = nodes.new("GeometryNodeSetMaterial")
    set_material.inputs["Material"].default_value = node_material("Pebble", Color=(0.9, 0.1, 0.1))
    cube.inputs["Size"].default_value = (0.2, 0.2, 0.2)
    links.new(source.outputs[0], on_points.inputs["Points"])
    links.new(cube.outputs[0], set_material.inputs["Geometry"])
    links.new(set_material.outputs[0], on_points.inputs["Instance"])
    links.new(on_points.outputs[0], sink.inputs[0])
    grid.modifiers.new("Scatter", "NODES").node_group = group
    exported, _ = export(scene)
    assert exported.counts["instances"] == 16
    table = {m.name: i for i, m in enumerate(exported.materials)}
    assert (exported.scene.material_index == table["Pebble"]).sum() == 16 * 12
    assert len(exported.scene.triangles) == 16 * 12


def test_unsupported_object_types_warn(scene):
    add_camera(scene)
    fur = bpy.data.objects.new("Fur", bpy.data.hair_curves.new("Fur"))
    scene.collection.objects.link(fur)
    _, warnings = export(scene)
    assert any("Fur" in w and "not rendered" in w for w in warnings)


def test_ray_visibility_warns_and_cast_shadow_is_exported(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add()
    bpy.context.object.name = "Ghost"
    bpy.context.object.visible_shadow = False
    light = add_area_light(name="Panel", size=1.0, energy=10.0, use_shadow=False)
    light.visible_camera = True
    add_area_light(name="Shadowing", size=1.0, energy=10.0)
    bpy.ops.object.light_add(type="SPOT")
    bpy.context.object.data.use_shadow = False
    exported, warnings = export(scene)
    assert any("Ray Visibility" in w and "Ghost" in w for w in warnings)
    assert not any("Panel" in w for w in warnings)  # the camera's lights are drawn (core/seen_lights.py)
    assert not any("Cast Shadow" in w for w in warnings)
    # Only Panel has Ray Visibility > Camera on (lights are added with it off, as Blender adds them).
    assert len(exported.scene.seen) == 1
    np.testing.assert_allclose(exported.scene.seen.radiance[0], exported.scene.lights.radiance[0])
    np.testing.assert_array_equal(exported.scene.lights.cast_shadow, [False, True])
    np.testing.assert_array_equal(exported.scene.facing.cast_shadow, [False])


def test_lights_ray_visibility_diffuse_and_glossy_is_exported_per_light(scene):
    """Issue 14: Object > Visibility > Ray Visibility > Diffuse and Glossy of area, point and sun lights and
    of emitting meshes become the lobes each reaches (measured in Cycles 5.0.1: either off, that lobe gets
    none of the light); both off, the light lights nothing and is left out, an emitter still shows."""
    from lazyvis_addon.core.scene import LOBE_DIFFUSE, LOBE_GLOSSY, LOBES_ALL
    add_camera(scene)
    add_area_light(name="Both", size=1.0, energy=10.0)
    add_area_light(name="Glossy only", size=1.0, energy=10.0).visible_diffuse = False
    none = add_area_light(name="Neither", size=1.0, energy=10.0)
    none.visible_diffuse = none.visible_glossy = False
    add_light("POINT", energy=10.0).visible_glossy = False
    add_light("SUN", energy=2.0)
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0.0, 0.0, 2.0))
    panel = bpy.context.object
    assign(panel, node_material("Glow", "ShaderNodeEmission", Strength=5.0))
    panel.visible_diffuse = False
    exported, warnings = export(scene)
    assert "Neither" not in exported.light_names and "Glow" in exported.light_names
    np.testing.assert_array_equal(exported.scene.lights.lobes, [LOBES_ALL, LOBE_GLOSSY, LOBE_GLOSSY])
    np.testing.assert_array_equal(exported.scene.facing.lobes, [LOBE_DIFFUSE, LOBES_ALL])
    panel.visible_glossy = False
    dark, _ = export(scene)
    assert "Glow" not in dark.light_names and len(dark.scene.lights) == 2
    assert (dark.scene.materials.emission > 0).any()  # the panel is still seen, emitting
    assert not any("Ray Visibility" in w for w in warnings)


def test_panoramic_camera_is_a_clear_error(scene):
    add_camera(scene, type="PANO")
    with pytest.raises(ValueError, match="perspective and orthographic cameras only"):
        export(scene)


def _emitter_material(kind: str):
    """A material whose output is fed by ``kind``: "add" (Add Shader of an Emission of strength 4 from a
    Value node and a Diffuse BSDF), "mix" (Mix Shader, factor 0.25, of an Emission of strength 4 and a
    Diffuse BSDF)."""
    material = bpy.data.materials.new(kind)
    tree = material.node_tree
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    for node in [n for n in tree.nodes if n != output]:
        tree.nodes.remove(node)
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    if kind == "add":
        value = tree.nodes.new("ShaderNodeValue")
        value.outputs[0].default_value = 4.0
        tree.links.new(value.outputs[0], emission.inputs["Strength"])
        join = tree.nodes.new("ShaderNodeAddShader")
        tree.links.new(emission.outputs[0], join.inputs[0])
        tree.links.new(diffuse.outputs[0], join.inputs[1])
    else:
        emission.inputs["Strength"].default_value = 4.0
        join = tree.nodes.new("ShaderNodeMixShader")
        join.inputs[0].default_value = 0.25
        tree.links.new(emission.outputs[0], join.inputs[1])
        tree.links.new(diffuse.outputs[0], join.inputs[2])
    tree.links.new(join.outputs[0], output.inputs["Surface"])
    return material


@pytest.mark.parametrize("kind, emission_weight, diffuse_weight", [("add", 1.0, 1.0), ("mix", 0.75, 0.25)])
def test_emission_added_or_mixed_with_a_diffuse_bsdf(kind, emission_weight, diffuse_weight):
    """Issue 14: public scenes' emitters are an Emission and a Diffuse BSDF joined by an Add Shader (or a Mix
    Shader), the Strength often from a Value node: the surface both emits and reflects, as in Cycles."""
    record = read_material(_emitter_material(kind))
    np.testing.assert_allclose(record.emission, np.array([1.0, 0.5, 0.25]) * 4.0 * emission_weight, rtol=1e-6)
    np.testing.assert_allclose(record.albedo, np.array([0.2, 0.4, 0.6]) * diffuse_weight, rtol=1e-6)
    assert record.is_emitter and record.kind == "diffuse"


def test_node_groups_are_followed_with_their_inputs():
    """Issue 14: an Emission inside a node group, its Strength from the Group Input (set on the group node)
    and its colour fixed inside; and a Diffuse colour from a group input fed by a Value node outside."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    group = bpy.data.node_groups.new("Glow group", "ShaderNodeTree")
    group.interface.new_socket("Strength", in_out="INPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    inside_in = group.nodes.new("NodeGroupInput")
    inside_out = group.nodes.new("NodeGroupOutput")
    emission = group.nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    group.links.new(inside_in.outputs["Strength"], emission.inputs["Strength"])
    group.links.new(emission.outputs[0], inside_out.inputs["Shader"])
    material = node_material("Grouped glow")
    tree = material.node_tree
    tree.nodes.remove(next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfDiffuse"))
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.inputs["Strength"].default_value = 7.0
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    tree.links.new(node.outputs["Shader"], output.inputs["Surface"])
    record = read_material(material)
    assert record.is_emitter
    np.testing.assert_allclose(record.emission, (7.0, 3.5, 1.75))
    # The same group fed by a Value node outside.
    value = tree.nodes.new("ShaderNodeValue")
    value.outputs[0].default_value = 2.0
    tree.links.new(value.outputs[0], node.inputs["Strength"])
    np.testing.assert_allclose(read_material(material).emission, (2.0, 1.0, 0.5))


# -- blackbody (issue 14) -------------------------------------------------------------------------------


def test_blackbody_table_is_blenders_function_between_its_points(scene):
    """core.blackbody interpolates a table of Blender's blackbody colour (tools/make_blackbody_table.py);
    at temperatures between the table's points, away from the function's own steps, it is Blender's to 1e-5."""
    from lazyvis_addon.core.blackbody import blackbody_rgb
    light = bpy.data.lights.new("probe", "AREA")
    light.use_temperature = True
    for temperature in (850.5, 1234.5, 2777.0, 4321.0, 5003.0, 7777.0, 10500.0):
        light.temperature = temperature
        expected = np.array(light.temperature_color[:3])
        np.testing.assert_allclose(blackbody_rgb(light.temperature), expected, atol=1e-5 * expected.max())


def _blackbody_emission(temperature: float, strength: float):
    """An Emission whose Color is a Blackbody node fed by a Value node of ``temperature``."""
    material = node_material("Ember", "ShaderNodeEmission", Strength=strength)
    tree = material.node_tree
    emission = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeEmission")
    blackbody, value = tree.nodes.new("ShaderNodeBlackbody"), tree.nodes.new("ShaderNodeValue")
    value.outputs[0].default_value = temperature
    tree.links.new(value.outputs[0], blackbody.inputs["Temperature"])
    tree.links.new(blackbody.outputs[0], emission.inputs["Color"])
    return material


def test_blackbody_and_rgb_nodes_feed_emission_and_light_colours(scene):
    """Issue 14: an Emission coloured by a Blackbody node (its temperature a constant or a Value node) emits
    Blender's blackbody colour; a light's node tree may colour it the same way, or by an RGB node."""
    from lazyvis_addon.core.blackbody import blackbody_rgb
    record = read_material(_blackbody_emission(2500.0, 3.0))
    assert record.is_emitter
    np.testing.assert_allclose(record.emission, 3.0 * blackbody_rgb(2500.0), rtol=1e-6)
    add_camera(scene)
    light = add_light("POINT", energy=10.0).data
    plain, _ = export(scene)
    light.use_nodes = True
    tree = light.node_tree
    emission = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeEmission")
    blackbody = tree.nodes.new("ShaderNodeBlackbody")
    blackbody.inputs["Temperature"].default_value = 4000.0
    tree.links.new(blackbody.outputs[0], emission.inputs["Color"])
    tinted, warnings = export(scene)
    np.testing.assert_allclose(tinted.scene.facing.intensity[0], plain.scene.facing.intensity[0]
                               * blackbody_rgb(4000.0), rtol=1e-6)
    assert not any("node" in w for w in warnings)
    rgb = tree.nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (0.5, 0.25, 1.0, 1.0)
    tree.links.new(rgb.outputs[0], emission.inputs["Color"])
    coloured, _ = export(scene)
    np.testing.assert_allclose(coloured.scene.facing.intensity[0], plain.scene.facing.intensity[0]
                               * np.array([0.5, 0.25, 1.0]), rtol=1e-6)
    noise = tree.nodes.new("ShaderNodeTexNoise")
    tree.links.new(noise.outputs["Color"], emission.inputs["Color"])
    fallback, warnings = export(scene)
    np.testing.assert_allclose(fallback.scene.facing.intensity[0], plain.scene.facing.intensity[0], rtol=1e-6)
    assert any("read as plain lights" in w for w in warnings)


def test_blackbody_emission_seen_by_the_camera_is_what_cycles_renders(scene, tmp_path):
    """A camera ray meeting an emitter returns its emission exactly, so one Cycles sample is the truth: an
    emissive plane filling the view, coloured by a Blackbody node at 3456 K (between the table's points),
    renders in LazyVis as in Cycles to 2e-4."""
    add_camera(scene, location=(0.0, 0.0, 3.0), rotation=(0.0, 0.0, 0.0))
    bpy.ops.mesh.primitive_plane_add(size=20.0)
    assign(bpy.context.object, _blackbody_emission(3456.0, 2.0))
    scene.render.resolution_x, scene.render.resolution_y = 4, 4
    ours = render_to_exr(scene, tmp_path / "lazyvis.exr")["RGBA"][..., :3]
    cycles_reference_tool().configure_cycles(scene, samples=1, seed=0, threads=1)
    theirs = render_to_exr(scene, tmp_path / "cycles.exr")["RGBA"][..., :3]
    assert theirs[..., 0].min() > 1.0 > theirs[..., 2].max() > 0.1  # a warm colour, not a default white
    np.testing.assert_allclose(ours, theirs, rtol=2e-4)
