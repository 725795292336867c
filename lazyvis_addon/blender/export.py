"""Blender depsgraph -> core ``Scene``: geometry, materials, lights, camera and world.

Everything is read with ``foreach_get`` into numpy and transformed in numpy; Python loops run over
objects, instances, material slots and lights, never over triangles or vertices.

Measured on Blender 5.0.1 (see tests/blender/test_export.py):
- ``depsgraph.object_instances`` hands the evaluated geometry of curves, surfaces, metaballs and text
  over as a separate *instance* whose object is of type MESH (``is_instance`` True, ``parent`` = the
  curve object). The curve object itself is listed too, with curve data. Reading only MESH objects
  therefore counts every triangle once; calling ``to_mesh()`` on the curve object as well would count
  its triangles twice.
- A render depsgraph leaves out objects with ``hide_render``; a viewport depsgraph (tests) does not, so
  ``hide_render`` is also checked here.
- ``Camera.view_frame`` matches ``screen_window`` below for every sensor fit, shift and pixel aspect.
- Materials: the Glossy BSDF's ``bl_idname`` is ``ShaderNodeBsdfAnisotropic`` (``nodes.new("ShaderNodeBsdfGlossy")``
  makes one), distributions BECKMANN, GGX, ASHIKHMIN_SHIRLEY, MULTI_GGX; the Principled BSDF's are GGX and
  MULTI_GGX. The Mix Shader's inputs are (Factor, Shader, Shader): Cycles weighs the first shader by
  1 - fac and the second by fac, fac clamped to [0, 1] (``svm_node_mix_closure``).
- UVs: ``loop_triangles.foreach_get("loops")`` gives the face corner of each triangle corner, in the order of
  its ``vertices``; ``uv_layers[name].uv.foreach_get("vector")`` the UV per face corner (``.data`` with "uv"
  gives the same numbers). Evaluated meshes keep their UV maps' names and ``active_render`` flags.
- Images: ``image.pixels`` is bottom row first; byte images read as exactly byte / 255. A file image loads
  when its ``size`` is read (``has_data`` turns True); a missing file leaves size (0, 0) and ``has_data``
  False. Setting a generated image's colour space regenerates (blanks) its pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.progress import Progress
from ..core.blackbody import blackbody_rgb
from ..core.emitters import group_mesh_emitters
from ..core.facing import MAX_SUN_HALF_ANGLE
from ..core.scene import (LOBE_DIFFUSE, LOBE_GLOSSY, LOBES_ALL, Camera, EmitterHulls, FacingLights, Lights,
                          Materials, Scene, SeenLights)
from ..core.texture import EXTENSIONS, INTERPOLATIONS, LINEAR_SPACES, SRGB_SPACES, ImageTexture
from ..tiles import border_window

DISK_VERTICES_DEFAULT = 32
# Cycles shades objects without a material with a grey diffuse surface.
DEFAULT_ALBEDO = (0.8, 0.8, 0.8)
DEFAULT_MATERIAL_NAME = "(no material)"

UNSUPPORTED_GEOMETRY = {"CURVES": "hair curves", "POINTCLOUD": "point cloud", "VOLUME": "volume",
                        "GREASEPENCIL": "Grease Pencil"}

# The Glossy BSDF is ShaderNodeBsdfAnisotropic since Blender 4.0 (nodes.new("ShaderNodeBsdfGlossy") makes one).
GLOSSY_IDNAMES = ("ShaderNodeBsdfAnisotropic", "ShaderNodeBsdfGlossy")

# What a readable material may ask for that LazyVis does not render: one warning per kind, listing materials.
ISSUE_MESSAGES = {
    "transmission": "Principled BSDF Transmission is not rendered (shaded as opaque)",
    "coat": "Principled BSDF Coat is not rendered",
    "sheen": "Principled BSDF Sheen is not rendered",
    "subsurface": "Principled BSDF Subsurface is not rendered (shaded as its diffuse base)",
    "thin_film": "Principled BSDF Thin Film is not rendered",
    "alpha": "Principled BSDF Alpha below 1 is rendered opaque",
    "diffuse_roughness": "diffuse roughness (Oren-Nayar) is rendered as roughness 0 (Lambert)",
    "anisotropy": "anisotropic reflection is rendered isotropic",
    "glossy_distribution": "Glossy BSDF Beckmann and Ashikhmin-Shirley distributions are rendered as GGX",
    "linked": "inputs fed by other nodes are read as their own constant value (only an Image Texture on "
              "the base colour is read)",
    "colour_fallback": "colours fed by nodes other than an Image Texture use the socket's own colour "
                       "(constant-colour fallback for other nodes)",
    "missing_image": "Image Textures without image data (no image, or a file that cannot be read) use the "
                     "socket's own colour",
    "image_source": "image sequences, movies and UDIM tiles are not read; these colours use the socket's own "
                    "colour",
    "texture_mapping": "Image Textures with a projection other than Flat, or a Vector input other than a UV "
                       "Map or Texture Coordinate UV, use the socket's own colour",
    "interpolation": "Cubic and Smart image interpolation are rendered as Linear",
    "extension": "image extensions other than Repeat, Extend, Clip and Mirror are rendered as Repeat",
    "colorspace": "image colour spaces other than sRGB, Linear Rec.709 and Non-Color are read as sRGB "
                  "(as Non-Color for data)",
}


# -- results ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TextureSource:
    """An Image Texture node on a base colour: the image, its lookup options and the UV map it reads
    (``uv_map`` "" = the mesh's active render UV map, as an unlinked Vector input does in Cycles).
    ``image`` is dropped (None) once the exporter has read its pixels: a record outlives the depsgraph."""

    image: object                   # bpy.types.Image or None
    image_name: str                 # name_full of the image
    interpolation: str              # "Closest" or "Linear"
    extension: str                  # one of core.texture.EXTENSIONS
    uv_map: str = ""

    @property
    def key(self) -> tuple[str, str, str]:
        """One core texture per image and options."""
        return (self.image_name, self.interpolation, self.extension)


@dataclass
class MaterialRecord:
    """One row of the material table, as read from the material's nodes.

    ``kind`` is "diffuse", "principled", "glossy", "mix" (a Diffuse and a Glossy BSDF), "emission",
    "no_nodes", "default", "black" or "viewport" (unreadable node setup, shown with the viewport colour).
    ``albedo`` is the base colour (the fallback colour when ``texture`` is set); ``emission`` the radiance
    of an emitting material (zero otherwise). The other values default to those of ``core.scene.Materials``
    (a diffuse row). ``issues`` are the kinds of what the nodes ask for and LazyVis does not render
    (keys of ``ISSUE_MESSAGES``); ``linked_inputs`` the sockets read as constants although linked.
    """

    name: str
    kind: str
    albedo: tuple[float, float, float]
    emission: tuple[float, float, float] = (0.0, 0.0, 0.0)
    metallic: float = 0.0
    roughness: float = 0.5
    specular_ior_level: float = 0.5
    ior: float = 1.5
    specular_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    glossy_colour: tuple[float, float, float] = (0.0, 0.0, 0.0)
    diffuse_weight: float = 1.0
    multiscatter: bool = True
    texture: TextureSource | None = None
    issues: tuple[str, ...] = ()
    linked_inputs: tuple[str, ...] = ()

    @property
    def is_emitter(self) -> bool:
        return max(self.emission) > 0.0

    @property
    def principled(self) -> bool:
        return self.kind == "principled"


@dataclass
class Export:
    """The core scene and what the Blender layer knows about it.

    Attributes
    ----------
    scene : Scene
    materials : list[MaterialRecord]    rows of ``scene.materials`` (emitting materials included: their
                                        triangles are lights, not surfaces)
    light_names : list[str]             object name of each light in ``scene.lights``, then ``scene.facing``,
                                        then ``scene.hulls`` (a mesh emitter's material name)
    counts : dict                       objects, instances, mesh triangles, emitter triangles, area lights
    """

    scene: Scene
    materials: list[MaterialRecord]
    light_names: list[str]
    counts: dict = field(default_factory=dict)


# -- pure maths (no bpy) ---------------------------------------------------------------------------------


def screen_window(projection: str, lens: float, sensor_width: float, sensor_height: float, sensor_fit: str,
                  ortho_scale: float, shift_x: float, shift_y: float, width: int, height: int,
                  pixel_aspect_x: float = 1.0, pixel_aspect_y: float = 1.0) -> np.ndarray:
    """(left, right, bottom, top) of the full frame as Blender's viewplane computes it.

    Perspective: on the plane z = -1 in camera space; orthographic: in camera-space units.
    The sensor (or ortho_scale) spans the image width for HORIZONTAL fit, the height for VERTICAL fit,
    and the longer side in aspect-corrected pixels for AUTO; lens shift is in units of that side.
    """
    y_correction = pixel_aspect_y / pixel_aspect_x
    aspect_width, aspect_height = width * pixel_aspect_x, height * pixel_aspect_y
    fit = sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if aspect_width >= aspect_height else "VERTICAL"
    if projection == "orthographic":
        span = ortho_scale
    else:
        sensor = sensor_height if sensor_fit == "VERTICAL" else sensor_width
        span = sensor / lens
    view_pixels = width if fit == "HORIZONTAL" else y_correction * height
    pixel = span / view_pixels
    half_x, half_y = 0.5 * width * pixel, 0.5 * y_correction * height * pixel
    dx, dy = shift_x * view_pixels * pixel, shift_y * view_pixels * pixel
    return np.array([-half_x + dx, half_x + dx, -half_y + dy, half_y + dy])


def ellipse_polygon(size_x: float, size_y: float, count: int) -> np.ndarray:
    """Regular ``count``-gon for an ellipse of diameters size_x, size_y in the local XY plane, scaled
    to the ellipse's area (pi/4 size_x size_y), ordered counter-clockwise about local -Z. (count, 3)."""
    angles = -2.0 * np.pi * np.arange(count) / count  # clockwise seen from +Z = counter-clockwise about -Z
    # Area of the regular n-gon inscribed in the unit circle is n/2 sin(2 pi/n); match pi.
    scale = math.sqrt(math.pi / (0.5 * count * math.sin(2.0 * math.pi / count)))
    return np.stack([0.5 * size_x * scale * np.cos(angles), 0.5 * size_y * scale * np.sin(angles),
                     np.zeros(count)], axis=1)


def rectangle_polygon(size_x: float, size_y: float) -> np.ndarray:
    """Rectangle of sides size_x, size_y centred in the local XY plane, counter-clockwise about -Z. (4, 3)."""
    hx, hy = 0.5 * size_x, 0.5 * size_y
    return np.array([[hx, hy, 0.0], [hx, -hy, 0.0], [-hx, -hy, 0.0], [-hx, hy, 0.0]])


def polygon_area_normal(vertices: np.ndarray) -> tuple[float, np.ndarray]:
    """Area and Newell normal (unnormalised, length 2 x area) of a planar polygon (V, 3)."""
    newell = np.cross(vertices, np.roll(vertices, -1, axis=0)).sum(axis=0)
    return 0.5 * float(np.linalg.norm(newell)), newell


def area_light_radiance(color, power: float, exposure: float, normalize: bool, area: float) -> np.ndarray:
    """Radiance of a Blender area light: colour P 2^exposure / (pi A), or without the area when not
    normalised (the project's radiometry note, measured against Cycles)."""
    value = np.asarray(color, dtype=np.float64)[:3] * power * 2.0 ** exposure / math.pi
    return value / area if normalize else value


# -- the exporter ----------------------------------------------------------------------------------------


def export_depsgraph(depsgraph, progress: Progress | None = None, *, camera_object=None,
                     resolution: tuple[int, int] | None = None,
                     disk_vertices: int = DISK_VERTICES_DEFAULT, camera: Camera | None = None) -> Export:
    """Read an evaluated depsgraph into a core ``Scene``.

    Parameters
    ----------
    depsgraph : bpy.types.Depsgraph     evaluated (render or viewport) depsgraph
    progress : Progress                 receives warnings (unsupported lights, materials, ...)
    camera_object : Object or None      the camera to render through (default: the scene camera)
    resolution : (W, H) or None         full-frame pixels; default from the render settings. The render
                                        engine passes its own ``resolution_x/y`` (Blender's rounding).
    disk_vertices : int                 polygon vertices for disk and ellipse area lights
    camera : Camera or None             the core camera itself (the Rendered viewport's view), instead of
                                        ``camera_object`` and ``resolution``

    Raises
    ------
    ValueError  no camera, unsupported camera, NaN or infinite coordinates (naming the object), ...
    """
    progress = progress or Progress()
    scene = depsgraph.scene
    render = scene.render
    if resolution is None:
        resolution = (render.resolution_x * render.resolution_percentage // 100,
                      render.resolution_y * render.resolution_percentage // 100)
    width, height = max(int(resolution[0]), 1), max(int(resolution[1]), 1)
    if disk_vertices < 3:
        raise ValueError(f"disk lights need at least 3 polygon vertices, not {disk_vertices}")

    if camera is None:
        camera = export_camera(camera_object or scene.camera, render, width, height)
    reader = _DepsgraphReader(progress, disk_vertices)
    reader.read(depsgraph)
    background = export_world(scene.world, progress)
    return reader.finish(camera, background)


def export_camera(camera_object, render, width: int, height: int) -> Camera:
    """Core camera of a Blender camera object at the given full-frame resolution."""
    if camera_object is None:
        raise ValueError("the scene has no camera: add one and make it the scene camera")
    data = camera_object.data
    if camera_object.type != "CAMERA":
        raise ValueError(f"'{camera_object.name}' is not a camera")
    if data.type not in ("PERSP", "ORTHO"):
        raise ValueError(f"camera '{camera_object.name}' is of type {data.type}; LazyVis renders perspective "
                         "and orthographic cameras only")
    matrix = np.array(camera_object.matrix_world, dtype=np.float64)
    if not np.isfinite(matrix).all():
        raise ValueError(f"camera '{camera_object.name}' has a NaN or infinite transform")
    # Blender ignores the camera object's scale: keep rotation and position only.
    lengths = np.linalg.norm(matrix[:3, :3], axis=0)
    if (lengths <= 0).any():
        raise ValueError(f"camera '{camera_object.name}' has a zero scale")
    matrix[:3, :3] /= lengths
    projection = "orthographic" if data.type == "ORTHO" else "perspective"
    window = screen_window(projection, data.lens, data.sensor_width, data.sensor_height, data.sensor_fit,
                           data.ortho_scale, data.shift_x, data.shift_y, width, height,
                           render.pixel_aspect_x, render.pixel_aspect_y)
    border = (render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y) \
        if render.use_border else None
    clip_start = max(float(data.clip_start), 0.0)
    clip_end = float(data.clip_end) if data.clip_end > clip_start else np.inf
    return Camera(matrix, width, height, projection, window, border_window(width, height, border), clip_start,
                  clip_end)


def export_world(world, progress: Progress) -> np.ndarray:
    """Background radiance (3,): a constant Background node's colour x strength, else ``world.color``."""
    if world is None:
        return np.zeros(3)
    tree = world.node_tree
    if tree is None:
        background = np.array(world.color[:3], dtype=np.float64)
    else:
        output = tree.get_output_node("CYCLES")
        node = _linked_node(output.inputs["Surface"]) if output is not None else None
        if output is None or not output.inputs["Surface"].is_linked:
            background = np.zeros(3)  # Cycles renders a world without a surface black
        elif node is not None and node.bl_idname == "ShaderNodeBackground" \
                and not node.inputs["Color"].is_linked and not node.inputs["Strength"].is_linked:
            background = np.array(node.inputs["Color"].default_value[:3]) * node.inputs["Strength"].default_value
        else:
            background = np.array(world.color[:3], dtype=np.float64)
            progress.warn(f"world '{world.name}': only a constant Background node is read; "
                          "showing its viewport colour instead")
    if background.max() > 0:
        progress.warn("the world is not black: LazyVis shows it behind the scene but does not light the "
                      "scene with it (Cycles does); use a black world to compare with Cycles")
    return background


# Node groups entered while following links: inner node (as_pointer) -> the group nodes around it, outermost
# first, so that an inner input fed by the Group Input reads the group node's input. A group used twice with
# different surroundings in one material makes its nodes ambiguous (None: unreadable, never a wrong guess).
_GROUP_PATH: dict = {}
_AMBIGUOUS = object()


def _linked_socket(socket):
    """The output socket feeding ``socket`` through reroutes and node groups (into the group's active Group
    Output, and from a Group Input out to the group node's input), or None (unlinked, muted, a loop, or an
    ambiguous group)."""
    path = _GROUP_PATH.get(socket.node.as_pointer(), ())
    if path is _AMBIGUOUS:
        return None
    path = list(path)
    seen = 0
    while seen < 64:
        seen += 1
        if not socket.is_linked:
            return None
        link = socket.links[0]
        if not link.is_valid or link.is_muted:
            return None
        node = link.from_node
        if node.mute:
            return None
        if node.bl_idname == "NodeReroute":
            socket = node.inputs[0]
            continue
        if node.bl_idname == "ShaderNodeGroup" and node.node_tree is not None:
            output = next((n for n in node.node_tree.nodes if n.bl_idname == "NodeGroupOutput"
                           and n.is_active_output), None)
            inner = None if output is None else next(
                (i for i in output.inputs if i.identifier == link.from_socket.identifier), None)
            if inner is None:
                return None
            path.append(node)
            socket = inner
            continue
        if node.bl_idname == "NodeGroupInput":
            if not path:
                return None
            group = path.pop()
            outer = next((i for i in group.inputs if i.identifier == link.from_socket.identifier), None)
            if outer is None:
                return None
            if not outer.is_linked:
                return outer  # an unlinked group input: its value is the group node's (``_socket_value``)
            socket = outer
            continue
        key = node.as_pointer()
        known = _GROUP_PATH.get(key)
        if known is not None and known is not _AMBIGUOUS and [g.as_pointer() for g in known] != \
                [g.as_pointer() for g in path]:
            _GROUP_PATH[key] = _AMBIGUOUS
            return None
        if known is None and path:
            _GROUP_PATH[key] = tuple(path)
        return link.from_socket
    return None


def _linked_node(socket):
    """The node feeding ``socket`` through reroutes, or None (unlinked, muted or a reroute loop)."""
    source = _linked_socket(socket)
    return None if source is None else source.node


def _socket_value(socket):
    """An input's constant value: its own when unlinked, a Value or RGB node's, a Blackbody node's colour
    (of a constant temperature) or an unlinked group input's when fed by one (through reroutes and groups);
    None when anything else feeds it."""
    if socket is None:
        return None
    if not socket.is_linked:
        return socket.default_value
    source = _linked_socket(socket)
    if source is None:
        return None
    if not source.is_output:  # an unlinked input of the group node around this one
        return source.default_value
    kind = source.node.bl_idname
    if kind in ("ShaderNodeValue", "ShaderNodeRGB"):
        return source.node.outputs[0].default_value
    if kind == "ShaderNodeBlackbody":
        temperature = _constant_value(source.node.inputs.get("Temperature"))
        return None if temperature is None else tuple(blackbody_rgb(temperature))
    return None


def _constant_value(socket):
    """A float input's value (``_socket_value``), or None."""
    value = _socket_value(socket)
    return None if value is None else float(value)


def _colour_of(value) -> tuple[float, float, float]:
    """RGB of a colour socket's value, or a float's grey (a Value node on a colour input)."""
    return (float(value),) * 3 if isinstance(value, (int, float)) else tuple(float(c) for c in value[:3])


def _unlinked(node, name: str):
    socket = node.inputs.get(name)
    return None if socket is None else _socket_value(socket)


class _Inputs:
    """Reads a shader node's inputs as constants, noting what LazyVis cannot honour."""

    def __init__(self, node) -> None:
        self.node = node
        self.issues: list[str] = []
        self.linked: list[str] = []
        self.texture: TextureSource | None = None

    def value(self, name: str, default: float = 0.0) -> float:
        """An unlinked float input (a linked one is read as its own value and reported)."""
        socket = self.node.inputs.get(name)
        if socket is None:  # an input this Blender version does not have
            return default
        value = _socket_value(socket)
        if value is None:
            self.linked.append(name)
            value = socket.default_value
        return float(value)

    def colour(self, name: str) -> tuple[float, float, float]:
        """An unlinked colour input, clamped to >= 0 as Cycles does (linked: its own value, reported)."""
        socket = self.node.inputs[name]
        value = _socket_value(socket)
        if value is None:
            self.linked.append(name)
            value = socket.default_value
        return tuple(max(c, 0.0) for c in _colour_of(value))

    def base_colour(self, name: str) -> tuple[float, float, float]:
        """A base colour: its constant, or an Image Texture read into ``self.texture`` (the constant is then
        the fallback); other nodes feeding it fall back to the socket's own colour."""
        socket = self.node.inputs[name]
        constant = tuple(float(c) for c in socket.default_value[:3])
        value = _socket_value(socket)
        if value is not None:
            return _colour_of(value)
        source = _linked_socket(socket)
        node = None if source is None else source.node
        if node is None or node.bl_idname != "ShaderNodeTexImage" or source.identifier != "Color":
            self.issues.append("colour_fallback")
            return constant
        texture, issues = read_image_texture(node)
        self.issues.extend(issues)
        self.texture = texture
        return constant

    def note_linked(self, *names: str) -> None:
        """Report the named inputs (normals, tangents, ...) when something feeds them."""
        for name in names:
            socket = self.node.inputs.get(name)
            if socket is not None and socket.is_linked and name not in self.linked:
                self.linked.append(name)

    def issue(self, kind: str, present: bool) -> None:
        if present:
            self.issues.append(kind)

    def record(self, name: str, kind: str, albedo, **values) -> "MaterialRecord":
        issues = list(self.issues) + (["linked"] if self.linked else [])
        return MaterialRecord(name, kind, tuple(albedo), texture=self.texture, issues=tuple(dict.fromkeys(issues)),
                              linked_inputs=tuple(self.linked), **values)


def read_image_texture(node) -> tuple[TextureSource | None, list[str]]:
    """The texture of an Image Texture node feeding a base colour, and the issue kinds met on the way.

    None (the caller keeps the socket's own colour) for a node without image data, an image sequence,
    movie or UDIM image, a projection other than Flat, or a Vector input other than a UV map.
    """
    issues = []
    image = node.image
    if image is None or image.source not in ("FILE", "GENERATED"):
        return None, ["missing_image" if image is None else "image_source"]
    # Reading the size loads a file image; a missing or unreadable file leaves it without data.
    width, height = image.size
    if width * height == 0 or not image.has_data:
        return None, ["missing_image"]
    if node.projection != "FLAT":
        return None, ["texture_mapping"]
    uv_map = ""
    vector = node.inputs["Vector"]
    if vector.is_linked:
        source = _linked_socket(vector)
        feeder = None if source is None else source.node
        if feeder is not None and feeder.bl_idname == "ShaderNodeUVMap":
            uv_map = feeder.uv_map
        elif not (feeder is not None and feeder.bl_idname == "ShaderNodeTexCoord" and source.identifier == "UV"):
            return None, ["texture_mapping"]
    interpolation = node.interpolation
    if interpolation not in INTERPOLATIONS:
        issues.append("interpolation")
        interpolation = "Linear"
    extension = node.extension
    if extension not in EXTENSIONS:
        issues.append("extension")
        extension = "REPEAT"
    if image.colorspace_settings.name not in SRGB_SPACES + LINEAR_SPACES and not image.is_float:
        issues.append("colorspace")
    return TextureSource(image, image.name_full, interpolation, extension, uv_map), issues


def _is_glossy(node) -> bool:
    return node.bl_idname in GLOSSY_IDNAMES


def _read_diffuse(node, inputs: _Inputs) -> tuple[float, float, float]:
    inputs.issue("diffuse_roughness", inputs.value("Roughness") > 0.0)
    inputs.note_linked("Normal")
    return inputs.base_colour("Color")


def _read_glossy(node, inputs: _Inputs) -> dict:
    """Glossy BSDF (Blender 4+: ``ShaderNodeBsdfAnisotropic``) as the fields of a record."""
    distribution = node.distribution
    inputs.issue("glossy_distribution", distribution not in ("GGX", "MULTI_GGX"))
    inputs.issue("anisotropy", inputs.value("Anisotropy") != 0.0)
    inputs.note_linked("Rotation", "Normal", "Tangent")
    return dict(glossy_colour=inputs.colour("Color"), roughness=inputs.value("Roughness", 0.5),
                multiscatter=distribution == "MULTI_GGX")


def read_material(material) -> MaterialRecord | None:
    """A material's row of the material table, or None when its node setup cannot be read.

    Read: Diffuse BSDF, Principled BSDF, Glossy BSDF, a Mix Shader of a Diffuse and a Glossy BSDF (or of an
    Emission and a Diffuse BSDF) with a constant factor, Emission (its Strength constant or from a Value node),
    and an Add Shader of an Emission and any of these; a base colour may come from an Image Texture. Node
    groups are followed (their Group Output, and Group Input values from the group node). What a readable node has
    that LazyVis does not render is listed in ``MaterialRecord.issues`` (the exporter warns once per kind).
    """
    if material is None:
        return MaterialRecord(DEFAULT_MATERIAL_NAME, "default", DEFAULT_ALBEDO)
    _GROUP_PATH.clear()  # group contexts are per material tree
    name = material.name
    tree = material.node_tree
    if tree is None:
        return MaterialRecord(name, "no_nodes", tuple(material.diffuse_color[:3]))
    output = tree.get_output_node("CYCLES")
    if output is None:
        return None
    surface = output.inputs["Surface"]
    if not surface.is_linked:
        return MaterialRecord(name, "black", (0.0, 0.0, 0.0))  # no closure: Cycles shades it black
    return _read_shader(name, _linked_node(surface))


def _read_shader(name: str, node, depth: int = 0) -> MaterialRecord | None:
    """The record of the closure ``node`` outputs (None: unreadable). An Add Shader of an Emission and a
    readable shader is that shader, emitting (how Cycles adds closures); Mix Shaders as ``_read_mix``."""
    if node is None or depth > 8:
        return None
    kind = node.bl_idname
    if kind == "ShaderNodeAddShader":
        parts = [_read_shader(name, _linked_node(socket), depth + 1) for socket in node.inputs[:2]]
        if any(p is None for p in parts):
            return None
        emitters = [p for p in parts if p.kind == "emission"]
        if len(emitters) == 2:
            return MaterialRecord(name, "emission", (0.0, 0.0, 0.0),
                                  tuple(a + b for a, b in zip(emitters[0].emission, emitters[1].emission)))
        if len(emitters) != 1:
            return None  # two reflecting closures added: not a material LazyVis has
        surface = next(p for p in parts if p.kind != "emission")
        return replace(surface, emission=tuple(a + b for a, b in zip(surface.emission, emitters[0].emission)))
    inputs = _Inputs(node)
    if kind == "ShaderNodeBsdfDiffuse":
        return inputs.record(name, "diffuse", _read_diffuse(node, inputs))
    if kind in GLOSSY_IDNAMES:
        return inputs.record(name, "glossy", (0.0, 0.0, 0.0), diffuse_weight=0.0, **_read_glossy(node, inputs))
    if kind == "ShaderNodeEmission":
        color, strength = _unlinked(node, "Color"), _constant_value(node.inputs.get("Strength"))
        if color is None or strength is None:
            return None
        return MaterialRecord(name, "emission", (0.0, 0.0, 0.0), tuple(np.array(_colour_of(color)) * strength))
    if kind == "ShaderNodeMixShader":
        return _read_mix(name, node)
    if kind == "ShaderNodeBsdfPrincipled":
        return _read_principled(name, node, inputs)
    return None


def _read_mix(name: str, node) -> MaterialRecord | None:
    """A Mix Shader of one Diffuse and one Glossy BSDF (either order) with an unlinked factor.

    Cycles weighs the first shader by 1 - fac and the second by fac, fac clamped to [0, 1]
    (``svm_node_mix_closure``).
    """
    factor = node.inputs[0]
    if factor.is_linked:
        return None
    fac = min(max(float(factor.default_value), 0.0), 1.0)
    first, second = _linked_node(node.inputs[1]), _linked_node(node.inputs[2])
    if first is None or second is None:
        return None
    if "ShaderNodeEmission" in (first.bl_idname, second.bl_idname):
        # An Emission mixed with a Diffuse BSDF (or another Emission): each weighed by its share.
        weights = (1.0 - fac, fac)
        records = [_read_shader(name, n) for n in (first, second)]
        if any(r is None or r.kind not in ("emission", "diffuse") or r.texture is not None for r in records):
            return None
        emission = tuple(sum(w * r.emission[k] for w, r in zip(weights, records)) for k in range(3))
        albedo = tuple(sum(w * r.albedo[k] for w, r in zip(weights, records) if r.kind == "diffuse") for k in range(3))
        if all(r.kind == "emission" for r in records):
            return MaterialRecord(name, "emission", (0.0, 0.0, 0.0), emission)
        return MaterialRecord(name, "diffuse", albedo, emission)
    if first.bl_idname == "ShaderNodeBsdfDiffuse" and _is_glossy(second):
        diffuse, glossy, diffuse_weight, glossy_weight = first, second, 1.0 - fac, fac
    elif _is_glossy(first) and second.bl_idname == "ShaderNodeBsdfDiffuse":
        diffuse, glossy, diffuse_weight, glossy_weight = second, first, fac, 1.0 - fac
    else:
        return None
    inputs = _Inputs(diffuse)
    albedo = _read_diffuse(diffuse, inputs)
    inputs.node = glossy
    values = _read_glossy(glossy, inputs)
    values["glossy_colour"] = tuple(glossy_weight * c for c in values["glossy_colour"])
    return inputs.record(name, "mix", albedo, diffuse_weight=diffuse_weight, **values)


# Principled inputs LazyVis does not render: (input, issue kind, value at which the input has no effect).
PRINCIPLED_UNSUPPORTED = (("Transmission Weight", "transmission", 0.0), ("Coat Weight", "coat", 0.0),
                          ("Sheen Weight", "sheen", 0.0), ("Subsurface Weight", "subsurface", 0.0),
                          ("Diffuse Roughness", "diffuse_roughness", 0.0), ("Anisotropic", "anisotropy", 0.0),
                          ("Thin Film Thickness", "thin_film", 0.0), ("Alpha", "alpha", 1.0))
# Principled inputs read into the record or only relevant to a lobe above.
PRINCIPLED_READ = {"Base Color", "Metallic", "Roughness", "IOR", "Specular IOR Level", "Specular Tint",
                   "Emission Color", "Emission Strength", "Weight"}


def _read_principled(name: str, node, inputs: _Inputs) -> MaterialRecord:
    """Principled BSDF: base colour, metallic, roughness, IOR, Specular IOR Level and Tint, distribution;
    the lobes LazyVis cannot render are left out (as if their weight were 0) and reported."""
    albedo = inputs.base_colour("Base Color")
    values = dict(metallic=inputs.value("Metallic"), roughness=inputs.value("Roughness", 0.5),
                  ior=inputs.value("IOR", 1.5), specular_ior_level=inputs.value("Specular IOR Level", 0.5),
                  specular_tint=inputs.colour("Specular Tint"), multiscatter=node.distribution == "MULTI_GGX")
    for socket_name, kind, neutral in PRINCIPLED_UNSUPPORTED:
        socket = node.inputs.get(socket_name)
        if socket is not None:
            inputs.issue(kind, float(socket.default_value) != neutral)
    strength = inputs.value("Emission Strength")
    emission_colour = inputs.colour("Emission Color")
    inputs.note_linked(*(socket.name for socket in node.inputs if socket.name not in PRINCIPLED_READ))
    emission = tuple(np.array(emission_colour) * strength) if strength > 0 else (0.0, 0.0, 0.0)
    return inputs.record(name, "principled", albedo, emission=emission, **values)


def image_texture(image, interpolation: str = "Linear", extension: str = "REPEAT") -> ImageTexture:
    """A core texture of a Blender image, holding what Cycles interpolates.

    ``image.pixels`` is bottom row first, as the core expects. Byte images come as ``byte / 255`` and
    are turned back into bytes, which ``ImageTexture.from_pixels`` premultiplies as Cycles does; float
    images are Blender's float buffer, already scene-linear and premultiplied, which Cycles copies as it
    is (``BlenderImageLoader``, colour space raw). Colour spaces the core does not know are read as sRGB
    (as Non-Color when the space is data).
    """
    width, height = image.size
    pixels = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(pixels)
    pixels = pixels.reshape(height, width, -1)
    space = image.colorspace_settings.name
    is_data = image.colorspace_settings.is_data
    if image.is_float:
        colorspace = "Non-Color" if is_data else "Linear Rec.709"
        alpha_mode = "NONE" if image.alpha_mode == "NONE" else "PREMUL"
    else:
        pixels = np.rint(pixels * 255.0).astype(np.uint8)
        colorspace = space if space in SRGB_SPACES + LINEAR_SPACES else ("Non-Color" if is_data else "sRGB")
        alpha_mode = image.alpha_mode
    return ImageTexture.from_pixels(pixels, colorspace, interpolation, extension, alpha_mode)


@dataclass
class _LocalMesh:
    """Triangles of one evaluated mesh in object space."""

    triangles: np.ndarray           # (T, 3, 3) float64
    slot: np.ndarray                # (T,) int64 material slot
    normals: np.ndarray | None      # (T, 3, 3) float64 corner normals, None when no face is smooth
    smooth: np.ndarray              # (T,) bool
    loops: np.ndarray               # (T, 3) int64 face corner (loop) of each triangle corner
    uv_maps: dict = field(default_factory=dict)  # UV map name -> (T, 3, 2) float64 or None (no such map)


class _DepsgraphReader:
    """Accumulates triangles, lights and materials over ``depsgraph.object_instances``."""

    def __init__(self, progress: Progress, disk_vertices: int) -> None:
        self.progress = progress
        self.disk_vertices = disk_vertices
        self.materials: list[MaterialRecord] = []
        self.material_ids: dict[str, int] = {}
        self.material_texture: list[int] = []  # row of self.textures per material, -1 for none
        self.textures: list[ImageTexture] = []
        self.texture_ids: dict[tuple, int] = {}
        self.unreadable: list[str] = []
        self.meshes: dict[int, _LocalMesh] = {}
        # triangles, material, normals, corner UVs (None when no material of the object is textured)
        # triangles, material, shading normals, corner UVs, Shadow Terminator Geometry Offset
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, float]] = []
        self.emitter_parts: list[tuple[np.ndarray, np.ndarray, int]] = []  # triangles, material, lobes
        self.light_polygons: list[np.ndarray] = []
        self.light_radiance: list[np.ndarray] = []
        self.light_names: list[str] = []
        self.light_shadows: list[bool] = []  # Cast Shadow of each area light
        self.light_spreads: list[float] = []  # and its Spread (radians)
        self.light_lobes: list[int] = []  # and the BSDF lobes it reaches (its object's Ray Visibility)
        self.facing: list[FacingLights] = []  # point, spot and sun lights
        self.facing_names: list[str] = []
        self.seen: list[SeenLights] = []  # lights with Ray Visibility > Camera on, drawn where the camera sees them
        self.skipped: dict[str, set[str]] = {}
        self.counts = {"objects": 0, "instances": 0, "mesh_triangles": 0, "emitter_triangles": 0,
                       "area_lights": 0}

    def skip(self, message: str, name: str) -> None:
        """Collect names under one warning message (one warning per message, however many objects)."""
        self.skipped.setdefault(message, set()).add(name)

    # -- traversal -----------------------------------------------------------------------------------
    def read(self, depsgraph) -> None:
        for instance in depsgraph.object_instances:  # one per object or instance, not per triangle
            self.progress.check_cancel()  # Esc between objects: a mesh's export is one array read
            obj = instance.object
            if not instance.show_self or _hidden_in_render(instance):
                continue
            kind = obj.type
            if kind == "MESH":
                self.add_mesh(obj, np.array(instance.matrix_world, dtype=np.float64))
            elif kind == "LIGHT":
                self.add_light(obj, np.array(instance.matrix_world, dtype=np.float64))
            elif kind in UNSUPPORTED_GEOMETRY:
                self.skip("objects of these types are not rendered", f"{obj.name} ({UNSUPPORTED_GEOMETRY[kind]})")
            else:
                continue
            self.counts["instances" if instance.is_instance else "objects"] += 1

    def material_index(self, material) -> int:
        key = DEFAULT_MATERIAL_NAME if material is None else material.name_full
        index = self.material_ids.get(key)
        if index is None:
            record = read_material(material)
            if record is None:
                self.unreadable.append(material.name)
                record = MaterialRecord(material.name, "viewport", tuple(material.diffuse_color[:3]))
            index = self.material_ids[key] = len(self.materials)
            self.materials.append(record)
            self.material_texture.append(self.texture_index(record.texture))
            if record.texture is not None:
                record.texture = replace(record.texture, image=None)
        return index

    def texture_index(self, source: TextureSource | None) -> int:
        if source is None:
            return -1
        index = self.texture_ids.get(source.key)
        if index is None:
            index = self.texture_ids[source.key] = len(self.textures)
            self.textures.append(image_texture(source.image, source.interpolation, source.extension))
        return index

    def local_mesh(self, mesh) -> _LocalMesh:
        key = mesh.as_pointer()
        cached = self.meshes.get(key)
        if cached is not None:
            return cached
        mesh.calc_loop_triangles()
        triangles = mesh.loop_triangles
        count = len(triangles)
        positions = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", positions)
        corners = np.empty(count * 3, np.int32)
        triangles.foreach_get("vertices", corners)
        loops = np.empty(count * 3, np.int32)
        triangles.foreach_get("loops", loops)
        slot = np.empty(count, np.int32)
        triangles.foreach_get("material_index", slot)
        smooth = np.empty(count, bool)
        triangles.foreach_get("use_smooth", smooth)
        normals = None
        if smooth.any():
            normals = np.empty(count * 9, np.float32)
            triangles.foreach_get("split_normals", normals)
            normals = normals.reshape(count, 3, 3).astype(np.float64)
        local = _LocalMesh(positions.reshape(-1, 3).astype(np.float64)[corners].reshape(count, 3, 3),
                           slot.astype(np.int64), normals, smooth, loops.reshape(count, 3).astype(np.int64))
        self.meshes[key] = local
        return local

    def add_mesh(self, obj, matrix: np.ndarray) -> None:
        local = self.local_mesh(obj.data)
        if len(local.triangles) == 0:
            return
        if not np.isfinite(local.triangles).all():
            bad = int((~np.isfinite(local.triangles)).any(axis=(1, 2)).sum())
            raise ValueError(f"object '{obj.name}' has NaN or infinite vertex coordinates "
                             f"({bad} of its {len(local.triangles)} triangles); fix or delete those vertices")
        if not np.isfinite(matrix).all():
            raise ValueError(f"object '{obj.name}' has a NaN or infinite transform")
        if not (obj.visible_camera and obj.visible_shadow):
            self.skip("Ray Visibility (camera, shadow) is not supported; these objects render as visible",
                      obj.name)
        slots = [self.material_index(slot.material) for slot in obj.material_slots] or [self.material_index(None)]
        lookup = np.array(slots, dtype=np.int64)
        material = lookup[np.clip(local.slot, 0, len(lookup) - 1)]
        uvs = self.corner_uvs(obj, local, material)

        rotation, translation = matrix[:3, :3], matrix[:3, 3]
        triangles = local.triangles @ rotation.T + translation
        determinant = np.linalg.det(rotation)
        normals = None
        if local.normals is not None:
            if abs(determinant) > 1e-300:
                normals = local.normals @ np.linalg.inv(rotation)  # (M^-T n)^T = n^T M^-1
                normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-300)
            else:  # flattened to a plane by a zero scale: flat shading
                normals = np.repeat(_geometric_normals(triangles)[:, None, :], 3, axis=1)
        if determinant < 0:
            # A mirroring transform turns the winding over; restore it so that the geometric normal and
            # the transformed shading normals agree (Cycles does the same for negative scale).
            triangles = triangles[:, [0, 2, 1]]
            normals = None if normals is None else normals[:, [0, 2, 1]]
            uvs = None if uvs is None else uvs[:, [0, 2, 1]]
        if normals is not None:
            flat = ~local.smooth
            normals[flat] = _geometric_normals(triangles[flat])[:, None, :]

        # Emitting triangles are both geometry (seen by the camera, blocking other lights, as in Cycles)
        # and two-sided triangle lights.
        emitting = np.array([self.materials[i].is_emitter for i in slots])[np.clip(local.slot, 0, len(slots) - 1)]
        lobes = _lobes_reached(obj)
        if emitting.any() and lobes:  # an emitter reaching no lobe lights nothing
            self.emitter_parts.append((triangles[emitting], material[emitting], lobes))
            self.counts["emitter_triangles"] += int(emitting.sum())
        if getattr(obj, "shadow_terminator_shading_offset", 0.0) > 0.0:
            self.skip("Shadow Terminator Shading Offset is not supported (the Geometry Offset is)", obj.name)
        self.parts.append((triangles, material, normals, uvs, float(getattr(obj, "shadow_terminator_geometry_offset",
                                                                            0.0))))
        self.counts["mesh_triangles"] += len(triangles)

    def corner_uvs(self, obj, local: _LocalMesh, material: np.ndarray) -> np.ndarray | None:
        """(T, 3, 2) texture coordinates of the triangles whose material is textured, each from the UV map
        its Image Texture reads (zeros elsewhere, and where the mesh lacks that map); None when no
        material of the object is textured."""
        maps = {}  # UV map name -> rows of self.materials reading it
        for row in np.unique(material):  # the object's materials: a handful
            texture = self.materials[row].texture
            if texture is not None and self.material_texture[row] >= 0:
                maps.setdefault(texture.uv_map, []).append(row)
        if not maps:
            return None
        uvs = np.zeros(local.triangles.shape[:2] + (2,))
        for name, rows in maps.items():
            corners = self.uv_map(obj.data, local, name)
            if corners is None:
                self.skip("objects without the UV map their Image Texture reads get texture coordinates (0, 0)",
                          f"{obj.name} ({name or 'no UV map'})")
                continue
            chosen = np.isin(material, rows)
            uvs[chosen] = corners[chosen]
        return uvs

    @staticmethod
    def uv_map(mesh, local: _LocalMesh, name: str) -> np.ndarray | None:
        """(T, 3, 2) float64 UVs of the named map ("" = the active render map) at the triangle corners,
        None when the mesh has no such map."""
        if name not in local.uv_maps:
            layers = mesh.uv_layers
            layer = layers.get(name) if name else next((uv for uv in layers if uv.active_render), None)
            corners = None
            if layer is not None:
                per_loop = np.empty(len(mesh.loops) * 2, np.float32)
                layer.uv.foreach_get("vector", per_loop)
                corners = per_loop.reshape(-1, 2).astype(np.float64)[local.loops]
            local.uv_maps[name] = corners
        return local.uv_maps[name]

    def add_light(self, obj, matrix: np.ndarray) -> None:
        light = obj.data
        name = obj.name
        if obj.visible_camera and light.type in ("AREA", "POINT", "SPOT", "SUN"):
            self.add_seen_light(obj, matrix)
        if not _lobes_reached(obj):  # Ray Visibility: neither Diffuse nor Glossy, as Cycles, lights nothing
            return
        if light.type in ("POINT", "SPOT", "SUN"):
            self.add_facing_light(obj, matrix)
            return
        if light.type != "AREA":
            self.skip("these lights are of a type LazyVis does not know and are ignored",
                      f"{name} ({light.type.lower()})")
            return
        if not np.isfinite(matrix).all():
            raise ValueError(f"light '{name}' has a NaN or infinite transform")
        if light.shape in ("SQUARE", "RECTANGLE"):
            size_y = light.size if light.shape == "SQUARE" else light.size_y
            local = rectangle_polygon(light.size, size_y)
        else:
            size_y = light.size if light.shape == "DISK" else light.size_y
            local = ellipse_polygon(light.size, size_y, self.disk_vertices)
        polygon = local @ matrix[:3, :3].T + matrix[:3, 3]
        area, newell = polygon_area_normal(polygon)
        extent = np.max(np.abs(polygon - polygon[0]))
        if not area > 1e-12 * max(extent, 1e-30) ** 2:
            self.skip("area lights of zero size are ignored", name)
            return
        # Emission leaves the light's local -Z side (Cycles uses -Z of the object's transform).
        if np.dot(newell, -matrix[:3, 2]) < 0:
            polygon = polygon[::-1]
        color = np.array(light.color[:3], dtype=np.float64)
        if light.use_temperature:
            color = color * np.array(light.temperature_color[:3])
        radiance = area_light_radiance(color * self.light_node_factor(light, name), light.energy, light.exposure,
                                       light.normalize, area)
        if not radiance.max() > 0:
            self.skip("area lights of zero power or black colour are ignored", name)
            return
        self.light_polygons.append(polygon)
        self.light_radiance.append(radiance)
        self.light_shadows.append(bool(light.use_shadow))
        self.light_spreads.append(float(light.spread) if abs(light.spread - math.pi) > 1e-6 else math.pi)
        self.light_lobes.append(_lobes_reached(obj))
        self.light_names.append(name)
        self.counts["area_lights"] += 1

    def add_seen_light(self, obj, matrix: np.ndarray) -> None:
        """A light with Ray Visibility > Camera on as a ``SeenLights`` row, drawn as Cycles 5.0.1 draws it
        (measured, ``core/seen_lights.py``): an area light's emitting side with its radiance and Spread, a
        lamp of radius above 0 as its disk (Soft Falloff) or sphere with a spot's cone, a sun of angle
        above 0 as its disc in the sky. Lamps of radius 0 and suns of angle 0 are seen by no ray."""
        light = obj.data
        if not np.isfinite(matrix).all():
            return  # add_light names it
        color = np.array(light.color[:3], dtype=np.float64)
        if getattr(light, "use_temperature", False):
            color = color * np.array(light.temperature_color[:3])
        factor = self.light_node_factor(light, obj.name)
        if light.type == "AREA":
            size_y = light.size if light.shape in ("SQUARE", "DISK") else light.size_y
            linear = matrix[:3, :3]
            u, v = linear @ np.array([0.5 * light.size, 0.0, 0.0]), linear @ np.array([0.0, 0.5 * size_y, 0.0])
            normal = np.cross(u, v)
            ellipse = light.shape in ("DISK", "ELLIPSE")
            area = float(np.linalg.norm(normal)) * (math.pi if ellipse else 4.0)
            if not area > 0:
                return  # add_light names it
            if np.dot(normal, -matrix[:3, 2]) < 0:  # emits along local -Z: u x v must point there
                v = -v
            radiance = area_light_radiance(color * factor, light.energy, light.exposure, light.normalize, area)
            spread = float(light.spread) if abs(light.spread - math.pi) > 1e-6 else math.pi
            self.seen.append(SeenLights.area(matrix[:3, 3], u, v, radiance, ellipse, spread))
            return
        power = color * light.energy * 2.0 ** getattr(light, "exposure", 0.0) * factor
        if light.type == "SUN":
            if light.angle > 0:
                self.seen.append(SeenLights.sun(matrix[:3, 2], 0.5 * min(float(light.angle), math.pi - 1e-6),
                                                power))
            return
        radius = float(light.shadow_soft_size)
        if not radius > 0:
            return
        spot = None
        if light.type == "SPOT":
            linear = matrix[:3, :3]
            if not abs(np.linalg.det(linear)) > 1e-18:
                return
            cone = FacingLights.point(matrix[:3, 3], radius, power).spot(np.linalg.inv(linear),
                                                                          float(light.spot_size),
                                                                          float(light.spot_blend))
            spot = (cone.spot_frame[0], float(cone.spot_cos_half[0]), float(cone.spot_smooth[0]))
        self.seen.append(SeenLights.lamp(matrix[:3, 3], radius, power / (4.0 * math.pi),
                                         bool(getattr(light, "use_soft_falloff", True)), spot))

    def light_node_factor(self, light, name: str) -> np.ndarray:
        """(3,) what a light's node tree multiplies its colour and power by, as Cycles 5.0 reads it (measured:
        an Emission node's Color times Strength feeding the Light Output). Other setups, and linked
        Emission inputs, are read as 1 with one warning."""
        tree = light.node_tree if getattr(light, "use_nodes", False) else None
        if tree is None:
            return np.ones(3)
        outputs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputLight"]
        output = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
        surface = output.inputs.get("Surface") if output is not None else None
        if surface is None or not surface.is_linked:
            return np.ones(3)
        node = surface.links[0].from_node
        if node.bl_idname != "ShaderNodeEmission":
            self.skip("light node setups other than an Emission node are read as plain lights", name)
            return np.ones(3)
        strength, color = _constant_value(node.inputs.get("Strength")), _socket_value(node.inputs.get("Color"))
        if strength is None or color is None:
            self.skip("light Emission inputs fed by nodes other than Value, RGB or Blackbody are read as plain "
                      "lights", name)
            return np.ones(3)
        return np.array(_colour_of(color), dtype=np.float64) * strength

    def add_facing_light(self, obj, matrix: np.ndarray) -> None:
        """A point, spot or sun light as a ``FacingLights`` row (the project's radiometry, measured against
        Cycles 5.0.1: intensity P / (4 pi) for lamps, a spot being the lamp times its cone; a sun's Strength
        is its irradiance)."""
        light = obj.data
        name = obj.name
        kind = light.type.lower()
        if not np.isfinite(matrix).all():
            self.skip("lights with a NaN or infinite transform are ignored", name)
            return
        color = np.array(light.color[:3], dtype=np.float64)
        if getattr(light, "use_temperature", False):
            color = color * np.array(light.temperature_color[:3])
        power = color * light.energy * 2.0 ** getattr(light, "exposure", 0.0) * self.light_node_factor(light, name)
        if not power.max() > 0:
            self.skip("lights of zero or negative power, or black colour, are ignored", name)
            return
        if light.type == "SUN":
            towards = matrix[:3, 2]  # a sun shines along its local -Z
            if not np.linalg.norm(towards) > 0:
                self.skip("suns with a zero-scale transform are ignored", name)
                return
            angle = float(light.angle)
            if angle > 2.0 * MAX_SUN_HALF_ANGLE:
                self.skip(f"suns wider than {math.degrees(2.0 * MAX_SUN_HALF_ANGLE):.0f} degrees are rendered at "
                          "that angle (less light than Cycles)", name)
            self.facing.append(FacingLights.sun(towards, angle, power))
        else:
            centre = matrix[:3, 3]
            radius = float(light.shadow_soft_size)
            lamp = FacingLights.point(centre, radius, power / (4.0 * math.pi),
                                      soft_falloff=bool(getattr(light, "use_soft_falloff", True)))
            if light.type == "SPOT":
                linear = matrix[:3, :3]
                if not abs(np.linalg.det(linear)) > 1e-18:
                    self.skip("spot lights with a zero-scale transform are ignored", name)
                    return
                lamp = lamp.spot(np.linalg.inv(linear), float(light.spot_size), float(light.spot_blend))
            self.facing.append(lamp)
        if not light.use_shadow:
            self.facing[-1] = self.facing[-1].without_shadows()
        lobes = _lobes_reached(obj)
        if lobes != LOBES_ALL:
            self.facing[-1] = self.facing[-1].reaching(lobes)
        self.facing_names.append(name)
        self.counts[f"{kind}_lights"] = self.counts.get(f"{kind}_lights", 0) + 1

    # -- assembly ------------------------------------------------------------------------------------
    def finish(self, camera: Camera, background: np.ndarray) -> Export:
        progress = self.progress
        if self.unreadable:
            progress.warn("materials whose node setup LazyVis cannot read are shown with their viewport "
                          "colour: " + ", ".join(sorted(set(self.unreadable))))
        for kind, message in ISSUE_MESSAGES.items():
            names = sorted(m.name + (f" ({', '.join(m.linked_inputs)})" if kind == "linked" else "")
                           for m in self.materials if kind in m.issues)
            if names:
                progress.warn(f"{message}: {', '.join(names)}")
        for message, names in self.skipped.items():
            progress.warn(f"{message}: {', '.join(sorted(names))}")

        if self.parts:
            triangles = np.concatenate([p[0] for p in self.parts])
            material_index = np.concatenate([p[1] for p in self.parts])
        else:
            triangles, material_index = np.zeros((0, 3, 3)), np.zeros(0, np.int64)
        normals = None
        if any(p[2] is not None for p in self.parts):
            normals = np.concatenate([p[2] if p[2] is not None else
                                      np.repeat(_geometric_normals(p[0])[:, None, :], 3, axis=1)
                                      for p in self.parts])
        corner_uvs = None
        if any(p[3] is not None for p in self.parts):
            corner_uvs = np.concatenate([p[3] if p[3] is not None else np.zeros(p[0].shape[:2] + (2,))
                                         for p in self.parts])
        # Cycles' Shadow Terminator Geometry Offset lifts shadow rays off smooth-shaded triangles only.
        terminator_offset = None
        if normals is not None and any(p[4] > 0 and p[2] is not None for p in self.parts):
            terminator_offset = np.concatenate([np.full(len(p[0]), p[4] if p[2] is not None else 0.0)
                                                for p in self.parts])
        lights, hulls, names, hull_names = self.lights()
        scene = Scene(triangles, material_index, self.material_table(), lights, camera, background, normals,
                      corner_uvs, list(self.textures), terminator_offset, FacingLights.concat(self.facing), hulls,
                      SeenLights.concat(self.seen))
        names = names + list(self.facing_names) + hull_names
        return Export(scene, list(self.materials), names, dict(self.counts))

    def material_table(self) -> Materials:
        rows = self.materials

        def column(name: str, tail: tuple[int, ...] = ()):
            return np.array([getattr(m, name) for m in rows], dtype=np.float64).reshape((len(rows),) + tail)

        return Materials(column("albedo", (3,)), column("emission", (3,)), np.array(self.material_texture, np.int64),
                         diffuse_weight=column("diffuse_weight"), principled=[m.principled for m in rows],
                         metallic=column("metallic"), roughness=column("roughness"), ior=column("ior"),
                         specular_level=column("specular_ior_level"), specular_tint=column("specular_tint", (3,)),
                         glossy_colour=column("glossy_colour", (3,)), multiscatter=[m.multiscatter for m in rows])

    def lights(self) -> tuple[Lights, EmitterHulls, list[str], list[str]]:
        """Area lights (one-sided polygons), then mesh emitters grouped as the core does
        (``emitters.group_mesh_emitters``: one polygon per planar convex emitter, one hull per closed
        convex one, two-sided triangles otherwise), padded to V; and the names of lights and hulls."""
        names = list(self.light_names)
        count = len(self.light_polygons)
        vmax = max([3] + [len(p) for p in self.light_polygons])
        vertices = np.empty((count, vmax, 3))
        vertex_count = np.empty(count, np.int64)
        for index, polygon in enumerate(self.light_polygons):  # area lights: a handful
            vertices[index, :len(polygon)] = polygon
            vertices[index, len(polygon):] = polygon[-1]
            vertex_count[index] = len(polygon)
        area = Lights(vertices, vertex_count, np.reshape(np.array(self.light_radiance, np.float64), (-1, 3)),
                      np.zeros(count, bool), np.array(self.light_shadows, bool),
                      np.array(self.light_spreads, np.float64), np.array(self.light_lobes, np.int64))
        if not self.emitter_parts:
            return area, EmitterHulls.empty(), names, []
        # One emitter per object instance and material: one radiance, one mesh surface.
        emission = np.array([m.emission for m in self.materials]).reshape(-1, 3)
        triangles = np.concatenate([p[0] for p in self.emitter_parts])
        material = np.concatenate([p[1] for p in self.emitter_parts])
        instance = np.repeat(np.arange(len(self.emitter_parts)), [len(p[0]) for p in self.emitter_parts])
        _, part = np.unique(instance * len(self.materials) + material, return_inverse=True)
        lobes = np.repeat([p[2] for p in self.emitter_parts], [len(p[0]) for p in self.emitter_parts])
        emitters = Lights(triangles, np.full(len(triangles), 3, np.int64), emission[material],
                          np.ones(len(triangles), bool), lobes=lobes)
        grouped, hulls, light_source, hull_source = group_mesh_emitters(emitters, part.reshape(-1))
        self.counts["emitter_lights"] = len(grouped)
        self.counts["emitter_hulls"] = len(hulls)
        names.extend(self.materials[i].name for i in material[light_source])
        return (Lights.concat([area, grouped]), hulls, names,
                [self.materials[i].name for i in material[hull_source]])


def _lobes_reached(obj) -> int:
    """The BSDF lobes an emitting object's light reaches (``scene.LOBE_*`` bits): its Ray Visibility >
    Diffuse and Glossy, which Cycles honours for lights and mesh emitters alike (measured: either off, that
    lobe gets none of its light)."""
    return (LOBE_DIFFUSE if getattr(obj, "visible_diffuse", True) else 0) | \
        (LOBE_GLOSSY if getattr(obj, "visible_glossy", True) else 0)


def _geometric_normals(triangles: np.ndarray) -> np.ndarray:
    """Unit normals (T, 3) of triangles (T, 3, 3) by their winding (zero-area ones get a zero vector)."""
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    return cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)


def _hidden_in_render(instance) -> bool:
    """``hide_render`` of the object or of the object instancing it (render depsgraphs already skip them)."""
    if instance.object.original.hide_render:
        return True
    parent = instance.parent
    return bool(instance.is_instance and parent is not None and parent.original.hide_render)
