"""Image textures (lazyvis_addon.core.texture): the sRGB curve, Closest and Linear lookups against values
computed by hand on tiny images, the four extension modes at and beyond the edges, alpha association,
barycentric interpolation of corner attributes, and a measurement against Cycles itself.

The Cycles test runs Blender (bpy) in a subprocess so that this process never imports bpy. It renders a
plane whose Emission colour is an Image Texture, through an orthographic camera with
``filter_width = 0.01`` (every sample within 0.01 px of the pixel centre), and compares each pixel with
``ImageTexture.lookup`` at the UV of the pixel centre. The image is 4 x 2 texels of random bytes and the
UVs run from -0.5 to 1.5, so texel edges and texel centres fall on pixel edges and every mode is seen
inside, at and beyond the image's borders.
"""

import importlib.util
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from lazyvis_addon.core import demo_scenes
from lazyvis_addon.core.surface import shade_hits
from lazyvis_addon.core.texture import (
    ImageTexture,
    interpolate_corner_attribute,
    linear_to_srgb,
    srgb_to_linear,
)

# A 3 x 2 Non-Color image, bottom row first as in Blender's image.pixels: texel (col, row) has
# red = col, green = row, blue = 10 * row + col, alpha 1.
COLS, ROWS = 3, 2
RAMP = np.zeros((ROWS, COLS, 4))
RAMP[..., 0] = np.arange(COLS)[None, :]
RAMP[..., 1] = np.arange(ROWS)[:, None]
RAMP[..., 2] = 10 * np.arange(ROWS)[:, None] + np.arange(COLS)[None, :]
RAMP[..., 3] = 1.0


def ramp(interpolation="Closest", extension="REPEAT"):
    return ImageTexture.from_pixels(RAMP, "Non-Color", interpolation, extension)


def at(texture, u, v):
    """RGBA (4,) at one UV."""
    return texture.lookup(np.array([[u, v]]))[0]


def texel(col, row):
    return RAMP[row, col]


# -- sRGB -------------------------------------------------------------------------------------------

def test_srgb_decode_values():
    assert srgb_to_linear(0.5) == pytest.approx(0.21404114048223255, abs=1e-15)
    assert srgb_to_linear(1.0) == pytest.approx(1.0, abs=1e-15)
    assert srgb_to_linear(0.0) == 0.0
    assert srgb_to_linear(0.02) == pytest.approx(0.02 / 12.92)
    assert srgb_to_linear(-0.3) == 0.0  # Cycles clamps negatives
    # The two pieces meet at 0.04045 (continuous to ~1e-8: the standard's rounded constants).
    assert srgb_to_linear(0.04045 - 1e-12) == pytest.approx(srgb_to_linear(0.04045), abs=1e-7)
    encoded = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(encoded)), encoded, atol=1e-12)


# -- Closest and Linear on hand-computed values -------------------------------------------------------

def test_bottom_left_origin_and_closest_texels():
    texture = ramp("Closest")
    assert np.array_equal(at(texture, 0.01, 0.01), texel(0, 0))  # bottom-left corner: row 0, col 0
    assert np.array_equal(at(texture, 0.99, 0.01), texel(2, 0))  # bottom-right
    assert np.array_equal(at(texture, 0.01, 0.99), texel(0, 1))  # top-left
    assert np.array_equal(at(texture, 0.5, 0.75), texel(1, 1))
    # Texel edges at multiples of 1/W: [1/3, 2/3) is column 1.
    assert at(texture, 1 / 3 + 1e-9, 0.2)[0] == 1.0
    assert at(texture, 1 / 3 - 1e-9, 0.2)[0] == 0.0
    # Rows given top first are flipped to Blender's order.
    flipped = ImageTexture.from_pixels(RAMP[::-1], "Non-Color", "Closest", top_row_first=True)
    assert np.array_equal(flipped.texels, texture.texels)


def test_linear_texel_centres_and_bilinear_weights():
    texture = ramp("Linear", "EXTEND")
    # At a texel centre ((col + 0.5) / W, (row + 0.5) / H) the texel itself.
    for col in range(COLS):
        for row in range(ROWS):
            np.testing.assert_allclose(at(texture, (col + 0.5) / COLS, (row + 0.5) / ROWS), texel(col, row),
                                       atol=1e-12)
    # Between centres: x = u W - 0.5 = 0.75 -> 0.25 of column 0, 0.75 of column 1;
    # y = v H - 0.5 = 0.2 -> 0.8 of row 0, 0.2 of row 1.
    u, v = 1.25 / COLS, 0.7 / ROWS
    expected = (0.8 * (0.25 * texel(0, 0) + 0.75 * texel(1, 0))
                + 0.2 * (0.25 * texel(0, 1) + 0.75 * texel(1, 1)))
    np.testing.assert_allclose(at(texture, u, v), expected, atol=1e-12)
    assert at(texture, u, v)[2] == pytest.approx(0.8 * 0.75 + 0.2 * 10.75)


def test_linear_srgb_interpolates_encoded_values():
    """Cycles interpolates sRGB images encoded and decodes after: halfway between black and white
    is srgb_to_linear(0.5), not 0.5."""
    pixels = np.array([[[0, 0, 0, 255], [255, 255, 255, 255]]], dtype=np.uint8)
    texture = ImageTexture.from_pixels(pixels, "sRGB", "Linear", "EXTEND")
    np.testing.assert_allclose(at(texture, 0.5, 0.5), [0.21404114048223255] * 3 + [1.0], atol=1e-7)
    np.testing.assert_allclose(texture.linear_pixels[0, :, 0], [0.0, 1.0], atol=1e-7)
    linear = ImageTexture.from_pixels(pixels, "Linear Rec.709", "Linear", "EXTEND")
    np.testing.assert_allclose(at(linear, 0.5, 0.5), [0.5, 0.5, 0.5, 1.0], atol=1e-7)


# -- extension modes at and beyond the edges ----------------------------------------------------------

@pytest.mark.parametrize("extension, columns", [
    # Closest lookups in columns -4..6 of a 3-wide image.
    ("REPEAT", [2, 0, 1, 2, 0, 1, 2, 0, 1, 2, 0]),
    ("EXTEND", [0, 0, 0, 0, 0, 1, 2, 2, 2, 2, 2]),
    ("MIRROR", [2, 2, 1, 0, 0, 1, 2, 2, 1, 0, 0]),
])
def test_closest_wraps(extension, columns):
    texture = ramp("Closest", extension)
    cols = np.arange(-4, 7)
    values = texture.lookup(np.stack([(cols + 0.5) / COLS, np.full(len(cols), 0.25)], axis=1))
    assert np.array_equal(values[:, 0], columns)


def test_closest_clip_is_transparent_black_outside():
    texture = ramp("Closest", "CLIP")
    outside = np.array([[-0.01, 0.5], [1.0, 0.5], [0.5, -1e-9], [0.5, 1.0], [3.2, -7.0]])
    assert np.array_equal(texture.lookup(outside), np.zeros((5, 4)))
    assert np.array_equal(at(texture, 0.0, 0.0), texel(0, 0))  # the lower edges are inside


def test_exact_edges_follow_floor():
    """u = 1 is column W (outside): REPEAT wraps to column 0, EXTEND clamps to W - 1."""
    assert at(ramp("Closest", "REPEAT"), 1.0, 0.25)[0] == 0.0
    assert at(ramp("Closest", "EXTEND"), 1.0, 0.25)[0] == 2.0
    assert at(ramp("Closest", "MIRROR"), 1.0, 0.25)[0] == 2.0


def test_linear_at_the_border():
    a, c = texel(0, 0), texel(2, 0)
    v = 0.5 / ROWS  # row 0's centre line: no vertical blending
    # u = 0: halfway between column -1 and column 0.
    np.testing.assert_allclose(at(ramp("Linear", "REPEAT"), 0.0, v), 0.5 * (a + c), atol=1e-12)
    np.testing.assert_allclose(at(ramp("Linear", "EXTEND"), 0.0, v), a, atol=1e-12)
    np.testing.assert_allclose(at(ramp("Linear", "MIRROR"), 0.0, v), a, atol=1e-12)
    clip = ramp("Linear", "CLIP")
    np.testing.assert_allclose(at(clip, 0.0, v), 0.5 * a, atol=1e-12)  # alpha 0.5 too
    np.testing.assert_allclose(at(clip, 1.0, v), 0.5 * c, atol=1e-12)
    assert np.array_equal(at(clip, -0.5 / COLS, v), np.zeros(4))  # half a texel out: nothing left
    assert np.array_equal(at(clip, -3.0, 5.0), np.zeros(4))
    # Far away REPEAT is periodic, MIRROR has period 2 and is symmetric about the edges.
    repeat, mirror = ramp("Linear", "REPEAT"), ramp("Linear", "MIRROR")
    np.testing.assert_allclose(at(repeat, 0.37 + 5, 0.61 - 3), at(repeat, 0.37, 0.61), atol=1e-9)
    np.testing.assert_allclose(at(mirror, 0.37 + 4, 0.61 - 2), at(mirror, 0.37, 0.61), atol=1e-9)
    np.testing.assert_allclose(at(mirror, -0.37, 0.61), at(mirror, 0.37, 0.61), atol=1e-9)
    np.testing.assert_allclose(at(mirror, 1.2, 0.61), at(mirror, 0.8, 0.61), atol=1e-9)


def test_non_finite_uvs_read_zero():
    values = ramp("Linear").lookup(np.array([[np.nan, 0.5], [0.5, np.inf], [0.5, 0.25]]))
    assert np.array_equal(values[:2], np.zeros((2, 4)))
    assert values[2, 3] == 1.0


# -- alpha and validation -----------------------------------------------------------------------------

def test_alpha_association():
    straight = np.array([[[0.8, 0.4, 0.2, 0.5]]])
    np.testing.assert_allclose(ImageTexture.from_pixels(straight, "sRGB").texels[0, 0], [0.4, 0.2, 0.1, 0.5])
    np.testing.assert_allclose(ImageTexture.from_pixels(straight, "Non-Color").texels[0, 0], straight[0, 0])
    np.testing.assert_allclose(ImageTexture.from_pixels(straight, "sRGB", alpha_mode="CHANNEL_PACKED").texels[0, 0],
                               straight[0, 0])
    np.testing.assert_allclose(ImageTexture.from_pixels(straight, "sRGB", alpha_mode="NONE").texels[0, 0],
                               [0.8, 0.4, 0.2, 1.0])
    # Bytes are premultiplied in integers, truncating, as Cycles' byte loader does: 200 * 100 // 255 = 78.
    byte = np.array([[[200, 255, 1, 100]]], dtype=np.uint8)
    np.testing.assert_allclose(ImageTexture.from_pixels(byte, "sRGB").texels[0, 0] * 255, [78, 100, 0, 100],
                               atol=1e-4)
    # One channel is grey with alpha 1.
    grey = ImageTexture.from_pixels(np.full((2, 2), 0.25), "Non-Color")
    np.testing.assert_allclose(grey.texels[0, 0], [0.25, 0.25, 0.25, 1.0])


@pytest.mark.parametrize("kwargs", [dict(colorspace="ACEScg"), dict(alpha_mode="PREMULTIPLIED"),
                                    dict(interpolation="Cubic"), dict(extension="WRAP")])
def test_unsupported_settings_are_named(kwargs):
    with pytest.raises(ValueError, match=str(next(iter(kwargs.values())))):
        ImageTexture.from_pixels(RAMP, **{"colorspace": "sRGB", **kwargs})


# -- corner attributes --------------------------------------------------------------------------------

def test_corner_attribute_uses_the_shade_hits_barycentrics(np_rng):
    scene = demo_scenes.floating_boxes(resolution=8, n_boxes=4)
    n = 200
    index_triangle = np_rng.integers(-1, len(scene.triangles), n)
    u = np_rng.uniform(0, 1, n)
    v = np_rng.uniform(0, 1, n) * (1 - u)
    directions = np.tile([0.0, 0.0, -1.0], (n, 1))
    surface = shade_hits(scene, np.zeros((n, 3)), directions, index_triangle, u, v, 10.0)
    positions = interpolate_corner_attribute(scene.triangles, index_triangle, u, v)
    np.testing.assert_allclose(positions, surface.position, atol=1e-12)
    assert np.array_equal(positions[index_triangle < 0], np.zeros(((index_triangle < 0).sum(), 3)))


def test_corner_attribute_at_the_corners():
    corner_uvs = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], [[0.2, 0.3], [0.4, 0.3], [0.2, 0.9]]])
    index = np.array([1, 1, 1, 1, 0])
    u = np.array([0.0, 1.0, 0.0, 1 / 3, 0.25])
    v = np.array([0.0, 0.0, 1.0, 1 / 3, 0.5])
    expected = np.array([[0.2, 0.3], [0.4, 0.3], [0.2, 0.9], [0.8 / 3, 1.5 / 3], [0.25, 0.5]])
    np.testing.assert_allclose(interpolate_corner_attribute(corner_uvs, index, u, v), expected, atol=1e-12)


# -- against Cycles -----------------------------------------------------------------------------------

CYCLES_SCRIPT = textwrap.dedent('''
    """Render an Emission plane coloured by an Image Texture, one render per case; save (K, S, S, 4)."""
    import json
    import sys

    import bpy
    import numpy as np
    import OpenEXR

    data = np.load(sys.argv[1])
    cases = json.loads(open(sys.argv[2]).read())
    out = sys.argv[3]
    size = int(data["size"])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.world = None
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.samples = int(data["samples"])
    cycles.use_adaptive_sampling = False
    cycles.use_denoising = False
    cycles.max_bounces = 0
    cycles.filter_width = 0.01
    cycles.seed = 0
    render = scene.render
    render.resolution_x = render.resolution_y = size
    render.resolution_percentage = 100
    render.use_compositing = False
    render.use_sequencer = False
    render.use_file_extension = False
    render.image_settings.file_format = "OPEN_EXR"
    render.image_settings.color_depth = "32"
    camera = bpy.data.cameras.new("camera")
    camera.type = "ORTHO"
    camera.ortho_scale = 2.0  # the view is world [-1, 1]^2
    camera_object = bpy.data.objects.new("camera", camera)
    camera_object.location = (0.0, 0.0, 1.0)
    scene.collection.objects.link(camera_object)
    scene.camera = camera_object
    mesh = bpy.data.meshes.new("plane")
    mesh.from_pydata([(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [], [(0, 1, 2, 3)])
    uv_layer = mesh.uv_layers.new(name="UVMap")
    plane = bpy.data.objects.new("plane", mesh)
    scene.collection.objects.link(plane)
    material = bpy.data.materials.new("textured")
    tree = material.node_tree
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    for node in [n for n in tree.nodes if n != output]:
        tree.nodes.remove(node)
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    texture = tree.nodes.new("ShaderNodeTexImage")
    tree.links.new(texture.outputs["Color"], emission.inputs["Color"])
    tree.links.new(emission.outputs[0], output.inputs["Surface"])
    mesh.materials.append(material)
    corner_xy = np.array([mesh.vertices[loop.vertex_index].co[:2] for loop in mesh.loops])
    images = []
    for k, case in enumerate(cases):
        pixels = data[case["image"]]
        height, width = pixels.shape[:2]
        image = bpy.data.images.new(f"image{k}", width, height, alpha=True)
        # Colour space and alpha mode first: changing them later regenerates a generated image.
        image.colorspace_settings.name = case["colorspace"]
        image.alpha_mode = case["alpha_mode"]
        image.pixels.foreach_set((pixels.astype(np.float32) / 255.0).reshape(-1))  # bottom row first
        image.pack()
        texture.image = image
        texture.interpolation = case["interpolation"]
        texture.extension = case["extension"]
        uv = np.array(case["uv_offset"]) + np.array(case["uv_scale"]) * (corner_xy + 1.0) / 2.0
        uv_layer.data.foreach_set("uv", uv.astype(np.float32).reshape(-1))
        mesh.update()
        render.filepath = f"{out}_{k}.exr"
        bpy.ops.render.render(write_still=True)
        with OpenEXR.File(render.filepath) as exr:
            images.append(np.array(exr.parts[0].channels["RGBA"].pixels))  # top row first
    np.save(out + ".npy", np.stack(images))
''')

CYCLES_SIZE = 32
CYCLES_SAMPLES = 256
UV_OFFSET, UV_SCALE = (-0.5, -0.5), (2.0, 2.0)  # pixel centres see UVs in [-0.5, 1.5]^2


def cycles_cases():
    cases = [dict(image="opaque", colorspace="sRGB", alpha_mode="STRAIGHT", interpolation=interpolation,
                  extension=extension)
             for interpolation in ("Closest", "Linear") for extension in ("REPEAT", "EXTEND", "CLIP", "MIRROR")]
    cases += [dict(image="opaque", colorspace="Non-Color", alpha_mode="STRAIGHT", interpolation="Linear",
                   extension="REPEAT"),
              dict(image="alpha", colorspace="sRGB", alpha_mode="STRAIGHT", interpolation="Closest",
                   extension="REPEAT"),
              dict(image="alpha", colorspace="sRGB", alpha_mode="STRAIGHT", interpolation="Linear",
                   extension="CLIP"),
              dict(image="alpha", colorspace="Non-Color", alpha_mode="STRAIGHT", interpolation="Linear",
                   extension="MIRROR")]
    for case in cases:
        case.update(uv_offset=UV_OFFSET, uv_scale=UV_SCALE)
    return cases


def pixel_centre_uvs():
    """(S * S, 2) UVs seen at the pixel centres, rows top first (as the EXR)."""
    rows, cols = np.mgrid[0:CYCLES_SIZE, 0:CYCLES_SIZE]
    screen = np.stack([(cols + 0.5) / CYCLES_SIZE, 1.0 - (rows + 0.5) / CYCLES_SIZE], axis=-1).reshape(-1, 2)
    return np.asarray(UV_OFFSET) + np.asarray(UV_SCALE) * screen


@pytest.fixture(scope="module")
def cycles_renders(tmp_path_factory):
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("Blender as a Python module (bpy) is not installed")
    folder = tmp_path_factory.mktemp("cycles_texture")
    rng = np.random.default_rng(2024)
    opaque = rng.integers(0, 256, (2, 4, 4)).astype(np.uint8)
    opaque[..., 3] = 255
    alpha = opaque.copy()
    alpha[..., 3] = rng.integers(0, 256, (2, 4))
    np.savez(folder / "input.npz", opaque=opaque, alpha=alpha, size=CYCLES_SIZE, samples=CYCLES_SAMPLES)
    cases = cycles_cases()
    (folder / "cases.json").write_text(json.dumps(cases))
    (folder / "render.py").write_text(CYCLES_SCRIPT)
    subprocess.run([sys.executable, str(folder / "render.py"), str(folder / "input.npz"), str(folder / "cases.json"),
                    str(folder / "render")], check=True, capture_output=True, timeout=300)
    return {"opaque": opaque, "alpha": alpha}, cases, np.load(folder / "render.npy")


def test_matches_cycles(cycles_renders):
    """Measured (Blender 5.0.1, 256 samples): Closest agrees to 2e-6 (float32); Linear to ~2e-6 (median),
    with a few pixels up to ~1e-3 where one of Cycles' samples took the stray entry of its filter table and moved up
    to half a pixel (see core/film.py). Decoding sRGB before interpolating, or texel centres at i / W
    instead of (i + 0.5) / W, would be off by more than 0.2; premultiplying bytes as floats by 4e-3."""
    images, cases, renders = cycles_renders
    uv = pixel_centre_uvs()
    for case, rendered in zip(cases, renders):
        texture = ImageTexture.from_pixels(images[case["image"]], case["colorspace"], case["interpolation"],
                                           case["extension"], case["alpha_mode"])
        expected = texture.lookup(uv)[:, :3].reshape(CYCLES_SIZE, CYCLES_SIZE, 3)
        error = np.abs(rendered[..., :3] - expected)
        label = f"{case['interpolation']} {case['extension']} {case['colorspace']} {case['image']}"
        assert error.max() < (1e-5 if case["interpolation"] == "Closest" else 2e-3), label
        assert np.median(error) < 1e-5, label
        if case["image"] == "alpha" and case["colorspace"] == "sRGB" and case["interpolation"] == "Closest":
            # Bytes are premultiplied in integers (measured 9e-7 off); exact products would be 4e-3 off.
            exact = ImageTexture.from_pixels(images["alpha"] / 255.0, "sRGB", "Closest", "REPEAT").lookup(uv)
            assert np.abs(rendered[..., :3] - exact[:, :3].reshape(error.shape)).max() > 1e-3, label
        if case["interpolation"] == "Linear":
            shifted = texture.lookup(uv + 0.5 / np.array([4.0, 2.0]))[:, :3].reshape(error.shape)
            assert np.abs(rendered[..., :3] - shifted).max() > 0.05, label
            if case["colorspace"] == "sRGB":
                decoded_first = ImageTexture(texture.linear_pixels, False, "Linear", case["extension"])
                wrong = decoded_first.lookup(uv)[:, :3].reshape(error.shape)
                assert np.abs(rendered[..., :3] - wrong).max() > 0.05, label
