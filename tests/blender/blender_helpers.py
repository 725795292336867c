"""Helpers that build small Blender scenes and read rendered EXRs back (imported by the tests)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def add_camera(scene, location=(0.0, -6.0, 4.0), rotation=(math.radians(56), 0.0, 0.0), **data):
    bpy.ops.object.camera_add(location=location, rotation=rotation)
    camera = bpy.context.object
    for key, value in data.items():
        setattr(camera.data, key, value)
    scene.camera = camera
    return camera


def add_area_light(location=(0.0, 0.0, 3.0), rotation=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0), name=None,
                   **data):
    return add_light("AREA", location, rotation, scale, name, **data)


def add_light(kind, location=(0.0, 0.0, 3.0), rotation=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0), name=None, **data):
    """A light of ``kind`` ("AREA", "POINT", "SPOT", "SUN") with its data properties set."""
    bpy.ops.object.light_add(type=kind, location=location, rotation=rotation)
    light = bpy.context.object
    light.scale = scale
    if name:
        light.name = name
    for key, value in data.items():
        setattr(light.data, key, value)
    return light


def node_material(name, shader="ShaderNodeBsdfDiffuse", **inputs):
    """A material whose output is fed by one shader node with the given unlinked inputs."""
    material = bpy.data.materials.new(name)
    tree = material.node_tree
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    for node in [n for n in tree.nodes if n != output]:
        tree.nodes.remove(node)
    node = tree.nodes.new(shader)
    for key, value in inputs.items():
        socket = node.inputs[key.replace("_", " ")]
        socket.default_value = (*value, 1.0) if isinstance(value, tuple) and len(value) == 3 else value
    tree.links.new(node.outputs[0], output.inputs["Surface"])
    return material


def assign(obj, *materials):
    for material in materials:
        obj.data.materials.append(material)
    return obj


def read_exr(path):
    """{channel group name: pixels (H, W[, C]) float32, row 0 at the top} of every part of an EXR."""
    import OpenEXR

    channels = {}
    with OpenEXR.File(str(path)) as exr:
        for part in exr.parts:
            for name, channel in part.channels.items():
                channels[name] = np.array(channel.pixels, dtype=np.float32)
    return channels


def render_to_exr(scene, path, multilayer=False):
    """Render ``scene`` with its engine and write a 32-bit float EXR; returns its channels."""
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE" if multilayer else "IMAGE"
    if not multilayer:
        settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    scene.render.use_file_extension = False
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    return read_exr(path)


def cycles_reference_tool():
    """tools/make_cycles_reference.py as a module (configure_cycles, configure_output, main)."""
    spec = importlib.util.spec_from_file_location("make_cycles_reference", ROOT / "tools" / "make_cycles_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
