"""Build the sample .blend files of LazyVis with bpy (Blender as a Python module).

    .venv/bin/python sample_blends/make_samples.py                    # all of them, into sample_blends/
    .venv/bin/python sample_blends/make_samples.py suzanne --output-dir /tmp
    .venv/bin/python sample_blends/make_samples.py glossy textured    # only these two

- ``floating_boxes.blend``: the paper's Fig. 7 set-up: 49 boxes floating over a ground plane before a
  back wall, four coloured area lights of different shapes and sizes (rectangle, square, thin rectangle,
  disk).
- ``chapel.blend``: a chapel-like interior (nave, pillars, altar, two blocks of benches) lit only through
  a slatted window by one large area light outside; the benches are bevelled and arrayed by modifiers,
  about 40,000 triangles after evaluation.
- ``suzanne.blend``: Suzanne, smooth shaded with a level-1 subdivision surface, on a floor under a DISK
  and an ELLIPSE area light; her Shadow Terminator Geometry Offset is Blender's default 0.1, as on
  users' objects (both renderers lift her shadow rays off the flat triangles towards grazing light).
- ``glossy.blend``: the floating boxes before a glossy back wall (Principled, roughness 0.3, base 0.8 grey)
  on a glossy floor (Principled, roughness 0.4); among the diffuse boxes a few metallic (Principled,
  metallic 1), Glossy BSDF and Mix (Diffuse + Glossy) ones; two area lights (issue 4).
- ``textured.blend``: a checker-textured floor (Image Texture of a 64 x 64 checker image packed into the
  file, Closest interpolation, sRGB) lit by one area light through five thin slats (issue 5).
- ``suzanne_dense.blend``, ``suzanne_dense3.blend``: Suzanne as in ``suzanne.blend`` but subdivided twice
  (about 16,000 triangles) or three times (about 63,000), under her DISK and ELLIPSE lights and a small
  DISK low on her right, whose shadows fall on her face as well as on the floor: level 2 against level 3.
- ``tree.blend``: a trunk with four branches and 4,000 separate leaf quads (3-6 cm, randomly oriented) in a
  crown of radius 1 m over a ground, lit by a 1 m SQUARE and a 0.2 m DISK light: a dappled soft shadow.
- ``room.blend``: a living-room corner (walls, floor, a sofa, a table on thin legs, a side table, a vase)
  lit as users light one: a ceiling SQUARE area light, a point lamp of radius 8 cm over the side table, a
  spot on the back wall and a hard point light (radius 0); Principled materials (issue 14).
- ``chairs.blend``: 150 linked duplicates of one chair mesh (a seat, a back and four 2.5 cm legs, 72
  triangles) in 10 rows on the floor of a room corner, under a 5 x 2.5 m RECTANGLE light near the ceiling
  and a low 0.5 m SQUARE light that casts the legs' long shadows.

Every file: a black world, area lights hidden from the camera (Cycles' default), 512 x 512 (chapel
640 x 480) at 100%, frame range 1-1, render engine LAZYVIS, and Cycles already set up as the project's
direct-light reference (tools/make_cycles_reference.py) so that switching the engine to Cycles gives the
image LazyVis should match. The floating boxes, chapel, Suzanne, tree and chairs use Diffuse BSDF
materials only (exact against Cycles); the glossy one Principled, Glossy and Mix shaders. Geometry comes
from a fixed seed: running the script twice gives the same scenes. Files are saved compressed (each about
100 KB, the tree about 400 KB).

Rebuilding changes the files' bytes even when the scenes are the same (Blender stores memory addresses
and a timestamp): re-run tools/make_cycles_references.py afterwards, the agreement tests check it.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import random
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

SAMPLES = ("floating_boxes", "chapel", "suzanne", "glossy", "textured", "suzanne_dense", "suzanne_dense3",
           "tree", "chairs", "room")


# -- building blocks (bpy imported by main before any of these run) ------------------------------------------


def new_scene(width: int, height: int):
    """Factory settings without objects, LazyVis registered and selected, Cycles set up as the reference."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    reference = _reference_tool()
    reference.configure_cycles(scene, samples=1024, seed=0)
    # Shipped with Blender's default pixel filter, as a user's file has it (the reference set-up's 0.01, a
    # point sample, is what the tests set where they compare pixel centres).
    scene.cycles.filter_width = 1.5
    scene.render.engine = "LAZYVIS"
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.frame_start = scene.frame_end = scene.frame_current = 1
    world = bpy.data.worlds.new("Black")
    world.color = (0.0, 0.0, 0.0)
    tree = world.node_tree if world.node_tree is not None else _world_nodes(world)
    background = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBackground")
    background.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    background.inputs["Strength"].default_value = 0.0
    scene.world = world
    return scene


def _world_nodes(world):
    """Blender < 5 worlds get their node tree through use_nodes."""
    world.use_nodes = True
    return world.node_tree


def _reference_tool():
    spec = importlib.util.spec_from_file_location("make_cycles_reference", ROOT / "tools" / "make_cycles_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def diffuse(name: str, color) -> "bpy.types.Material":
    """A material whose surface is one Diffuse BSDF of ``color`` (viewport colour to match)."""
    import bpy

    material = bpy.data.materials.new(name)
    tree = material.node_tree if material.node_tree is not None else _material_nodes(material)
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    for node in [n for n in tree.nodes if n != output]:
        tree.nodes.remove(node)
    node = tree.nodes.new("ShaderNodeBsdfDiffuse")
    node.location = (output.location.x - 250, output.location.y)
    node.inputs["Color"].default_value = (*color, 1.0)
    tree.links.new(node.outputs["BSDF"], output.inputs["Surface"])
    material.diffuse_color = (*color, 1.0)
    return material


def principled(name: str, color, roughness: float, metallic: float = 0.0) -> "bpy.types.Material":
    """A material whose surface is one Principled BSDF (Multiscatter GGX, Cycles' default)."""
    material = _shader_material(name, "ShaderNodeBsdfPrincipled", color)
    node = next(n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    node.inputs["Base Color"].default_value = (*color, 1.0)
    node.inputs["Roughness"].default_value = roughness
    node.inputs["Metallic"].default_value = metallic
    return material


def glossy(name: str, color, roughness: float) -> "bpy.types.Material":
    """A material whose surface is one Glossy BSDF (GGX)."""
    material = _shader_material(name, "ShaderNodeBsdfGlossy", color)
    node = next(n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfAnisotropic")
    node.inputs["Color"].default_value = (*color, 1.0)
    node.inputs["Roughness"].default_value = roughness
    node.distribution = "GGX"
    return material


def diffuse_glossy_mix(name: str, color, glossy_color, roughness: float, fac: float) -> "bpy.types.Material":
    """A Mix Shader of a Diffuse BSDF (weight 1 - fac) and a Glossy BSDF (weight fac)."""
    material = _shader_material(name, "ShaderNodeMixShader", color)
    tree = material.node_tree
    mix = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeMixShader")
    mix.inputs[0].default_value = fac
    base, shine = tree.nodes.new("ShaderNodeBsdfDiffuse"), tree.nodes.new("ShaderNodeBsdfGlossy")
    base.inputs["Color"].default_value = (*color, 1.0)
    shine.inputs["Color"].default_value = (*glossy_color, 1.0)
    shine.inputs["Roughness"].default_value = roughness
    base.location = (mix.location.x - 250, mix.location.y + 150)
    shine.location = (mix.location.x - 250, mix.location.y - 150)
    tree.links.new(base.outputs["BSDF"], mix.inputs[1])
    tree.links.new(shine.outputs["BSDF"], mix.inputs[2])
    return material


def _shader_material(name: str, shader: str, viewport_color) -> "bpy.types.Material":
    """A material whose output is fed by one new ``shader`` node (its inputs left at their defaults)."""
    import bpy

    material = bpy.data.materials.new(name)
    tree = material.node_tree if material.node_tree is not None else _material_nodes(material)
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    for node in [n for n in tree.nodes if n != output]:
        tree.nodes.remove(node)
    node = tree.nodes.new(shader)
    node.location = (output.location.x - 250, output.location.y)
    tree.links.new(node.outputs[0], output.inputs["Surface"])
    material.diffuse_color = (*viewport_color, 1.0)
    return material


def _material_nodes(material):
    material.use_nodes = True
    return material.node_tree


def box_mesh(name: str, boxes) -> "bpy.types.Mesh":
    """One mesh of axis-aligned boxes, each ((cx, cy, cz), (sx, sy, sz)), outward-facing quads."""
    import bpy

    vertices, faces = [], []
    for centre, size in boxes:
        base = len(vertices)
        for z in (-0.5, 0.5):
            for y in (-0.5, 0.5):
                for x in (-0.5, 0.5):
                    vertices.append((centre[0] + x * size[0], centre[1] + y * size[1], centre[2] + z * size[2]))
        for quad in ((0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)):
            faces.append(tuple(base + i for i in quad))
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(vertices, [], faces)
    mesh.validate()
    return mesh


def add_object(name: str, data, material=None, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0),
               scale=(1.0, 1.0, 1.0)):
    import bpy

    obj = bpy.data.objects.new(name, data)
    obj.location, obj.rotation_euler, obj.scale = location, rotation, scale
    if material is not None and len(data.materials) == 0:
        data.materials.append(material)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def add_camera(name: str, eye, target, angle_degrees: float):
    """A perspective camera at ``eye`` looking at ``target``; ``angle_degrees`` spans the longer side."""
    import bpy
    from mathutils import Vector

    data = bpy.data.cameras.new(name)
    data.sensor_fit = "AUTO"
    data.angle = math.radians(angle_degrees)
    data.clip_start, data.clip_end = 0.05, 200.0
    camera = add_object(name, data, location=eye)
    camera.rotation_euler = (Vector(target) - Vector(eye)).to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.camera = camera
    return camera


def add_area_light(name: str, location, target, shape: str, size: float, size_y: float | None = None,
                   color=(1.0, 1.0, 1.0), radiance: float = 10.0):
    """An area light at ``location`` whose emitting side (local -Z) faces ``target``.

    ``radiance`` is the emitted radiance L of the brightest channel (W m^-2 sr^-1); the power is set from
    Blender's L = colour P / (pi A) (radiometry note), so lights of different sizes are given alike.
    The light is hidden from camera rays (Cycles' default; LazyVis does not draw lights either).
    """
    import bpy
    from mathutils import Vector

    data = bpy.data.lights.new(name, "AREA")
    data.shape = shape
    data.size = size
    if size_y is not None:
        data.size_y = size_y
    data.color = color
    sy = size if size_y is None or shape in ("SQUARE", "DISK") else size_y
    area = size * sy * (math.pi / 4.0 if shape in ("DISK", "ELLIPSE") else 1.0)
    data.energy = radiance * math.pi * area / max(color)
    light = add_object(name, data, location=location)
    light.rotation_euler = (Vector(target) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
    light.visible_camera = False
    return light


def save(path: Path) -> None:
    import bpy

    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backup of the previous file
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True, check_existing=False)


# -- the scenes ------------------------------------------------------------------------------------------------


def build_floating_boxes() -> None:
    """49 boxes in a jittered 7 x 7 grid, 0.5-2 m above a 12 x 12 m ground, a 6 m back wall, 4 lights."""
    new_scene(512, 512)
    ground = diffuse("Ground", (0.8, 0.8, 0.8))
    wall = diffuse("Wall", (0.75, 0.72, 0.68))
    _boxes_before_a_wall(ground, wall, _box_palette())
    add_area_light("Warm Rectangle", (-2.0, -1.5, 4.5), (-1.6, -1.2, 0.0), "RECTANGLE", 1.6, 1.0,
                   color=(1.0, 0.83, 0.67), radiance=15.0)
    add_area_light("Blue Square", (2.5, 1.5, 5.0), (2.2, 1.0, 0.0), "SQUARE", 0.8,
                   color=(0.45, 0.68, 1.0), radiance=22.0)
    add_area_light("Red Strip", (0.5, -3.0, 3.8), (0.5, -2.0, 0.0), "RECTANGLE", 2.4, 0.5,
                   color=(1.0, 0.48, 0.4), radiance=12.5)
    add_area_light("Green Disk", (-1.5, 3.0, 4.2), (-1.2, 2.5, 0.0), "DISK", 1.0,
                   color=(0.6, 1.0, 0.6), radiance=12.5)
    add_camera("Camera", (0.0, -11.0, 7.5), (0.0, 0.0, 0.8), 50.0)


def _box_palette() -> list:
    return [diffuse(name, color) for name, color in (
        ("Red", (0.8, 0.3, 0.2)), ("Green", (0.2, 0.7, 0.3)), ("Blue", (0.25, 0.35, 0.8)),
        ("Yellow", (0.8, 0.75, 0.3)), ("Grey", (0.7, 0.7, 0.7)))]


def _boxes_before_a_wall(ground, wall, palette) -> None:
    """The floating-boxes layout: a 12 x 12 m ground, a 6 m back wall and 49 boxes (seed 7), box i with
    ``palette[i % len(palette)]``."""
    rng = random.Random(7)
    add_object("Ground", box_mesh("Ground", [((0.0, 0.0, -0.05), (12.0, 12.0, 0.1))]), ground)
    add_object("Back Wall", box_mesh("Back Wall", [((0.0, 6.05, 3.0), (12.0, 0.1, 6.0))]), wall)
    # One unit cube per material, shared by the boxes of that material (linked duplicates: a small file).
    cubes = [box_mesh(f"Box {m.name}", [((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))]) for m in palette]
    for cube, material in zip(cubes, palette):
        cube.materials.append(material)
    side = 7
    for index in range(49):
        gx, gy = index % side, index // side
        centre = (-3.6 + 7.2 * (gx + 0.5) / side + rng.uniform(-0.25, 0.25),
                  -3.6 + 7.2 * (gy + 0.5) / side + rng.uniform(-0.25, 0.25), rng.uniform(0.5, 2.0))
        size = tuple(rng.uniform(0.25, 0.6) for _ in range(3))
        add_object(f"Box {index:02d}", cubes[index % len(cubes)], location=centre,
                   rotation=(0.0, 0.0, rng.uniform(0.0, math.pi)), scale=size)


def build_glossy() -> None:
    """The floating boxes before a glossy wall on a glossy floor, some boxes metallic or glossy, 2 lights."""
    new_scene(512, 512)
    floor = principled("Glossy Floor", (0.5, 0.5, 0.5), roughness=0.4)
    wall = principled("Glossy Wall", (0.8, 0.8, 0.8), roughness=0.3)
    palette = _box_palette() + [principled("Gold", (1.0, 0.77, 0.34), roughness=0.25, metallic=1.0),
                                glossy("Mirror", (0.9, 0.9, 0.9), roughness=0.15),
                                diffuse_glossy_mix("Varnished Red", (0.7, 0.15, 0.1), (1.0, 1.0, 1.0),
                                                   roughness=0.2, fac=0.3)]
    _boxes_before_a_wall(floor, wall, palette)
    add_area_light("Warm Rectangle", (-2.5, -2.0, 4.5), (-1.0, 1.0, 0.0), "RECTANGLE", 2.0, 1.0,
                   color=(1.0, 0.85, 0.7), radiance=15.0)
    add_area_light("Cool Square", (3.0, 0.5, 5.0), (1.5, 3.0, 0.5), "SQUARE", 1.0,
                   color=(0.6, 0.75, 1.0), radiance=20.0)
    add_camera("Camera", (0.0, -11.0, 7.5), (0.0, 0.0, 0.8), 50.0)


def checker_image(name: str, size: int = 64, squares: int = 8, dark=0.15, light=0.85) -> "bpy.types.Image":
    """A ``size`` x ``size`` sRGB checker of ``squares`` x ``squares`` squares, packed into the .blend."""
    import bpy
    import numpy as np

    image = bpy.data.images.new(name, size, size, alpha=False)
    image.colorspace_settings.name = "sRGB"  # before the pixels: a new colour space regenerates the image
    cell = (np.arange(size) * squares // size) % 2
    value = np.where(cell[:, None] ^ cell[None, :], light, dark).astype(np.float32)
    pixels = np.ones((size, size, 4), np.float32)
    pixels[..., :3] = value[..., None]
    image.pixels.foreach_set(pixels.ravel())
    image.pack()
    return image


def build_textured() -> None:
    """An 8 x 8 m checker floor (UVs repeating twice) lit by one narrow area light through five slats."""
    import bpy
    import numpy as np

    new_scene(512, 512)
    floor_material = diffuse("Checker Floor", (0.5, 0.5, 0.5))
    tree = floor_material.node_tree
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.image = checker_image("Checker")
    texture.interpolation = "Closest"
    texture.extension = "REPEAT"
    texture.location = (-600, 0)
    shader = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfDiffuse")
    tree.links.new(texture.outputs["Color"], shader.inputs["Color"])

    bpy.ops.mesh.primitive_plane_add(size=8.0)
    floor = bpy.context.object
    floor.name = floor.data.name = "Floor"
    floor.data.materials.append(floor_material)
    uv = floor.data.uv_layers[0].uv
    coordinates = np.empty(len(uv) * 2, np.float32)
    uv.foreach_get("vector", coordinates)
    uv.foreach_set("vector", 2.0 * coordinates)  # the checker twice across: 16 squares of 0.5 m

    # Slats along x, 1.2 m up; the light is long along them and narrow across, so the stripes of shadow
    # have penumbrae of about 0.1 m (0.25 m x 1.2 m / 2.8 m) between them.
    slats = [((0.0, -1.2 + 0.6 * i, 1.2), (3.0, 0.25, 0.06)) for i in range(5)]
    add_object("Slats", box_mesh("Slats", slats), diffuse("Slat Wood", (0.45, 0.3, 0.18)))
    add_area_light("Light", (0.4, -0.8, 4.0), (0.0, 0.0, 0.0), "RECTANGLE", 1.2, 0.25,
                   color=(1.0, 0.95, 0.85), radiance=120.0)
    add_camera("Camera", (0.0, -7.5, 5.5), (0.0, 0.2, 0.5), 50.0)


def build_chapel() -> None:
    """A 9 x 22 x 7 m nave with a slatted window in its right wall and one 6 x 4 m light outside it."""
    import bpy

    scene = new_scene(640, 480)
    stone = diffuse("Stone Floor", (0.55, 0.5, 0.45))
    plaster = diffuse("Plaster", (0.8, 0.78, 0.72))
    wood = diffuse("Oak", (0.45, 0.28, 0.15))
    slat_material = diffuse("Slats", (0.35, 0.33, 0.3))
    altar_material = diffuse("Marble", (0.75, 0.74, 0.72))

    half_width, half_length, height, wall = 4.5, 11.0, 7.0, 0.3
    add_object("Floor", box_mesh("Floor", [((0.0, 0.0, -0.1), (2 * half_width + 2 * wall, 2 * half_length, 0.2))]),
               stone)
    add_object("Ceiling", box_mesh("Ceiling", [((0.0, 0.0, height + 0.1),
                                                 (2 * half_width + 2 * wall, 2 * half_length, 0.2))]), plaster)
    # Right wall (x = +half_width) with a window opening y in [-3, 3], z in [2.5, 5.5].
    x_wall = half_width + wall / 2
    y0, y1, z0, z1 = -3.0, 3.0, 2.5, 5.5
    walls = [((-x_wall, 0.0, height / 2), (wall, 2 * half_length, height)),            # left
             ((0.0, half_length + wall / 2, height / 2), (2 * half_width, wall, height)),   # altar end
             ((0.0, -half_length - wall / 2, height / 2), (2 * half_width, wall, height)),  # entrance end
             ((x_wall, (y0 - half_length) / 2, height / 2), (wall, y0 + half_length, height)),
             ((x_wall, (y1 + half_length) / 2, height / 2), (wall, half_length - y1, height)),
             ((x_wall, 0.0, z0 / 2), (wall, y1 - y0, z0)),
             ((x_wall, 0.0, (z1 + height) / 2), (wall, y1 - y0, height - z1))]
    add_object("Walls", box_mesh("Walls", walls), plaster)
    # Slats: horizontal louvres and two mullions across the opening.
    slats = [((x_wall, 0.0, z0 + (i + 0.5) * (z1 - z0) / 7), (0.12, y1 - y0, 0.12)) for i in range(7)]
    slats += [((x_wall, y, (z0 + z1) / 2), (0.14, 0.14, z1 - z0)) for y in (-1.0, 1.0)]
    add_object("Slats", box_mesh("Slats", slats), slat_material)

    # Pillars: 24-sided cylinders on both sides of the nave.
    pillar = bpy.data.meshes.new("Pillar")
    _cylinder(pillar, radius=0.25, depth=height, segments=24)
    pillar.materials.append(plaster)
    for side in (-1, 1):
        for index, y in enumerate((-6.0, -1.5, 3.0, 7.5)):
            add_object(f"Pillar {'LR'[side > 0]}{index}", pillar, location=(side * 3.6, y, height / 2))
    add_object("Altar", box_mesh("Altar", [((0.0, 9.3, 0.5), (2.4, 1.0, 1.0)), ((0.0, 9.3, 0.05), (3.2, 1.6, 0.1))]),
               altar_material)

    # Benches: seat, back and two side panels, bevelled, arrayed along the nave and mirrored across the aisle.
    bench = box_mesh("Bench", [((-1.9, 0.0, 0.45), (2.2, 0.42, 0.06)),    # seat
                               ((-1.9, 0.23, 0.8), (2.2, 0.05, 0.5)),     # back
                               ((-3.0, 0.0, 0.45), (0.07, 0.5, 0.9)),     # outer side
                               ((-0.8, 0.0, 0.45), (0.07, 0.5, 0.9)),     # aisle side
                               ((-1.9, 0.1, 0.15), (2.2, 0.04, 0.1))])    # kneeler rail
    bench.materials.append(wood)
    benches = add_object("Benches", bench, location=(0.0, -8.0, 0.0))
    bevel = benches.modifiers.new("Bevel", "BEVEL")
    bevel.width, bevel.segments, bevel.limit_method = 0.015, 4, "NONE"
    array = benches.modifiers.new("Rows", "ARRAY")
    array.count = 14
    array.use_relative_offset, array.use_constant_offset = False, True
    array.constant_offset_displace = (0.0, 1.1, 0.0)
    mirror = benches.modifiers.new("Aisle", "MIRROR")
    mirror.use_axis = (True, False, False)
    for polygon in bench.polygons:
        polygon.use_smooth = False

    add_area_light("Window Light", (9.5, -1.5, 9.0), (3.0, 0.0, 3.5), "RECTANGLE", 6.0, 4.0,
                   color=(1.0, 0.92, 0.8), radiance=60.0)
    add_camera("Camera", (-1.2, -10.4, 2.1), (1.0, 4.0, 1.4), 75.0)
    # Slats and bevels thinner than a pixel: the paper's blocker map (4 shadow rays a pixel) leaked light
    # through them and the file once shipped 32 verification rays; the default silhouettes find every edge
    # by construction, so it ships LazyVis' defaults like every sample.


def _cylinder(mesh, radius: float, depth: float, segments: int) -> None:
    """A closed cylinder about local Z, centred on the origin (flat-shaded quads and two n-gons)."""
    ring = [(radius * math.cos(2 * math.pi * i / segments), radius * math.sin(2 * math.pi * i / segments))
            for i in range(segments)]
    vertices = [(x, y, -depth / 2) for x, y in ring] + [(x, y, depth / 2) for x, y in ring]
    faces = [(i, (i + 1) % segments, segments + (i + 1) % segments, segments + i) for i in range(segments)]
    faces += [tuple(reversed(range(segments))), tuple(range(segments, 2 * segments))]
    mesh.from_pydata(vertices, [], faces)
    mesh.validate()


def build_suzanne() -> None:
    """Suzanne (smooth, subdivision level 1) on a 10 x 10 m floor under a disk and an ellipse light.

    Level 1, not 2: every floor point in Suzanne's shadow has all the triangles of her near side that
    overlap a light as blockers (umbra detection needs one blocker covering the whole light), so the
    cost of pass 2 grows with the triangle count; level 2 is four times the triangles and about three
    times the render time for an image that differs only in the silhouette.
    """
    scene = _suzanne_on_a_floor(levels=1)
    add_area_light("Disk", (2.0, -2.5, 5.0), (0.0, 0.0, 0.8), "DISK", 1.2, color=(1.0, 0.9, 0.8), radiance=22.0)
    add_area_light("Ellipse", (-3.0, -1.0, 3.5), (0.0, 0.0, 0.8), "ELLIPSE", 1.8, 0.5,
                   color=(0.55, 0.7, 1.0), radiance=16.0)
    add_camera("Camera", (0.0, -5.2, 2.4), (0.0, 0.0, 0.85), 40.0)
    # Disk and ellipse lights become polygons of this many vertices with the same area (export.py).
    scene.lazyvis.disk_vertices = 64


def build_suzanne_dense(levels: int = 2) -> None:
    """Suzanne subdivided ``levels`` times (2: about 16,000 triangles, 3: about 63,000) under three lights.

    The stress case of the level-1 scene's docstring: its disk and ellipse, and a small low disk on her
    right whose sharper shadows of ear, brow and nose fall on her own face as well as on the floor.
    """
    scene = _suzanne_on_a_floor(levels)
    add_area_light("Disk", (2.0, -2.5, 5.0), (0.0, 0.0, 0.8), "DISK", 1.2, color=(1.0, 0.9, 0.8), radiance=22.0)
    add_area_light("Ellipse", (-3.0, -1.0, 3.5), (0.0, 0.0, 0.8), "ELLIPSE", 1.8, 0.5,
                   color=(0.55, 0.7, 1.0), radiance=16.0)
    add_area_light("Small Disk", (-2.4, -1.6, 1.5), (0.0, 0.0, 1.0), "DISK", 0.25, color=(1.0, 0.8, 0.6),
                   radiance=120.0)
    add_camera("Camera", (0.0, -5.2, 2.4), (0.0, 0.0, 0.85), 40.0)
    scene.lazyvis.disk_vertices = 64


def _suzanne_on_a_floor(levels: int):
    """A new 512 x 512 scene: a 10 x 10 m floor and Suzanne, smooth, subdivided ``levels`` times."""
    import bpy

    scene = new_scene(512, 512)
    floor = diffuse("Floor", (0.7, 0.7, 0.7))
    skin = diffuse("Suzanne", (0.8, 0.5, 0.3))
    add_object("Floor", box_mesh("Floor", [((0.0, 0.0, -0.05), (10.0, 10.0, 0.1))]), floor)
    bpy.ops.mesh.primitive_monkey_add(size=2.0, location=(0.0, 0.0, 1.0), rotation=(math.radians(-20), 0.0, 0.0))
    monkey = bpy.context.object
    monkey.name = "Suzanne"
    monkey.data.materials.append(skin)
    bpy.ops.object.shade_smooth()
    subsurf = monkey.modifiers.new("Subdivision", "SUBSURF")
    subsurf.levels, subsurf.render_levels = levels, levels
    return scene


def build_tree() -> None:
    """A trunk, four branches and 4,000 loose leaves in a 1 m crown over a ground, a square and a small disk."""
    import bpy
    from mathutils import Quaternion, Vector

    new_scene(512, 512)
    bark = diffuse("Bark", (0.35, 0.25, 0.15))
    add_object("Ground", box_mesh("Ground", [((0.0, 0.0, -0.05), (10.0, 10.0, 0.1))]),
               diffuse("Grass", (0.6, 0.6, 0.5)))
    trunk = bpy.data.meshes.new("Trunk")
    _cylinder(trunk, radius=0.08, depth=1.9, segments=16)
    add_object("Trunk", trunk, bark, location=(0.0, 0.0, 0.95))
    branch = bpy.data.meshes.new("Branch")  # one mesh shared by the four branches
    _cylinder(branch, radius=0.03, depth=0.8, segments=8)
    for index in range(4):
        direction = Vector((math.cos(index * math.pi / 2 + 0.4), math.sin(index * math.pi / 2 + 0.4), 1.0)).normalized()
        add_object(f"Branch {index}", branch, bark, location=Vector((0.0, 0.0, 1.6)) + 0.4 * direction,
                   rotation=direction.to_track_quat("Z", "Y").to_euler())

    # Leaves: separate quads 3-6 cm long, 0.6 as wide, uniformly rotated, uniform in a ball of radius 1 m.
    rng = random.Random(11)
    centre, vertices, faces = Vector((0.0, 0.0, 2.2)), [], []
    while len(faces) < 4000:
        offset = Vector((rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1)))
        if offset.length > 1.0:
            continue
        turn = Quaternion([rng.gauss(0.0, 1.0) for _ in range(4)]).normalized()
        length = rng.uniform(0.03, 0.06)
        corners = [(-0.5, -0.3), (0.5, -0.3), (0.5, 0.3), (-0.5, 0.3)]
        faces.append(tuple(range(len(vertices), len(vertices) + 4)))
        vertices += [tuple(centre + offset + turn @ Vector((u * length, v * length, 0.0))) for u, v in corners]
    leaves = bpy.data.meshes.new("Leaves")
    leaves.from_pydata(vertices, [], faces)
    leaves.validate()
    add_object("Leaves", leaves, diffuse("Leaf", (0.25, 0.5, 0.15)))

    # Both lights on the camera's right: the crown is lit where seen, its shadows fall to the left of the trunk.
    add_area_light("Square", (2.5, -1.5, 6.0), (0.0, 0.0, 2.2), "SQUARE", 1.0, color=(1.0, 0.95, 0.85), radiance=25.0)
    add_area_light("Small Disk", (3.0, 0.5, 6.5), (0.0, 0.0, 2.2), "DISK", 0.2, color=(0.7, 0.8, 1.0),
                   radiance=500.0)
    add_camera("Camera", (1.0, -6.5, 4.0), (-0.6, 0.3, 1.0), 50.0)


def build_chairs() -> None:
    """150 linked duplicates of one 6-box chair in 10 rows on the floor of a room's corner, two lights."""
    new_scene(512, 512)
    add_object("Floor", box_mesh("Floor", [((0.0, 0.0, -0.05), (12.0, 12.0, 0.1))]), diffuse("Floor", (0.7, 0.7, 0.7)))
    walls = [((-6.05, 0.0, 1.75), (0.1, 12.0, 3.5)), ((0.0, 6.05, 1.75), (12.2, 0.1, 3.5))]
    add_object("Walls", box_mesh("Walls", walls), diffuse("Wall", (0.8, 0.78, 0.72)))
    seat_and_back = [((0.0, 0.0, 0.455), (0.42, 0.42, 0.03)), ((0.0, 0.195, 0.69), (0.42, 0.03, 0.44))]
    legs = [((x, y, 0.22), (0.025, 0.025, 0.44)) for x in (-0.19, 0.19) for y in (-0.19, 0.19)]
    chair = box_mesh("Chair", seat_and_back + legs)  # 72 triangles, one mesh for all the chairs
    chair.materials.append(diffuse("Chair", (0.6, 0.35, 0.2)))
    rng = random.Random(5)
    for row in range(10):
        for seat in range(15):
            location = (-4.2 + 0.6 * seat + rng.uniform(-0.05, 0.05), -4.5 + 0.95 * row + rng.uniform(-0.05, 0.05), 0.0)
            add_object(f"Chair {row}-{seat:02d}", chair, location=location,
                       rotation=(0.0, 0.0, math.radians(rng.uniform(-8.0, 8.0))))
    # The chairs face -y, towards both lights and the camera; the low square light casts long leg shadows.
    add_area_light("Ceiling", (0.0, -1.0, 3.4), (0.0, -1.0, 0.0), "RECTANGLE", 5.0, 2.5, color=(1.0, 0.95, 0.9),
                   radiance=8.0)
    add_area_light("Square", (5.0, -5.0, 2.5), (0.0, 0.0, 0.0), "SQUARE", 0.5, color=(0.75, 0.85, 1.0), radiance=150.0)
    add_camera("Camera", (4.5, -8.5, 8.0), (-0.3, 0.3, 0.2), 50.0)


def add_lamp(name: str, kind: str, location, power: float, radius: float, color=(1.0, 1.0, 1.0), target=None,
             spot_size: float = 45.0, spot_blend: float = 0.15, angle: float = 0.0):
    """A point, spot or sun light (``kind`` "POINT", "SPOT", "SUN"): power in W (a sun's Strength in W/m^2),
    radius in m (a sun's angular diameter ``angle`` in degrees), spot size in degrees; spots and suns point
    their local -Z at ``target``. Hidden from camera rays (Blender's default for new lights)."""
    import bpy
    from mathutils import Vector

    data = bpy.data.lights.new(name, kind)
    data.energy = power
    data.color = color
    if kind == "SUN":
        data.angle = math.radians(angle)
    else:
        data.shadow_soft_size = radius
    if kind == "SPOT":
        data.spot_size = math.radians(spot_size)
        data.spot_blend = spot_blend
    light = add_object(name, data, location=location)
    if target is not None:
        light.rotation_euler = (Vector(target) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
    light.visible_camera = False
    return light


def build_room() -> None:
    """A living-room corner lit as users light one: a soft ceiling area light, a point lamp (Soft Falloff on)
    over a side table, a spot on the back wall and a small hard point light (radius 0) beside the sofa;
    Principled materials (Specular IOR Level 0 on the walls and floor, a glossy table top)."""
    new_scene(512, 384)
    floor = principled("Floor", (0.55, 0.45, 0.35), 0.5)
    wall = principled("Wall", (0.8, 0.78, 0.74), 0.5)
    for material in (floor, wall):
        node = next(n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
        node.inputs["Specular IOR Level"].default_value = 0.0
    add_object("Floor", box_mesh("Floor", [((0.0, 0.0, -0.05), (8.0, 8.0, 0.1))]), floor)
    add_object("Walls", box_mesh("Walls", [((0.0, 2.55, 1.4), (8.0, 0.1, 2.8)), ((-3.05, 0.0, 1.4), (0.1, 8.0, 2.8))]),
               wall)
    # The sofa's boxes overlap but share no face plane (coplanar overlapping faces shadow each other in
    # Cycles, by rounding).
    sofa = box_mesh("Sofa", [((-1.2, 1.7, 0.22), (2.2, 0.9, 0.44)), ((-1.2, 2.1, 0.62), (2.16, 0.2, 0.5)),
                             ((-2.25, 1.7, 0.55), (0.2, 0.96, 0.3)), ((-0.15, 1.7, 0.55), (0.2, 0.96, 0.3))])
    add_object("Sofa", sofa, principled("Fabric", (0.25, 0.35, 0.5), 0.9))
    legs = [((x, y, 0.2), (0.04, 0.04, 0.4)) for x in (-0.45, 0.45) for y in (-0.25, 0.25)]
    table = box_mesh("Table", [((0.0, 0.0, 0.42), (1.1, 0.65, 0.04))] + legs)
    add_object("Table", table, principled("Wood", (0.45, 0.25, 0.12), 0.25), location=(-1.1, 0.4, 0.0))
    side = box_mesh("Side Table", [((0.0, 0.0, 0.3), (0.45, 0.45, 0.6))])
    add_object("Side Table", side, principled("Side", (0.7, 0.7, 0.65), 0.6), location=(0.5, 1.8, 0.0))
    add_object("Vase", box_mesh("Vase", [((0.0, 0.0, 0.12), (0.12, 0.12, 0.24))]),
               principled("Clay", (0.7, 0.3, 0.2), 0.7), location=(-1.3, 0.45, 0.44))
    add_area_light("Ceiling", (-0.8, 0.6, 2.75), (-0.8, 0.6, 0.0), "SQUARE", 1.2, color=(1.0, 0.96, 0.9), radiance=6.0)
    add_lamp("Lamp", "POINT", (0.5, 1.8, 1.05), 60.0, 0.08, color=(1.0, 0.8, 0.55))
    add_lamp("Wall Spot", "SPOT", (0.8, -0.8, 2.6), 250.0, 0.05, color=(0.85, 0.9, 1.0), target=(-0.6, 2.5, 1.4),
             spot_size=40.0, spot_blend=0.25)
    add_lamp("Reading", "POINT", (-2.6, 1.2, 1.2), 15.0, 0.0)
    add_camera("Camera", (1.9, -3.2, 1.9), (-1.0, 1.3, 0.6), 62.0)


BUILDERS = {"floating_boxes": build_floating_boxes, "chapel": build_chapel, "suzanne": build_suzanne,
            "glossy": build_glossy, "textured": build_textured, "suzanne_dense": build_suzanne_dense,
            "suzanne_dense3": lambda: build_suzanne_dense(levels=3), "tree": build_tree, "chairs": build_chairs,
            "room": build_room}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"samples to build (default: all of {', '.join(SAMPLES)})")
    parser.add_argument("--output-dir", type=Path, default=HERE)
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in BUILDERS]
    if unknown:
        parser.error(f"unknown sample(s) {', '.join(unknown)}; choose from {', '.join(SAMPLES)}")

    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    import bpy  # noqa: F401  (Blender as a Python module)
    import lazyvis_addon

    lazyvis_addon.register()
    try:
        for name in args.names or SAMPLES:
            BUILDERS[name]()
            path = args.output_dir / f"{name}.blend"
            save(path)
            print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KB)")
    finally:
        lazyvis_addon.unregister()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
