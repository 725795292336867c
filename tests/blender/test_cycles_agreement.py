"""LazyVis against Cycles on the sample .blend files and small built scenes: the proof that the exporter,
the engine and the core reproduce Blender's own renderer, pixel for pixel, up to Cycles' noise.

No Cycles render runs here. The references are committed: ``tests/references/<scene>.seed1.exr`` and
``.seed2.exr``, made by ``tools/make_cycles_references.py`` (Cycles 5.0.1, direct light only, filter width
0.01 = a point sample at each pixel centre, thousands of samples, seeds 1 and 2), at each scene's low
resolution (``agreement_scenes.CASES``); the ``*_filter1.5`` cases use Blender's default filter instead
(``test_default_filter_matches_cycles``, at the end). Each test renders the same scene at the same resolution with
LazyVis through Blender (``bpy.ops.render.render``, the engine's own path from the depsgraph) and compares.

The statistics, over every RGB value of the image. A and B are the two Cycles renders, L the LazyVis one,
T the true image. Cycles is unbiased with noise variance s^2 per value, independent between seeds; L has
no noise, only an error e = L - T. Then

    E[(A - B)^2] = 2 s^2,      E[(L - A)^2] = e^2 + s^2,

so ``noise = RMS(A - B) / sqrt(2)`` estimates one render's noise s and ``RMS(L - A)`` equals it when LazyVis
is exact. We require

    RMS(L - A) <= 1.5 * RMS(A - B) / sqrt(2)          (the noise-floor ratio)

that is LazyVis' own RMS error at most sqrt(1.5^2 - 1) = 1.1 times Cycles' noise: as close to the truth
as the high-sample Cycles render itself. With ~10^4 or more values per image the ratio is measured to
about 1%, so 1.5 leaves room for chance but not for a bug: a light 1% too bright, a flipped normal or a
missing blocker shows up as a ratio of 2 to 100. The mean bias |sum(L) - sum(A)| / sum(A) must be under 1%
(Cycles' noise moves it by ~noise / sqrt(N), far less). Both are printed relative to mean(A).

What legitimately differs, and how it is handled (figures measured against the committed references):
- Pixel footprint: a filter width of 0.01 is not quite a point sample. Cycles spreads each pixel's
  samples over +-0.01 pixel (Blackman-Harris; filter_width is a radius), and 1 sample in 1023 per axis
  lands anywhere in the pixel's left or lower half (the last entry of Cycles' filter table, see
  core/film.py). Where a silhouette or crease passes within 0.01 pixel of a centre, Cycles averages both
  sides and LazyVis, which shades the exact centre, shows one: such a pixel is off by up to the full
  contrast (an emitter's edge: 6.0 against 0.03), enough for a ratio of 5 to 160 from a handful of
  pixels. ``excluded_pixels`` finds them with LazyVis itself (depth, normal and coverage probed 0.02
  pixel around each centre; 0.4% of the boxes' pixels, 3.3% of the chapel's with its bevelled benches,
  at most 5% allowed) and leaves them out. The stray 1-in-1023 samples only matter against an emitter
  seen by the camera (one sample of 6.0 in 8192 is 50 times the noise there): its pixels and their neighbours
  are left out too. Elsewhere they move a pixel by 0.1% of a neighbour's contrast, inside the margin,
  except against a texture (below).
- Textures (textured.blend: a checker, Closest interpolation, 36:1 in linear light): a texel edge is as
  sharp as a silhouette, so pixels within 0.02 pixel of one are left out too (found by lens-shifting full
  LazyVis renders; 32 pixels, 0.35%): with them the ratio is 44. And the stray samples, next to a checker
  edge, move a dark pixel by a few percent (ratio 1.43 with them ignored, over a fifth of the pixels): they are
  modelled, not left out (``with_stray_samples``: 2/1023 of the weight from LazyVis renders at the strays'
  positions), giving 0.95.
- Anti-aliasing: LazyVis' own is turned off here (``point_sampled``), so that it shades pixel centres.
- Emitters seen by the camera: area lights are hidden from the camera (Cycles' default; LazyVis does not
  draw them). An emissive mesh is seen with its radiance by both; only its outline is left out (above).
- Missed blockers: none. Every sample renders at LazyVis' default settings, whose silhouette pass finds
  every edge that can cross a light however small (issue 13). The paper's blocker map, seeded by 4
  shadow rays a pixel, missed slats, bevels and Suzanne's triangles at these 96 px (ratio 9.5 boxes,
  79 chapel, 126 Suzanne, as measured before) and needed 64 to 2,048 shadow rays here.
- Smooth shading: Cycles starts shadow rays of smooth-shaded faces towards grazing light off the flat
  triangle (Object > Shading > Shadow Terminator > Geometry Offset, 0.1 by default), and so does LazyVis
  (``core.terminator``). Rendered as if the offset were 0, Suzanne's self-shadowed creases are up to 60%
  darker than Cycles' (ratio 46 on her pixels, -0.2% of her light) while the floor still agrees;
  with it her pixels are within the noise
  (``test_shadow_terminator_offset_lifts_suzannes_shadow_rays_as_in_cycles``).
- Disk and ellipse lights are polygons of equal area in LazyVis (64 vertices here): their outlines move
  by 0.1% of the radius, far inside the noise (256 vertices change nothing measurable).

Blender's default filter (issue 5): Blackman-Harris of radius 1.5 px in both renderers, LazyVis with its own
adaptive anti-aliasing (16 filter-placed samples in pixels marked as edges, the centre elsewhere). Nothing
is left out: both average the edges. LazyVis' edge pixels are a 16-sample estimate, 4.7% (boxes), 13%
(checker) and 69% (the chapel's one-pixel light streaks) RMS noise against Cycles' 0.4%, 0.4% and 3.5%, so
against Cycles alone the ratio is 10, 33 and 21;
that noise is measured from two LazyVis seeds and joins the floor (as for glossy MC), and the pixels shaded
at their centre only must on their own stay within Cycles' noise (``test_default_filter_matches_cycles``).
With 256 samples in every pixel the boxes' ratio against the combined floor is 1.09 (LazyVis' noise 0.6%).
The chapel was +8.6% too bright (combined ratio 2.0) until the samples were verified: a sample seeing a
slat's face between two centres, or a blocker that parallax uncovers, lacks it in its pixel's list.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import agreement_scenes  # noqa: E402
from blender_helpers import read_exr, render_to_exr  # noqa: E402

from lazyvis_addon.blender import engine as engine_module  # noqa: E402
from lazyvis_addon.blender.export import read_material  # noqa: E402

RATIO_LIMIT = 1.5
BIAS_LIMIT = 0.01
# Edge probes: how far from the pixel centre (pixels), and what counts as a different surface there.
SILHOUETTE_REACH = 0.02
DEPTH_STEP = 0.005    # relative depth change (a slanted plane changes ~1e-4 over the reach)
NORMAL_STEP = math.cos(math.radians(1.0))  # smooth shading turns the normal ~0.1 degree over the reach
TEXEL_STEP = 0.25     # relative radiance change over the reach on a textured surface (a penumbra: < 2%)
INDEX = agreement_scenes.REFERENCES / "references.json"
# LazyVis' own noise under Blender's default filter (RMS between two seeds over the image, relative to its
# mean) joins the floor of ``test_default_filter_matches_cycles``, so a noisier anti-aliasing would loosen
# its own test: it is capped at about 1.3 times what it measures (2026-12-06: 3.45 %, 1.03 %, 5.84 %,
# 12.8 %, 0.61 %), so that a regression to half the samples' worth (1.4 times the noise) fails.
OWN_NOISE_LIMIT = {"seen_lights": 0.045, "floating_boxes_filter1.5": 0.0135, "textured_filter1.5": 0.075,
                   "chapel_filter1.5": 0.165, "suzanne_filter1.5": 0.008}


def point_sampled(scene) -> None:
    """LazyVis shades pixel centres only, like the references (Cycles' filter width 0.01)."""
    scene.lazyvis.aa_samples = 1


def agreement(ours: np.ndarray, first: np.ndarray, second: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """Noise-floor ratio, bias and their parts (see the module docstring) over the (H, W, 3) images'
    pixels where ``mask`` (H, W) is True (default all)."""
    if mask is None:
        mask = np.ones(first.shape[:2], bool)
    ours, first, second = (np.asarray(x, np.float64)[mask] for x in (ours, first, second))
    mean = max(first.mean(), 1e-30)
    rmse = math.sqrt(np.mean((ours - first) ** 2))
    noise = math.sqrt(np.mean((first - second) ** 2) / 2.0)
    return dict(ratio=rmse / max(noise, 1e-30), bias=(ours.sum() - first.sum()) / max(first.sum(), 1e-30),
                relative_rmse=rmse / mean, relative_noise=noise / mean, mean=mean,
                excluded=int(mask.size - mask.sum()))


def describe(name: str, stats: dict) -> str:
    return (f"{name}: RMSE(LazyVis - Cycles) {100 * stats['relative_rmse']:.3f}% of the mean, noise floor "
            f"{100 * stats['relative_noise']:.3f}% -> ratio {stats['ratio']:.2f} (limit {RATIO_LIMIT}); "
            f"bias {100 * stats['bias']:+.3f}% (limit {100 * BIAS_LIMIT:.0f}%)")


def references(case) -> tuple[np.ndarray, np.ndarray]:
    """The two Cycles renders of ``case`` (H, W, 3), checked to be made from the scene as it is now."""
    index = json.loads(INDEX.read_text())["scenes"]
    assert case.name in index, f"no Cycles reference for {case.name}: run tools/make_cycles_references.py {case.name}"
    entry = index[case.name]
    assert entry["source_sha256"] == case.source_digest(), (
        f"{entry['source']} changed since its Cycles reference was made: run "
        f"tools/make_cycles_references.py {case.name} (and commit tests/references/)")
    assert tuple(entry["resolution"]) == case.resolution
    assert entry.get("filter_width", agreement_scenes.POINT_FILTER) == case.filter_width
    images = []
    for path in case.reference_paths():
        channels = read_exr(path)
        rgb = channels["RGB"] if "RGB" in channels else np.stack([channels[c] for c in "RGB"], axis=2)
        images.append(rgb[..., :3])
    return images[0], images[1]


def render_lazyvis(case, integrator, tmp_path, **settings) -> np.ndarray:
    """LazyVis' image (H, W, 3) of ``case`` through Blender, point-sampled unless the case has a wider
    pixel filter (``settings``: more ``scene.lazyvis`` values)."""
    scene = agreement_scenes.load(case)
    scene.render.engine = engine_module.ENGINE_ID
    for key, value in {**case.lazyvis, **settings}.items():
        setattr(scene.lazyvis, key, value)
    scene.lazyvis.integrator = integrator
    if case.point_sampled:
        point_sampled(scene)
    return render_to_exr(scene, tmp_path / f"{case.name}.exr")["RGBA"][..., :3]


def render_lazyvis_filtered(case, tmp_path, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """LazyVis' image (H, W, 3) float64 of a filtered ``case`` with anti-aliasing seed ``seed``, and which
    pixels (H, W) bool it anti-aliased (its Sample Count pass)."""
    scene = agreement_scenes.load(case)
    scene.render.engine = engine_module.ENGINE_ID
    for key, value in {**case.lazyvis, "seed": seed}.items():
        setattr(scene.lazyvis, key, value)
    layer = scene.view_layers[0]
    layer.lazyvis.use_pass_sample_count = True
    channels = render_to_exr(scene, tmp_path / f"{case.name}.exr", multilayer=True)
    return (channels[f"{layer.name}.Combined"][..., :3].astype(np.float64),
            channels[f"{layer.name}.Sample Count.X"] > 1)


def _probe(scene, tmp_path, prefix):
    """(depth, normal, covered) at the pixel centres: a LazyVis render's Depth and Normal passes."""
    channels = render_to_exr(scene, tmp_path / "probe.exr", multilayer=True)
    depth = channels[prefix + "Depth.Z"]
    normal = np.stack([channels[prefix + f"Normal.{axis}"] for axis in "XYZ"], axis=2)
    return depth, normal, depth < 1e9


def _is_emitter(obj) -> bool:
    records = [read_material(slot.material) for slot in obj.material_slots]
    return any(record is not None and record.is_emitter for record in records)


def _is_textured(obj) -> bool:
    records = [read_material(slot.material) for slot in obj.material_slots]
    return any(record is not None and record.texture is not None for record in records)


def _textured(scene) -> list:
    return [obj for obj in scene.objects if obj.type == "MESH" and _is_textured(obj)]


def _hard_lights(scene) -> list:
    """Lights of radius or angle 0: their shadows' edges are steps."""
    return [obj for obj in scene.objects if obj.type == "LIGHT" and
            ((obj.data.type in ("POINT", "SPOT") and obj.data.shadow_soft_size == 0.0)
             or (obj.data.type == "SUN" and obj.data.angle == 0.0))]


def _shifted(scene, case, offsets):
    """Iterate over ``offsets`` ((dx, dy) pixels) with every pixel centre moved dx to the right and dy up
    (the camera's lens shift, in units of the sensor-fitted side); the camera is restored after."""
    camera = scene.camera.data
    width, height = case.resolution
    unit = width if camera.sensor_fit == "HORIZONTAL" else height if camera.sensor_fit == "VERTICAL" \
        else max(width, height)
    base = camera.shift_x, camera.shift_y
    try:
        for dx, dy in offsets:
            camera.shift_x, camera.shift_y = base[0] + dx / unit, base[1] + dy / unit
            yield
    finally:
        camera.shift_x, camera.shift_y = base


def _cross(reach):
    """The centre, then ``reach`` pixels right, left, up and down."""
    return [(0.0, 0.0), (reach, 0.0), (-reach, 0.0), (0.0, reach), (0.0, -reach)]


def _point_sampled_scene(case):
    """``case`` loaded for LazyVis with its settings, shading pixel centres."""
    scene = agreement_scenes.load(case)
    scene.render.engine = engine_module.ENGINE_ID
    for key, value in case.lazyvis.items():
        setattr(scene.lazyvis, key, value)
    point_sampled(scene)
    return scene


def _renders(scene, case, offsets, tmp_path) -> list[np.ndarray]:
    """LazyVis' images (H, W, 3) float64 of ``scene`` with the pixel centres moved by each offset."""
    return [render_to_exr(scene, tmp_path / "shifted.exr")["RGBA"][..., :3].astype(np.float64)
            for _ in _shifted(scene, case, offsets)]


STRAY_POSITIONS = 4  # stray positions averaged per axis (26 change the textured case's ratio by 0.02)


def with_stray_samples(case, ours, tmp_path, always: bool = False) -> np.ndarray:
    """LazyVis' point-sampled image ``ours`` (H, W, 3) as Cycles' filter of width 0.01 sees it, on scenes
    with textures.

    Per axis 1 sample in 1023 is a stray (core/film.py): it lands uniformly in [0, 0.51] pixel from the
    pixel's left (x) or bottom (y) edge, instead of within 0.01 pixel of the centre. Next to a texel edge
    of the checker (36:1 in linear light) those strays move a dark pixel by up to 3% and a bright one by
    0.1%, several times Cycles' noise at 8192 samples over a fifth of the textured case's pixels; on
    untextured scenes they stay inside the noise (see the module docstring). So the image compared is
    ``(1 - 2/1023) ours + (mean over the left strays + mean over the lower strays) / 1023``, the strays'
    means from LazyVis renders with the centres moved to ``STRAY_POSITIONS`` midpoints of [-0.5, 0.01]
    pixel along each axis. LazyVis' own value keeps 99.8% of the weight: no error of its own can hide in
    the correction. Hard lights' shadows (radius or angle 0) are steps of the same contrast beside a box lit
    by them (hard_lamps: 0.4% at pixels next to a lit box top): corrected the same way. Scenes with neither:
    ``ours`` unchanged, unless ``always`` (references so converged that a silhouette's strays show).
    """
    scene = _point_sampled_scene(case)
    if not always and not _textured(scene) and not _hard_lights(scene):
        return ours
    positions = -0.5 + 0.51 * (np.arange(STRAY_POSITIONS) + 0.5) / STRAY_POSITIONS
    left = np.mean(_renders(scene, case, [(d, 0.0) for d in positions], tmp_path), axis=0)
    below = np.mean(_renders(scene, case, [(0.0, d) for d in positions], tmp_path), axis=0)
    ours = np.asarray(ours, np.float64)
    return ours + (left - ours) / 1023.0 + (below - ours) / 1023.0


def excluded_pixels(case, tmp_path, reach: float = SILHOUETTE_REACH):
    """Pixels Cycles' footprint legitimately mixes: (H, W) bool near edges, (H, W) bool at emitters, and
    the (H, W, 3) normal seen at each pixel centre (zero on the background).

    - Near an edge: Cycles' filter of width 0.01 spreads each pixel's samples over +-0.01 pixel, so where
      a silhouette or crease passes that close to the centre Cycles averages both sides and LazyVis shows
      one. Found with LazyVis itself: the camera's lens shift moves every pixel centre by ``reach`` pixels
      left, right, up and down (lights hidden, so only camera rays are traced), and a pixel whose depth,
      normal or coverage changes is near an edge (a reach of 0.02 catches every edge crossing the
      +-0.01 pixel square the samples fall in).
    - At a texel edge: an Image Texture with Closest interpolation steps from one texel's colour to the
      next, an edge in the image as sharp as a silhouette, which the geometry probes above do not see.
      Where a textured object is seen at the pixel centre, the same lens shifts are applied to a full
      LazyVis render (lights on): a pixel whose radiance changes by more than ``TEXEL_STEP`` of the
      brighter value (and by more than 1% of the image's mean, which leaves out near-black pixels at
      an umbra's edge) is next to a texel edge. On the textured case the checker's steps change by 97%
      and the next largest change, in a penumbra, is 19%: 32 pixels (0.35%), counted as edges.
    - At a hard shadow's edge (a light of radius or angle 0): the same test, on every pixel.
    - At an emitter seen by the camera: 1 in 1023 of Cycles' samples lands anywhere in the pixel's
      left or lower half (see the module docstring). Against an emitter 200 times brighter than its
      surroundings that one sample is far above the noise, so the emitter's pixels and their 8 neighbours
      are left out (found with a render in which only the emitting meshes are visible).
    """
    scene = _point_sampled_scene(case)
    textured = _textured(scene)
    hard = _hard_lights(scene)
    steps = None
    if textured or hard:
        shots = _renders(scene, case, _cross(reach), tmp_path)
        steps = np.zeros(shots[0].shape[:2], bool)
        for shot in shots[1:]:
            change = np.abs(shot - shots[0]).max(axis=2)
            steps |= (change > TEXEL_STEP * np.maximum(shot, shots[0]).max(axis=2)) & (change > 0.01 * shots[0].mean())
    for obj in scene.objects:
        if obj.type == "LIGHT":
            obj.hide_render = True
    layer = scene.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = True
    prefix = layer.name + "."
    probes = [_probe(scene, tmp_path, prefix) for _ in _shifted(scene, case, _cross(reach))]
    depth, normal, covered = probes[0]
    edges = np.zeros(depth.shape, bool)
    for other_depth, other_normal, other_covered in probes[1:]:
        edges |= other_covered != covered
        both = covered & other_covered
        edges |= both & (np.abs(other_depth - depth) > DEPTH_STEP * np.abs(depth))
        edges |= both & (np.sum(other_normal * normal, axis=2) < NORMAL_STEP)
    if hard:
        edges |= steps  # a hard shadow's edge is as sharp as a silhouette
    if textured:
        hidden = {obj.name: obj.hide_render for obj in scene.objects}
        for obj in scene.objects:
            obj.hide_render = obj.type != "CAMERA" and obj not in textured
        edges |= steps & _probe(scene, tmp_path, prefix)[2]
        for obj in scene.objects:
            obj.hide_render = hidden[obj.name]

    at_emitters = np.zeros(depth.shape, bool)
    emitters = [obj for obj in scene.objects if obj.type == "MESH" and _is_emitter(obj)]
    if emitters:
        for obj in scene.objects:
            obj.hide_render = obj.type != "CAMERA" and obj not in emitters
        seen = _probe(scene, tmp_path, prefix)[2]
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                at_emitters |= np.roll(np.roll(seen, dy, axis=0), dx, axis=1)
    return edges, at_emitters, np.where(covered[..., None], normal, 0.0)


KNOWN_DIFFERENCES = set()
GLOSSY_CASES = [case for case in agreement_scenes.CASES if case.name.startswith("glossy_")]
# Glossy scenes tested with glossy Monte Carlo too; at the defaults the glossy floors by their own test
# (below: Cycles' stray samples modelled), ray_visibility with the others.
GLOSSY_MC_CASES = GLOSSY_CASES + [agreement_scenes.CASES_BY_NAME["ray_visibility"]]
FILTERED_CASES = [case for case in agreement_scenes.CASES if not case.point_sampled]
# Cases that fail for a reason another issue owns: run, and expected to fail until it is fixed (strict: a
# pass shows the issue done). The room's Principled sofa (roughness 0.9) and side table (0.6) are 1-4 %
# below Cycles by LTC's shape error (glossy Monte Carlo over the same pieces agrees): issue 16. Its
# lights are proven by room_matte.
EXPECTED_FAILURES = {}
CASES = [pytest.param(case, "analytic", id=f"{case.name}-analytic",
                      marks=[pytest.mark.xfail(reason=EXPECTED_FAILURES[case.name], strict=True)]
                      if case.name in EXPECTED_FAILURES else [])
         for case in agreement_scenes.CASES
         if case.name not in KNOWN_DIFFERENCES and case not in GLOSSY_CASES and case not in FILTERED_CASES]
CASES += [pytest.param(case, "reference", id=f"{case.name}-reference")
          for case in agreement_scenes.CASES if case.reference_integrator]


@pytest.mark.parametrize("case, integrator", CASES)
def test_lazyvis_matches_cycles_within_its_noise(addon, case, integrator, tmp_path):
    first, second = references(case)
    ours = render_lazyvis(case, integrator, tmp_path)
    assert ours.shape == first.shape, f"LazyVis rendered {ours.shape}, the reference is {first.shape}"
    assert first.mean() > 0.0 and np.isfinite(ours).all()
    ours = with_stray_samples(case, ours, tmp_path)
    edges, at_emitters, _ = excluded_pixels(case, tmp_path)
    assert edges.mean() <= 0.05, f"{edges.sum()} of {edges.size} pixels are next to an edge: too many to leave out"
    stats = agreement(ours, first, second, ~(edges | at_emitters))
    print(describe(f"{case.name} ({integrator}, {stats['excluded']} pixels left out)", stats))
    assert stats["ratio"] <= RATIO_LIMIT and abs(stats["bias"]) < BIAS_LIMIT, describe(case.name, stats)


@pytest.mark.parametrize("case", FILTERED_CASES, ids=[case.name for case in FILTERED_CASES])
def test_default_filter_matches_cycles(addon, case, tmp_path):
    """Blender's default pixel filter (Blackman-Harris, 1.5 px) in both renderers, LazyVis with its own
    anti-aliasing defaults (16 edge samples, adaptive): no pixel left out.

    LazyVis' edge pixels are a 16-sample estimate of the filtered value, so they are noisy and their noise
    joins Cycles' in the floor (measured from two LazyVis seeds, as for glossy MC):
    RMS(L - A) <= 1.5 * sqrt(s_Cycles^2 + s_LazyVis^2). That floor is dominated by the edges and would hide a
    wrong value in the pixels LazyVis shades at their centre only (its Sample Count pass says which).
    Those must be within Cycles' own noise: their error, RMS over the image, at most
    sqrt(1.5^2 - 1) = 1.12 times Cycles' noise (the share of the ratio test's budget an exact image leaves).
    A missed edge fails this: before the frame's outermost pixels were anti-aliased, a floor ending just
    below the frame left the boxes' bottom row 19% too bright, 3.6 times the noise."""
    first, second = references(case)
    (ours, refined), (second_seed, _) = (render_lazyvis_filtered(case, tmp_path, seed) for seed in (1, 2))
    ours = [ours, second_seed]
    assert ours[0].shape == first.shape and np.isfinite(ours[0]).all()
    assert 0.0 < refined.mean() < 1.0
    stats = agreement(ours[0], first, second)
    noise = stats["relative_noise"] * stats["mean"]
    own_noise = math.sqrt(np.mean((ours[0] - ours[1]) ** 2) / 2.0)
    ratio = stats["relative_rmse"] * stats["mean"] / math.hypot(noise, own_noise)
    centre = ~refined
    centre_error = math.sqrt(np.sum((ours[0] - first)[centre] ** 2) / ours[0].size) / noise
    # The bias from both seeds' mean: on the chapel one 16-sample seed's image sum alone is uncertain by
    # 0.4% (bright one-pixel light streaks), the two seeds read -0.5% and +0.7%.
    bias = float((ours[0] + ours[1]).sum() / (2.0 * first.sum()) - 1.0)
    stats["bias"] = bias
    print(describe(f"{case.name} (filter {case.filter_width}, 16 edge samples)", stats),
          f"LazyVis' own noise {100 * own_noise / stats['mean']:.3f}%, combined ratio {ratio:.2f}; "
          f"{100 * centre.mean():.0f}% of the pixels shaded at the centre, their error "
          f"{centre_error:.2f} x Cycles' noise", sep="\n")
    assert ratio <= RATIO_LIMIT and abs(stats["bias"]) < BIAS_LIMIT, describe(case.name, stats)
    assert centre_error <= math.sqrt(RATIO_LIMIT ** 2 - 1.0), f"{case.name}: centre-shaded pixels {centre_error:.2f}"
    assert own_noise / stats["mean"] <= OWN_NOISE_LIMIT[case.name], f"{case.name}: LazyVis' own noise grew"


def test_shadow_terminator_offset_lifts_suzannes_shadow_rays_as_in_cycles(addon, tmp_path, monkeypatch):
    """Suzanne with Blender's default Shadow Terminator Geometry Offset (0.1): Cycles lifts shadow rays
    leaving her smooth faces towards grazing light off the flat triangles, so her self-shadowed creases
    are lighter than her flat triangles alone would make them. Rendered as if the objects' offset were 0
    (what LazyVis did before it read the setting) her pixels are far outside Cycles' noise and darker,
    the floor (flat: no lift) still within it; with the offset her error falls more than tenfold (the
    whole image agrees within the noise: ``test_lazyvis_matches_cycles_within_its_noise``)."""
    import lazyvis_addon.blender.export as export
    case = agreement_scenes.CASES_BY_NAME["suzanne_48px"]
    first, second = references(case)
    edges, at_emitters, normal = excluded_pixels(case, tmp_path)
    excluded = edges | at_emitters
    floor = ~excluded & (normal[..., 2] > 0.9999)
    suzanne = ~excluded & (np.abs(normal).sum(axis=2) > 0) & (normal[..., 2] <= 0.9999)
    assert floor.sum() > 1000 and suzanne.sum() > 200
    lifted = agreement(render_lazyvis(case, "analytic", tmp_path), first, second, suzanne)
    real_scene = export.Scene

    def without_offset(*args, **kwargs):
        scene = real_scene(*args, **kwargs)
        scene.terminator_offset = None
        return scene

    monkeypatch.setattr(export, "Scene", without_offset)
    flat = render_lazyvis(case, "analytic", tmp_path)
    on_floor, on_suzanne = agreement(flat, first, second, floor), agreement(flat, first, second, suzanne)
    print(describe("floor, offset ignored", on_floor), describe("Suzanne, offset ignored", on_suzanne),
          describe("Suzanne, offset", lifted), sep="\n")
    assert on_floor["ratio"] <= RATIO_LIMIT, describe("floor", on_floor)
    assert on_suzanne["ratio"] > 3.0 and on_suzanne["bias"] < -0.001, describe("Suzanne", on_suzanne)
    assert lifted["relative_rmse"] < on_suzanne["relative_rmse"] / 10 and abs(lifted["bias"]) < 0.0005, \
        describe("Suzanne, offset", lifted)


def test_the_statistics_see_a_one_percent_error(np_rng):
    """The ratio test is sharp: Cycles-like noise of 0.3% around an image passes, the same image 1% too
    bright (a light's power off by 1%) fails, and a noise-free copy of the truth gives a ratio of 1."""
    truth = np_rng.uniform(0.2, 1.0, (96, 96, 3))
    first, second = (truth * (1.0 + 0.003 * np_rng.standard_normal(truth.shape)) for _ in range(2))
    exact = agreement(truth, first, second)
    assert exact["ratio"] == pytest.approx(1.0, abs=0.03) and abs(exact["bias"]) < 1e-3
    assert agreement(truth * 1.01, first, second)["ratio"] > 3.0


def test_references_are_small_and_documented():
    """Every case has two references of its resolution, each under 300 KB, and references.json says how
    they were made."""
    index = json.loads(INDEX.read_text())
    assert "max_bounces 0" in index["settings"] and "filter_width 0.01" in index["settings"]
    for case in agreement_scenes.CASES:
        entry = index["scenes"][case.name]
        assert entry["samples"] >= 4096 and entry["resolution"] == list(case.resolution)
        for path in case.reference_paths():
            assert path.stat().st_size < 300 * 1024, path


# Glossy (issue 4). Monte Carlo over the visible pieces is unbiased for Cycles' BSDF, so it must agree within
# the two renderers' noise: LazyVis' own MC noise (from two of its seeds) joins Cycles' in the floor.
# The LTC integrator approximates the lobe's shape; its error against Cycles is measured per roughness,
# documented in the README and held to the limits below (relative RMSE and bias, with a margin).
GLOSSY_MC_SAMPLES = 256
# Measured (relative RMSE, bias): 0.1: 0.99%, -0.06%; 0.3: 6.0%, -1.3%; 0.5: 5.7%, -0.5%; 0.8: 5.3%, +0.6%.
# The floor is seen at 55-75 degrees, where the published LTC fit's lobe shape is a few percent off
# (tests/test_ltc.py); the Fresnel is evaluated at each piece's lobe-weighted direction (with the lobe's
# mean Fresnel instead the errors were 3.6%, 13.3%, 14.2% and 9.4%).
LTC_LIMITS = {0.1: (0.015, 0.005), 0.3: (0.075, 0.02), 0.5: (0.07, 0.01), 0.8: (0.065, 0.01)}


@pytest.mark.parametrize("case", GLOSSY_MC_CASES, ids=[case.name for case in GLOSSY_MC_CASES])
def test_glossy_monte_carlo_matches_cycles_within_the_noise(addon, case, tmp_path):
    first, second = references(case)
    ours = [render_lazyvis(case, "analytic", tmp_path, glossy_integrator="mc",
                           mc_samples=GLOSSY_MC_SAMPLES, seed=seed) for seed in (1, 2)]
    edges, at_emitters, _ = excluded_pixels(case, tmp_path)
    mask = ~(edges | at_emitters)
    stats = agreement(ours[0], first, second, mask)
    own = agreement(ours[1], ours[0], ours[0], mask)  # RMSE between LazyVis' two seeds
    own_noise = own["relative_rmse"] * own["mean"] / math.sqrt(2.0)
    floor = math.hypot(stats["relative_noise"] * stats["mean"], own_noise)
    ratio = stats["relative_rmse"] * stats["mean"] / floor
    print(describe(f"{case.name} (glossy MC, {GLOSSY_MC_SAMPLES} samples)", stats),
          f"LazyVis' own noise {100 * own_noise / stats['mean']:.3f}%, combined ratio {ratio:.2f}")
    assert ratio <= RATIO_LIMIT and abs(stats["bias"]) < BIAS_LIMIT, describe(case.name, stats)


@pytest.mark.parametrize("case", GLOSSY_CASES, ids=[case.name for case in GLOSSY_CASES])
def test_glossy_default_integral_matches_cycles_within_the_noise(addon, case, tmp_path):
    """Issue 16: at LazyVis' defaults (LTC, and what it leaves out of the lobe's shape and the Fresnel's change
    over a piece by a Gauss rule in LTC's cosine domain) the glossy floor is within Cycles' noise, where plain
    LTC is 1-6 % off (``test_glossy_ltc_error_against_cycles_is_as_documented``). Measured 2026-12-06:
    ratio 1.04 / 1.05 / 1.01 / 1.03 at roughness 0.1 / 0.3 / 0.5 / 0.8 (with the Fresnel at each piece's
    centroid, as before: 1.21 / 2.1 / 7.5 / 8.2, 0.1 % off where the noise is 0.01-0.04 %).

    These references are converged to 0.01 % of the mean at roughness 0.5-0.8, so Cycles' stray samples (1 in
    1023 per axis, anywhere in the pixel's left or lower half: ``with_stray_samples``) are modelled here as
    for textures: the row just above the floor's far edge (0.12 pixel below its centres) takes 0.063 % of the
    floor's radiance from them in Cycles and nothing in a point-sampled LazyVis, 3 times the noise there."""
    first, second = references(case)
    ours = with_stray_samples(case, render_lazyvis(case, "analytic", tmp_path), tmp_path, always=True)
    edges, at_emitters, _ = excluded_pixels(case, tmp_path)
    stats = agreement(ours, first, second, ~(edges | at_emitters))
    print(describe(f"{case.name} (default glossy)", stats))
    assert stats["ratio"] <= RATIO_LIMIT and abs(stats["bias"]) < BIAS_LIMIT, describe(case.name, stats)


@pytest.mark.parametrize("case", GLOSSY_CASES, ids=[case.name for case in GLOSSY_CASES])
def test_glossy_ltc_error_against_cycles_is_as_documented(addon, case, tmp_path):
    first, second = references(case)
    ours = render_lazyvis(case, "analytic", tmp_path, glossy_integrator="ltc")
    edges, at_emitters, _ = excluded_pixels(case, tmp_path)
    stats = agreement(ours, first, second, ~(edges | at_emitters))
    roughness = dict(case.options)["roughness"]
    rmse_limit, bias_limit = LTC_LIMITS[roughness]
    print(describe(f"{case.name} (LTC)", stats))
    assert stats["relative_rmse"] <= rmse_limit and abs(stats["bias"]) <= bias_limit, describe(case.name, stats)
