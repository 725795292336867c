"""The pixel filter (lazyvis_addon.core.film): Cycles' Blackman-Harris window and its width, the inverse-CDF
table, chi-square fits of the sampled offsets against the filter, and measured edge profiles from Cycles.

The chi-square tests use fixed seeds and the significance level ALPHA = 1e-3 of tests/test_sampling.py.

The Cycles test renders (in a subprocess, so this process never imports bpy) an Emission-lit region
under an orthographic camera with one world unit per pixel and a black world. A pixel's value is then
the fraction of its camera samples that land inside the region, whose expectation the offsets predict
exactly: ``P(pixel + offset inside)``. Measured on Blender 5.0.1 (CPU):

- vertical edge at x = 16.3 px, filter_width 1.5, 4096 samples, 32 x 32: the column means agree with the
  prediction to 1.5e-4 (at the steepest column, 0.68000 measured vs 0.67986 predicted; seeds 0, 1, 2 give
  1.5e-4, 1.3e-4, 0.3e-4 there), i.e. an edge displacement below 3e-4 px. A filter of radius 0.75 or
  3 px (filter_width read as a full width, or doubled once more) would be off by 0.15. At filter_width
  0.01 the edge is a step: 0.99951 in the edge column against 0.99942 predicted (the table's stray
  entry, below).
- a diagonal edge x + y = 32.1 px (both axes at once): diagonal means agree to 1.9e-4 (radius 0.75:
  off by 0.065, radius 3: by 0.16).
- Cycles' table has a stray 0 in its last entry: 1/1023 of the samples land uniformly in
  [0, 0.5 + filter_width] from the pixel's left and *bottom* edges. With filter_width 0.01 and an edge
  0.25 px from a pixel's left (bright on the left) or bottom (bright below) edge, Cycles returns 4.6e-4
  and 4.9e-4 in that pixel column / row (predicted 4.7e-4); mirrored, exactly 0.
"""

import importlib.util
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from lazyvis_addon.core.film import (
    CYCLES_TABLE_SIZE,
    blackman_harris,
    filter_function,
    filter_offsets,
    filter_table,
    offset_density,
    read_table,
)
from test_sampling import chi2_critical

A = (0.35875, 0.48829, 0.14128, 0.01168)
STRAY = 1.0 / (CYCLES_TABLE_SIZE - 1)  # fraction of samples that read the table's last, zero entry


# -- independent closed forms -------------------------------------------------------------------------

def window(n, big_n):
    """The textbook 4-term Blackman-Harris window w(n), 0 <= n <= N."""
    t = 2.0 * np.pi * np.asarray(n, dtype=np.float64) / big_n
    return A[0] - A[1] * np.cos(t) + A[2] * np.cos(2 * t) - A[3] * np.cos(3 * t)


def bh_cdf(x, radius):
    """CDF of the normalised Blackman-Harris density on [-radius, radius] (x from the pixel centre)."""
    p = np.pi * np.clip(x, -radius, radius) / radius + np.pi
    return (A[0] * p - A[1] * np.sin(p) + A[2] * np.sin(2 * p) / 2 - A[3] * np.sin(3 * p) / 3) / (2 * np.pi * A[0])


def offset_cdf(s, radius):
    """CDF of one Cycles offset coordinate s, measured from the pixel's left (or bottom) edge: the filter,
    plus the 1/1023 of samples spread uniformly over [0, 0.5 + radius] by the table's stray entry."""
    return (1.0 - STRAY) * bh_cdf(s - 0.5, radius) + STRAY * np.clip(s / (0.5 + radius), 0.0, 1.0)


def equal_probability_edges(radius, bins):
    """Bin edges (bins + 1,) in offset coordinates, equally likely under the filter."""
    x = np.linspace(-radius, radius, 200001)
    edges = np.interp(np.linspace(0.0, 1.0, bins + 1), bh_cdf(x, radius), x) + 0.5
    edges[0], edges[-1] = -1.0, 2.0 + 2 * radius  # catch everything
    return edges


def chi2_statistic(samples, edges, cdf):
    counts = np.histogram(samples, edges)[0]
    expected = len(samples) * np.diff(cdf(edges))
    return np.sum((counts - expected) ** 2 / expected), len(counts) - 1


# -- the window and its width ---------------------------------------------------------------------------

def test_blackman_harris_is_the_textbook_window_over_twice_the_width():
    width = 1.5
    big_n = 1000
    n = np.arange(big_n + 1)
    x = (n - big_n / 2) / (big_n / 2) * width  # the window spans [-width, width]: width is the radius
    np.testing.assert_allclose(blackman_harris(x, width), window(n, big_n), atol=1e-12)
    assert blackman_harris(0.0, width) == pytest.approx(1.0)
    assert blackman_harris(width, width) == pytest.approx(6e-5, abs=1e-12)
    assert blackman_harris(np.array([-1.51, 1.51, 7.0]), width).tolist() == [0.0, 0.0, 0.0]
    # Scaling: the shape depends on x / width only.
    np.testing.assert_allclose(blackman_harris(0.3 * x, 0.3 * width), blackman_harris(x, width), atol=1e-12)


def test_table_structure():
    width = 1.5
    table = filter_table(width)
    assert table.shape == (CYCLES_TABLE_SIZE,)
    half = (CYCLES_TABLE_SIZE - 1) // 2
    assert table[half] == pytest.approx(0.5)
    np.testing.assert_allclose(table[half + np.arange(half + 1)] + table[half - np.arange(half + 1)], 1.0,
                               atol=1e-12)
    assert table[0] == pytest.approx(0.5 - width) and table[2 * half] == pytest.approx(0.5 + width)
    assert table[-1] == 0.0  # never written by Cycles
    assert np.all(np.diff(table[:2 * half + 1]) > 0)
    assert not table.flags.writeable
    # lookup_table_read interpolates linearly between entries and clamps u.
    assert read_table(table, np.array([0.0, 1.0, -3.0, 2.0])).tolist() == [table[0], table[-1], table[0], table[-1]]
    middle = (half + 0.25) / (CYCLES_TABLE_SIZE - 1)
    assert read_table(table, np.array([middle]))[0] == pytest.approx(0.75 * table[half] + 0.25 * table[half + 1])


def test_offsets_match_the_filter_chi_square():
    width = 1.5
    n = 1_000_000
    # Not the np_rng fixture: its first 1e6 pairs of uniforms themselves fail the 10 x 10 independence
    # test below (chi2 168 > 148, p ~ 3e-5), whatever the filter.
    offsets = filter_offsets(np.random.default_rng(1).uniform(size=(n, 2)), width)
    edges = equal_probability_edges(width, 50)
    # x is measured from the left edge like Cycles' raster x; our y runs down, Cycles' up.
    for name, coordinate in (("x", offsets[:, 0]), ("y", 1.0 - offsets[:, 1])):
        statistic, df = chi2_statistic(coordinate, edges, lambda s: offset_cdf(s, width))
        assert statistic < chi2_critical(df), f"{name}: chi2 {statistic:.1f}"
    # Independence (the 2D filter is the separable product): a 10 x 10 table of equally likely cells.
    coarse = equal_probability_edges(width, 10)
    cells = np.histogram2d(offsets[:, 0], 1.0 - offsets[:, 1], [coarse, coarse])[0]
    marginal = np.diff(offset_cdf(coarse, width))
    expected = n * np.outer(marginal, marginal)
    assert np.sum((cells - expected) ** 2 / expected) < chi2_critical(99)


@pytest.mark.parametrize("wrong_width", [0.75, 3.0])
def test_chi_square_rejects_another_width(np_rng, wrong_width):
    """The test above can tell a radius from a full width."""
    offsets = filter_offsets(np_rng.uniform(size=(100_000, 2)), wrong_width)
    statistic, df = chi2_statistic(offsets[:, 0], equal_probability_edges(1.5, 50), lambda s: offset_cdf(s, 1.5))
    assert statistic > 10 * chi2_critical(df)


def test_width_semantics(np_rng):
    u = np_rng.uniform(size=(200_000, 2))
    for width in (0.5, 1.5, 2.5):
        offsets = filter_offsets(u, width)
        regular = offsets[u[:, 0] < 1.0 - STRAY, 0]
        assert regular.min() >= 0.5 - width and regular.max() <= 0.5 + width
        assert regular.min() < 0.5 - 0.6 * width and regular.max() > 0.5 + 0.6 * width
        # Standard deviation of the window's density: 0.2770 * radius (numerically integrated).
        x = np.linspace(-width, width, 20001)
        weights = blackman_harris(x, width)
        sigma = np.sqrt(np.sum(weights * x ** 2) / np.sum(weights))
        assert sigma == pytest.approx(0.27701 * width, rel=1e-4)
        assert regular.std() == pytest.approx(sigma, rel=0.01)
    # A tiny width is a point sample at the centre, but for the table's stray entry.
    tiny = filter_offsets(u, 0.01)
    near = np.all(np.abs(tiny - 0.5) <= 0.01 + 1e-12, axis=1)
    assert 1.0 - near.mean() == pytest.approx(2 * STRAY * (1 - 0.02 / 0.51), rel=0.1)


def test_offset_density_is_the_density_the_table_samples():
    """The density that pooling weighs samples by: it integrates to 1 for every filter type, puts on
    equally likely bins of the closed-form Blackman-Harris CDF (stray entry included) their probability to
    0.2% (the 1023-entry table's resolution), and 0 outside the support; y offsets (``1 - T(u)``) have
    ``offset_density(1 - t)``, checked by chi-square on sampled offsets."""
    t = np.linspace(-2.5, 3.5, 3_000_001)
    for width, filter_type in ((1.5, "BLACKMAN_HARRIS"), (1.0, "GAUSSIAN"), (1.0, "BOX"), (0.01, "BLACKMAN_HARRIS")):
        density = offset_density(t, width, filter_type)
        assert np.trapz(density, t) == pytest.approx(1.0, abs=1e-5), filter_type
    edges = equal_probability_edges(1.5, 50)
    edges[0], edges[-1] = -1.2, 2.3
    density = offset_density(t, 1.5)
    cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(t))])
    got = np.diff(np.interp(edges, t, cumulative))
    np.testing.assert_allclose(got, np.diff(offset_cdf(edges, 1.5)), rtol=2e-3)
    assert offset_density(np.array([-1.01, 2.01]), 1.5).tolist() == [0.0, 0.0]
    # Chi-square of sampled y offsets against the density's own bin probabilities.
    offsets = filter_offsets(np.random.default_rng(3).uniform(size=(200_000, 2)), 1.5)
    counts = np.histogram(1.0 - offsets[:, 1], edges)[0]
    expected = len(offsets) * got
    assert np.sum((counts - expected) ** 2 / expected) < chi2_critical(len(counts) - 1)


def test_other_filter_types(np_rng):
    u = np_rng.uniform(size=(200_000, 2))
    box = filter_offsets(u, 1.0, "BOX")[u[:, 0] < 1.0 - STRAY, 0]
    assert box.min() >= 0.0 and box.max() <= 1.0
    assert np.histogram(box, 10, (0, 1))[0] == pytest.approx(np.full(10, len(box) / 10), rel=0.03)
    gaussian = filter_offsets(u, 1.5, "GAUSSIAN")[u[:, 0] < 1.0 - STRAY, 0]
    assert gaussian.std() == pytest.approx(1.5 / 4, rel=0.01)  # sigma = width / 4
    assert filter_function(np.array([0.0]), 1.5, "GAUSSIAN")[0] == 1.0
    with pytest.raises(ValueError, match="MITCHELL"):
        filter_table(1.5, "MITCHELL")
    with pytest.raises(ValueError, match="positive"):
        filter_offsets(u, 0.0)


# -- against Cycles -----------------------------------------------------------------------------------

CYCLES_SCRIPT = textwrap.dedent('''
    """Render Emission-lit convex polygons (pixel coordinates, y down) under an orthographic camera with one
    world unit per pixel; save each render's red channel, top row first, as render_<k>.npy."""
    import json
    import sys

    import bpy
    import numpy as np
    import OpenEXR

    jobs = json.loads(open(sys.argv[1]).read())
    out = sys.argv[2]
    for k, job in enumerate(jobs):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        scene.world = None
        scene.render.engine = "CYCLES"
        cycles = scene.cycles
        cycles.device = "CPU"
        cycles.samples = job["samples"]
        cycles.use_adaptive_sampling = False
        cycles.use_denoising = False
        cycles.max_bounces = 0
        cycles.pixel_filter_type = "BLACKMAN_HARRIS"
        cycles.filter_width = job["filter_width"]
        cycles.seed = 0
        render = scene.render
        width, height = job["width"], job["height"]
        render.resolution_x, render.resolution_y = width, height
        render.resolution_percentage = 100
        render.use_compositing = False
        render.use_sequencer = False
        render.use_file_extension = False
        render.image_settings.file_format = "OPEN_EXR"
        render.image_settings.color_depth = "32"
        camera = bpy.data.cameras.new("camera")
        camera.type = "ORTHO"
        camera.ortho_scale = max(width, height)
        camera_object = bpy.data.objects.new("camera", camera)
        camera_object.location = (0.0, 0.0, 10.0)
        scene.collection.objects.link(camera_object)
        scene.camera = camera_object
        corners = [(x - width / 2, height / 2 - y, 0.0) for x, y in job["polygon"]]
        mesh = bpy.data.meshes.new("region")
        mesh.from_pydata(corners, [], [tuple(range(len(corners)))])
        region = bpy.data.objects.new("region", mesh)
        scene.collection.objects.link(region)
        material = bpy.data.materials.new("emission")
        tree = material.node_tree
        output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
        for node in [n for n in tree.nodes if n != output]:
            tree.nodes.remove(node)
        emission = tree.nodes.new("ShaderNodeEmission")
        emission.inputs["Strength"].default_value = 1.0
        tree.links.new(emission.outputs[0], output.inputs["Surface"])
        mesh.materials.append(material)
        render.filepath = f"{out}_{k}.exr"
        bpy.ops.render.render(write_still=True)
        with OpenEXR.File(render.filepath) as exr:
            np.save(f"{out}_{k}.npy", np.array(exr.parts[0].channels["RGBA"].pixels)[..., 0])
''')

FAR = 100.0  # polygons reach far outside the image (not too far: float32 vertices)


def half_plane_polygon(normal, c):
    """A big quad (4, 2) covering {p : normal . p > c} near the image, in pixel coordinates (y down).
    Its winding does not matter: an Emission surface emits from both sides."""
    normal = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    along = np.array([-normal[1], normal[0]])
    base = normal * c
    return [list(base - FAR * along), list(base + FAR * along), list(base + FAR * along + FAR * normal),
            list(base - FAR * along + FAR * normal)]


JOBS = {
    "edge_1.5": dict(width=32, height=32, samples=4096, filter_width=1.5, normal=(1.0, 0.0), c=16.3),
    "edge_0.01": dict(width=32, height=32, samples=1024, filter_width=0.01, normal=(1.0, 0.0), c=16.3),
    "diagonal_1.5": dict(width=32, height=32, samples=4096, filter_width=1.5, normal=(1.0, 1.0),
                         c=32.1 / np.sqrt(2.0)),
    # Probes of the table's stray entry: the edge 0.25 px from a pixel edge, bright on either side.
    "stray_left": dict(width=32, height=8, samples=4096, filter_width=0.01, normal=(-1.0, 0.0), c=-16.25),
    "stray_right": dict(width=32, height=8, samples=4096, filter_width=0.01, normal=(1.0, 0.0), c=16.75),
    "stray_below": dict(width=8, height=32, samples=4096, filter_width=0.01, normal=(0.0, 1.0), c=16.75),
    "stray_above": dict(width=8, height=32, samples=4096, filter_width=0.01, normal=(0.0, -1.0), c=-16.25),
}


def predicted_coverage(job, width=None):
    """(H, W) expected fraction of each pixel's samples inside the job's half-plane, from filter_offsets
    on regular grids of uniforms: 2^16 per axis for an axis-aligned edge, 2048 x 2048 pairs otherwise
    (fine enough to resolve the 1/1023 of u that reads the table's last entry)."""
    normal = np.asarray(job["normal"], dtype=np.float64) / np.linalg.norm(job["normal"])
    size = 2 ** 16 if 0.0 in normal else 2048
    grid = (np.arange(size) + 0.5) / size
    offsets = filter_offsets(np.stack([grid, grid], axis=1), job["filter_width"] if width is None else width)
    projected = np.sort((normal[0] * offsets[:, 0][:, None] + normal[1] * offsets[:, 1][None, :]).reshape(-1)
                        if 0.0 not in normal else offsets @ normal)
    rows, cols = np.mgrid[0:job["height"], 0:job["width"]]
    needed = job["c"] - (cols * normal[0] + rows * normal[1])
    return 1.0 - np.searchsorted(projected, needed, side="right") / len(projected)


@pytest.fixture(scope="module")
def cycles_renders(tmp_path_factory):
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("Blender as a Python module (bpy) is not installed")
    folder = tmp_path_factory.mktemp("cycles_film")
    jobs = [dict(width=job["width"], height=job["height"], samples=job["samples"], filter_width=job["filter_width"],
                 polygon=half_plane_polygon(job["normal"], job["c"])) for job in JOBS.values()]
    (folder / "jobs.json").write_text(json.dumps(jobs))
    (folder / "render.py").write_text(CYCLES_SCRIPT)
    subprocess.run([sys.executable, str(folder / "render.py"), str(folder / "jobs.json"), str(folder / "render")],
                   check=True, capture_output=True, timeout=300)
    return {name: np.load(folder / f"render_{k}.npy") for k, name in enumerate(JOBS)}


@pytest.mark.slow
def test_cycles_edge_profile(cycles_renders):
    job = JOBS["edge_1.5"]
    measured = cycles_renders["edge_1.5"].mean(axis=0)
    predicted = predicted_coverage(job).mean(axis=0)
    assert np.abs(measured - predicted).max() < 5e-4
    for wrong in (0.75, 3.0):  # radius halved, or doubled (filter_width read as full width / as radius x 2)
        assert np.abs(measured - predicted_coverage(job, wrong).mean(axis=0)).max() > 0.1
    point = cycles_renders["edge_0.01"].mean(axis=0)
    assert np.abs(point - predicted_coverage(JOBS["edge_0.01"]).mean(axis=0)).max() < 3e-4
    assert np.all(point[:16] == 0.0) and np.all(point[17:] == 1.0)


@pytest.mark.slow
def test_cycles_diagonal_edge(cycles_renders):
    """Both axes at once: pixels on the same diagonal x + y share an expected value."""
    job = JOBS["diagonal_1.5"]
    rows, cols = np.mgrid[0:32, 0:32]
    diagonal = (rows + cols).reshape(-1)
    count = np.bincount(diagonal)
    measured = np.bincount(diagonal, cycles_renders["diagonal_1.5"].reshape(-1)) / count
    predicted = np.bincount(diagonal, predicted_coverage(job).reshape(-1)) / count
    assert np.abs(measured - predicted).max() < 5e-4
    assert np.abs(measured - np.bincount(diagonal, predicted_coverage(job, 0.75).reshape(-1)) / count).max() > 0.03


@pytest.mark.slow
def test_cycles_stray_table_entry_and_y_direction(cycles_renders):
    """The 1/1023 of samples that read the table's zero entry pull towards the pixel's left and bottom
    edges; filter_offsets reproduces it (and so Cycles' upward raster y)."""
    for name, axis in (("stray_left", 0), ("stray_right", 0), ("stray_below", 1), ("stray_above", 1)):
        measured = cycles_renders[name].mean(axis=axis)
        predicted = predicted_coverage(JOBS[name]).mean(axis=axis)
        assert np.abs(measured - predicted).max() < 1.5e-4, name
        edge_pixel = 16
        if name in ("stray_left", "stray_below"):
            assert measured[edge_pixel] > 2e-4 and predicted[edge_pixel] > 4e-4, name
        else:
            assert measured[edge_pixel] == 0.0 and predicted[edge_pixel] == 0.0, name
