"""Random and adversarial scenes for the core's ``render`` (issue 17's fuzzing), as Hypothesis strategies.

A scene is drawn as a ``SceneRecipe``: a handful of structural choices (how many blockers and of which
adversarial kinds, the lights, the camera, the scale) and one integer seed for the coordinates, so a
failing example prints as a short, exactly reproducible recipe (``recipe.build()``), and Hypothesis
shrinks the choices rather than thousands of floats. Used by ``tests/test_fuzz.py`` (a fast,
derandomized profile in CI) and ``bench/fuzz.py`` (thousands of examples, failures counted).

What can go wrong, and so what a recipe can hold, follows the issue: triangle soups, coplanar and duplicate
faces, blockers touching receivers and lights, lights inside or crossing geometry, slivers, degenerate and
collinear triangles, scales from 1e-4 to 1e4, cameras inside geometry, orthographic cameras, tiny and huge
lights, many lights, point / spot / sun lamps, glossy materials, every integrator and anti-aliasing setting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from hypothesis import strategies as st

from lazyvis_addon.core.demo_scenes import box_triangles, icosphere_triangles, look_at, quad_triangles, rectangle_light
from lazyvis_addon.core.scene import Camera, FacingLights, Lights, Materials, Scene
from lazyvis_addon.core.settings import GLOSSY_INTEGRATORS, INTEGRATORS, VISIBILITY_METHODS, Settings

SCALES = (1e-4, 1e-2, 1.0, 1e2, 1e4)
# The adversarial kinds of blocker a recipe may add (each a few triangles, see ``_adversarial``).
KINDS = ("soup", "box", "duplicate", "coplanar_ground", "degenerate", "collinear", "sliver", "tiny",
         "touching_ground", "touching_light", "crossing_light", "standing_wall", "sphere", "leaves",
         "open_mesh", "duplicate_crossing")
LIGHT_SIZES = (1e-4, 0.02, 0.4, 1.5, 6.0)
LIGHT_PLACES = ("above", "tilted", "inside", "low", "facing_up")
LAMP_KINDS = ("point", "soft_point", "spot", "sun")
CAMERAS = ("perspective", "orthographic", "inside_box", "low_grazing")
MATERIALS = ("diffuse", "principled", "metal", "glossy", "black")
# Bad input a user's file or script can hold (``_damage``): each must give an image or a clean error.
DAMAGES = ("", "nan_vertex", "inf_vertex", "overflow", "zero_light", "collinear_light", "nan_radiance",
           "negative_radiance", "zero_radiance", "nan_camera", "nan_lamp", "zero_lamp", "nan_normals",
           "negative_albedo", "huge_roughness")


@dataclass(frozen=True)
class SceneRecipe:
    """Everything that decides a fuzzed scene; ``build()`` makes it (deterministic)."""

    seed: int
    scale: float
    ground: bool
    kinds: tuple[str, ...]
    lights: tuple[tuple[str, float, int], ...]     # (place, size, sides of the polygon)
    lamps: tuple[tuple[str, float], ...]           # (kind, radius or angle)
    camera: str
    width: int
    height: int
    materials: tuple[str, ...]
    smooth: bool = False
    terminator: float = 0.0
    damage: str = ""

    def build(self) -> Scene:
        # One random stream per part (seeded by the recipe's seed and the part), so that dropping a part
        # while shrinking leaves the others where they were.
        def rng(*part):
            return np.random.default_rng([self.seed, *part])

        s = self.scale
        triangles = []
        if self.ground:
            triangles.append(quad_triangles([(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)]))
        light_polygons = [_light_polygon(place, size, sides, rng(1, i))
                          for i, (place, size, sides) in enumerate(self.lights)]
        for i, kind in enumerate(self.kinds):  # a handful of kinds per recipe
            triangles.append(_adversarial(kind, rng(2, i, KINDS.index(kind)), light_polygons))
        tris = np.concatenate(triangles) if triangles else np.zeros((0, 3, 3))
        material_index = rng(3).integers(0, len(self.materials), len(tris))
        materials = _materials(self.materials, rng(4))
        light_rng = rng(5)
        radiance = light_rng.uniform(0.5, 12.0, (len(light_polygons), 3))
        lights = Lights.from_polygons([p * s for p in light_polygons], radiance,
                                      two_sided=light_rng.random(len(light_polygons)) < 0.25) if light_polygons \
            else Lights.empty()
        facing = FacingLights.concat([_lamp(kind, size, s, rng(6, i)) for i, (kind, size) in enumerate(self.lamps)])
        camera = _camera(self.camera, self.width, self.height, s, rng(7))
        shading_normals = None
        if self.smooth and len(tris):
            # Vertex normals tilted off the face normal by up to ~25 degrees: what a smooth-shaded coarse
            # mesh gives, where the terminator lift applies.
            face = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
            length = np.linalg.norm(face, axis=1, keepdims=True)
            face = np.where(length > 0, face / np.where(length > 0, length, 1.0), np.array([0.0, 0.0, 1.0]))
            shading_normals = face[:, None, :] + rng(8).uniform(-0.45, 0.45, (len(tris), 3, 3))
            shading_normals /= np.linalg.norm(shading_normals, axis=2, keepdims=True)
        scene = Scene(tris * s, material_index, materials, lights, camera,
                      background=np.array([0.02, 0.03, 0.04]), shading_normals=shading_normals,
                      terminator_offset=np.full(len(tris), self.terminator) if self.terminator else None,
                      facing=facing)
        return _damage(scene, self.damage) if self.damage else scene


def _damage(scene: Scene, damage: str) -> Scene:
    """``scene`` with one kind of bad input written into its arrays (after construction, as a script or a
    corrupt file could leave them); a part the scene lacks stays as it is."""
    if damage in ("nan_vertex", "inf_vertex", "overflow") and len(scene.triangles):
        scene.triangles = scene.triangles.copy()
        if damage == "overflow":  # beyond float32, which Embree takes
            scene.triangles *= 1e39 / max(float(np.abs(scene.triangles).max()), 1e-300)
        else:
            scene.triangles[0, 0, 0] = np.nan if damage == "nan_vertex" else np.inf
    elif damage in ("zero_light", "collinear_light", "nan_radiance", "negative_radiance", "zero_radiance") \
            and len(scene.lights):
        lights = scene.lights
        lights.vertices, lights.radiance = lights.vertices.copy(), lights.radiance.copy()
        if damage == "zero_light":
            lights.vertices[0] = lights.vertices[0, :1]
        elif damage == "collinear_light":
            lights.vertices[0] = lights.vertices[0, 0] + np.linspace(0, 1, lights.vertices.shape[1])[:, None]
        else:
            lights.radiance[0] = {"nan_radiance": np.nan, "negative_radiance": -1.0, "zero_radiance": 0.0}[damage]
    elif damage == "nan_camera":
        scene.camera.world_from_camera = scene.camera.world_from_camera.copy()
        scene.camera.world_from_camera[0, 3] = np.nan
    elif damage in ("nan_lamp", "zero_lamp") and len(scene.facing):
        scene.facing.centre = scene.facing.centre.copy()
        scene.facing.intensity = scene.facing.intensity.copy()
        if damage == "nan_lamp":
            scene.facing.centre[0, 0] = np.nan
        else:
            scene.facing.intensity[0] = 0.0
    elif damage == "nan_normals" and scene.shading_normals is not None and len(scene.shading_normals):
        scene.shading_normals = scene.shading_normals.copy()
        scene.shading_normals[0] = 0.0  # a zero vector: NaN once normalized
    elif damage == "negative_albedo":
        scene.materials.albedo = scene.materials.albedo.copy()
        scene.materials.albedo[0] = -0.5
    elif damage == "huge_roughness":
        scene.materials.roughness = np.full_like(scene.materials.roughness, 1e6)
    return scene


def _light_polygon(place: str, size: float, sides: int, rng) -> np.ndarray:
    """(sides, 3) vertices of a convex light (unscaled world units) facing down onto the ground, or as
    ``place`` says: tilted, inside the blockers' space, just above the ground, or facing away."""
    centre = np.array([rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(2.2, 3.2)])
    normal = np.array([0.0, 0.0, -1.0])
    if place == "tilted":
        normal = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), -rng.uniform(0.05, 1.0)])
    elif place == "inside":
        centre[2] = rng.uniform(0.3, 1.5)
    elif place == "low":
        centre[2] = rng.uniform(1e-3, 0.05)
    elif place == "facing_up":
        normal = np.array([0.0, 0.0, 1.0])
    if sides == 4:
        return rectangle_light(centre, size, size * rng.uniform(0.2, 1.0), normal)
    square = rectangle_light(centre, 1.0, 1.0, normal)
    tangent, bitangent = square[1] - square[0], square[3] - square[0]
    angle = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False) + rng.uniform(0, 1)
    return centre + 0.5 * size * (np.cos(angle)[:, None] * tangent + np.sin(angle)[:, None] * bitangent)


def _adversarial(kind: str, rng, lights: list[np.ndarray]) -> np.ndarray:
    """A few triangles (k, 3, 3) of one adversarial kind, in the unscaled scene (ground 4 x 4 at z = 0,
    lights about 2.2-3.2 above it)."""
    def point(low_z=0.2, high_z=2.0):
        return np.array([rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(low_z, high_z)])

    if kind == "soup":
        return np.array([[point(), point(), point()] for _ in range(int(rng.integers(1, 8)))])
    if kind == "box":
        return box_triangles(point(0.3, 1.5), rng.uniform(0.1, 0.9, 3), rng.uniform(0, np.pi))
    if kind == "duplicate":
        tri = np.array([[point(), point(), point()]])
        flipped = tri[:, ::-1]
        return np.concatenate([tri, tri, flipped])
    if kind == "coplanar_ground":  # faces lying in the ground's plane, overlapping it and each other
        a = np.array([[point(0, 0), point(0, 0), point(0, 0)] for _ in range(2)])
        return a
    if kind == "degenerate":  # a repeated vertex and a point triangle
        p, q = point(), point()
        return np.array([[p, p, q], [q, q, q]])
    if kind == "collinear":
        p, q = point(), point()
        return np.array([[p, 0.5 * (p + q), q]])
    if kind == "sliver":
        p, q = point(), point()
        r = 0.5 * (p + q) + rng.normal(size=3) * 1e-7
        return np.array([[p, q, r]])
    if kind == "tiny":  # blockers far below a pixel's footprint
        p = point()
        return p + rng.normal(size=(3, 3, 3)) * 1e-5
    if kind == "touching_ground":  # an edge on the ground, the face rising from it
        p, q = point(0, 0), point(0, 0)
        return np.array([[p, q, 0.5 * (p + q) + np.array([0.0, 0.0, rng.uniform(0.1, 1.0)])]])
    if kind in ("touching_light", "crossing_light", "duplicate_crossing"):
        light = lights[int(rng.integers(len(lights)))] if lights else np.array([[0, 0, 2.5]] * 3, float)
        centre = light.mean(axis=0)
        if kind == "touching_light":  # a vertex on the light's surface
            return np.array([[centre, point(), point()]])
        # a face through the light's plane and polygon (and its copies, one flipped)
        face = np.array([[centre + np.array([0, 0, 0.3]), centre - np.array([0.2, 0, 0.3]),
                          centre - np.array([-0.2, 0.1, 0.3])]])
        return np.concatenate([face, face, face[:, ::-1]]) if kind == "duplicate_crossing" else face
    if kind == "standing_wall":  # a vertical quad from the ground up, a long thin shadow caster
        p, q = point(0, 0), point(0, 0)
        h = np.array([0.0, 0.0, rng.uniform(0.05, 2.0)])
        return quad_triangles([p, q, q + h, p + h])
    if kind == "sphere":  # a closed smooth mesh: silhouettes are chains of shared edges
        return icosphere_triangles(point(0.3, 1.5), rng.uniform(0.1, 0.7), int(rng.integers(1, 3)))
    if kind == "leaves":  # a crown of many small separate quads: heavy couples, cut into cells
        centres = np.array([point(0.6, 1.8) for _ in range(int(rng.integers(20, 120)))])
        u, v = rng.normal(size=(len(centres), 3)) * 0.06, rng.normal(size=(len(centres), 3)) * 0.06
        return np.concatenate([np.stack([centres, centres + u, centres + u + v], axis=1),
                               np.stack([centres, centres + u + v, centres + v], axis=1)])
    if kind == "open_mesh":  # a wavy height-field sheet: an open, non-convex mesh with rims
        n = int(rng.integers(3, 9))
        x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
        z = 1.0 + 0.3 * np.sin(3 * x + rng.uniform(0, 6)) * np.cos(2 * y)
        grid = np.stack([x, y, z], axis=-1)
        a, b, c, d = grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]
        return np.concatenate([np.stack([a, b, c], axis=-2).reshape(-1, 3, 3),
                               np.stack([a, c, d], axis=-2).reshape(-1, 3, 3)])
    raise ValueError(kind)


def _materials(kinds: tuple[str, ...], rng) -> Materials:
    rows = len(kinds)
    albedo = rng.uniform(0.05, 0.95, (rows, 3))
    principled = np.array([k in ("principled", "metal") for k in kinds])
    metallic = np.array([1.0 if k == "metal" else 0.0 for k in kinds])
    roughness = rng.uniform(0.02, 1.0, rows)
    glossy_colour = np.array([[0.8, 0.8, 0.8] if k == "glossy" else [0.0, 0.0, 0.0] for k in kinds])
    diffuse_weight = np.array([0.0 if k == "glossy" else 1.0 for k in kinds])
    albedo[np.array([k == "black" for k in kinds])] = 0.0
    return Materials(albedo, principled=principled, metallic=metallic, roughness=roughness,
                     glossy_colour=glossy_colour, diffuse_weight=diffuse_weight)


def _lamp(kind: str, size: float, s: float, rng) -> FacingLights:
    centre = np.array([rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(1.0, 3.0)]) * s
    power = rng.uniform(0.5, 5.0, 3)
    if kind == "sun":
        towards = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.05, 1.0)])
        return FacingLights.sun(towards, size, power)
    lamp = FacingLights.point(centre, size * s, power * s * s, soft_falloff=kind != "point")
    if kind == "spot":
        frame = look_at(centre, np.zeros(3))[:3, :3].T * s
        return lamp.spot(frame, rng.uniform(0.2, 2.5), rng.uniform(0.0, 1.0))
    return lamp


def _camera(kind: str, width: int, height: int, s: float, rng) -> Camera:
    if kind == "orthographic":
        eye = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), 6.0]) * s
        return Camera.orthographic(look_at(eye, np.zeros(3), up=(0, 1, 0)), width, height, 5.0 * s)
    if kind == "inside_box":  # within the blockers' space (often inside a box or among the soup)
        eye = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(0.4, 1.2)]) * s
        return Camera.perspective(look_at(eye, np.array([0.0, 0.0, 0.0])), width, height, np.radians(80.0))
    if kind == "low_grazing":  # the ground seen at grazing angles
        eye = np.array([rng.uniform(-1, 1), -4.0, rng.uniform(0.01, 0.1)]) * s
        return Camera.perspective(look_at(eye, np.array([0.0, 0.0, 0.0])), width, height, np.radians(60.0))
    angle = rng.uniform(0, 2 * np.pi)
    eye = np.array([5.0 * math.cos(angle), 5.0 * math.sin(angle), rng.uniform(1.0, 6.0)]) * s
    return Camera.perspective(look_at(eye, np.array([0.0, 0.0, 0.5]) * s), width, height, np.radians(55.0))


@st.composite
def scene_recipes(draw, max_kinds: int = 5, max_size: int = 12, damage: bool = False) -> SceneRecipe:
    """A ``SceneRecipe``: up to ``max_kinds`` adversarial blocker kinds, 0-3 polygon lights and 0-2 lamps (at
    least one light of either), an image of up to ``max_size`` pixels a side; with ``damage``, one kind of
    bad input (``DAMAGES``) or none."""
    lights = draw(st.lists(st.tuples(st.sampled_from(LIGHT_PLACES), st.sampled_from(LIGHT_SIZES),
                                     st.sampled_from((3, 4, 6, 16))), max_size=3))
    lamps = draw(st.lists(st.tuples(st.sampled_from(LAMP_KINDS), st.sampled_from((0.0, 0.01, 0.3))),
                          min_size=0 if lights else 1, max_size=2))
    return SceneRecipe(
        seed=draw(st.integers(0, 2 ** 31 - 1)),
        scale=draw(st.sampled_from(SCALES)),
        ground=draw(st.booleans()),
        kinds=tuple(draw(st.lists(st.sampled_from(KINDS), max_size=max_kinds))),
        lights=tuple(lights), lamps=tuple(lamps),
        camera=draw(st.sampled_from(CAMERAS)),
        width=draw(st.integers(1, max_size)), height=draw(st.integers(1, max_size)),
        materials=tuple(draw(st.lists(st.sampled_from(MATERIALS), min_size=1, max_size=3))),
        smooth=draw(st.booleans()),
        terminator=draw(st.sampled_from((0.0, 0.1, 1.0))),
        # Half the recipes damaged, so that half still test what healthy scenes do.
        damage=draw(st.sampled_from(("",) * (len(DAMAGES) - 1) + DAMAGES[1:])) if damage else "",
    )


@st.composite
def render_settings(draw) -> Settings:
    """Every integrator, glossy integrator, visibility method and anti-aliasing setting, at sample counts
    small enough for hundreds of renders."""
    return Settings(
        integrator=draw(st.sampled_from(INTEGRATORS)),
        glossy_integrator=draw(st.sampled_from(GLOSSY_INTEGRATORS)),
        visibility=draw(st.sampled_from(VISIBILITY_METHODS)),
        shadow_rays=draw(st.sampled_from((1, 4))),
        mc_samples=draw(st.sampled_from((1, 4))),
        verify_rays=draw(st.sampled_from((0, 4))),
        aa_samples=draw(st.sampled_from((1, 2, 16))),
        aa_coverage_rays=draw(st.sampled_from((0, 16))),
        filter_width=draw(st.sampled_from((0.01, 1.5, 4.0))),
        filter_type=draw(st.sampled_from(("BLACKMAN_HARRIS", "GAUSSIAN", "BOX"))),
        transparent_background=draw(st.booleans()),
        threads=draw(st.sampled_from((1, 2))),
        merge_quads=draw(st.booleans()),
        memory_budget_mb=draw(st.sampled_from((2048.0,) * 7 + (1.0,))),
    )


def check_image(recipe: SceneRecipe, settings: Settings):
    """The robustness property: building ``recipe``'s scene and rendering it give a finite, non-negative
    image of the camera's window, or raise ValueError / MemoryError whose message says something. Returns
    the output (None if it raised)."""
    from lazyvis_addon.core.render import render

    try:
        scene = recipe.build()
        out = render(scene, settings)
    except (ValueError, MemoryError) as error:
        assert str(error).strip(), f"{type(error).__name__} without a message"
        return None
    height, width = scene.camera.window_shape
    assert out.combined.shape == (height, width, 4), out.combined.shape
    assert np.isfinite(out.combined).all(), "non-finite pixels"
    assert (out.combined >= 0.0).all(), f"negative pixels: min {out.combined.min()}"
    alpha = out.combined[..., 3]
    assert (alpha <= 1.0 + 1e-9).all(), f"alpha above 1: {alpha.max()}"
    for name in ("depth", "normal", "sample_count"):
        assert not np.isnan(getattr(out, name)).any(), f"NaN in the {name} pass"
    return out
