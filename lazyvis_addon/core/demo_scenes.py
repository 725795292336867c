"""Small built-in scenes: the paper's floating boxes, a plane under a light. Used by the sample render,
the tests and the benchmark, and handy to try the core without Blender."""

from __future__ import annotations

import numpy as np

from .scene import Camera, Lights, Materials, Scene


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """world_from_camera (4, 4) for a camera at ``eye`` looking at ``target`` (Blender axes: looks along -Z)."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-9:
        right = np.cross((0.0, 1.0, 0.0), back)
    right /= np.linalg.norm(right)
    true_up = np.cross(back, right)
    matrix = np.eye(4)
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = right, true_up, back, eye
    return matrix


def box_triangles(centre, size, rotation_z: float = 0.0) -> np.ndarray:
    """An axis-aligned box (turned about Z) as (12, 3, 3) outward-wound triangles."""
    corners = np.array([[x, y, z] for z in (-0.5, 0.5) for y in (-0.5, 0.5) for x in (-0.5, 0.5)])
    corners = corners * np.asarray(size, dtype=np.float64)
    c, s = np.cos(rotation_z), np.sin(rotation_z)
    corners = corners @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) + np.asarray(centre, dtype=np.float64)
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = [(a, b, c_) for a, b, c_, d in faces] + [(a, c_, d) for a, b, c_, d in faces]
    return corners[np.array(tris)]


def quad_triangles(corners) -> np.ndarray:
    """A planar quad (4, 3) as (2, 3, 3) triangles."""
    corners = np.asarray(corners, dtype=np.float64)
    return corners[np.array([(0, 1, 2), (0, 2, 3)])]


def icosphere_triangles(centre, radius: float, level: int = 3) -> np.ndarray:
    """An icosphere's faces (20 * 4^level, 3, 3) float64, wound outward: a closed convex mesh."""
    t = (1.0 + 5.0 ** 0.5) / 2.0
    points = [np.array(p, np.float64) for p in ((-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t),
                                                (0, 1, t), (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1),
                                                (-t, 0, -1), (-t, 0, 1))]
    points = [p / np.linalg.norm(p) for p in points]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(level):  # subdivision levels: a handful
        middle = {}

        def midpoint(a, b):
            key = (min(a, b), max(a, b))
            if key not in middle:
                m = points[a] + points[b]
                points.append(m / np.linalg.norm(m))
                middle[key] = len(points) - 1
            return middle[key]

        faces = [f for a, b, c in faces
                 for ab, bc, ca in [(midpoint(a, b), midpoint(b, c), midpoint(c, a))]
                 for f in ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))]
    return np.asarray(centre, np.float64) + radius * np.array(points)[np.array(faces)]


def rectangle_light(centre, size_x: float, size_y: float, normal=(0.0, 0.0, -1.0)) -> np.ndarray:
    """Vertices (4, 3) of a rectangle light facing ``normal``, counter-clockwise about it."""
    normal = np.asarray(normal, dtype=np.float64)
    normal /= np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    tangent = np.cross(helper, normal)
    tangent /= np.linalg.norm(tangent)
    bitangent = np.cross(normal, tangent)
    hx, hy = 0.5 * size_x, 0.5 * size_y
    offsets = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
    return np.array([np.asarray(centre) + a * tangent + b * bitangent for a, b in offsets])


def floating_boxes(resolution: int = 512, n_boxes: int = 49, seed: int = 7) -> Scene:
    """The paper's Fig. 7 set-up: boxes floating over a ground plane before a back wall, 4 coloured lights
    of different sizes. About 600 triangles with the default 49 boxes."""
    rng = np.random.default_rng(seed)
    tris = [quad_triangles([(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)])]
    materials = [(0.8, 0.8, 0.8)]
    material_index = [0, 0]
    palette = [(0.8, 0.3, 0.2), (0.2, 0.7, 0.3), (0.25, 0.35, 0.8), (0.8, 0.75, 0.3), (0.7, 0.7, 0.7)]
    materials += palette
    side = int(np.ceil(np.sqrt(n_boxes)))
    for index in range(n_boxes):  # scene construction, not a hot path
        gx, gy = index % side, index // side
        centre = (-3.6 + 7.2 * (gx + 0.5) / side + rng.uniform(-0.25, 0.25),
                  -3.6 + 7.2 * (gy + 0.5) / side + rng.uniform(-0.25, 0.25), rng.uniform(0.5, 2.0))
        size = rng.uniform(0.25, 0.6, 3)
        tris.append(box_triangles(centre, size, rng.uniform(0, np.pi)))
        material_index += [1 + index % len(palette)] * 12
    triangles = np.concatenate(tris)
    lights = Lights.from_polygons(
        [rectangle_light((-2.0, -1.5, 4.5), 1.6, 1.0), rectangle_light((2.5, 1.5, 5.0), 0.8, 0.8),
         rectangle_light((0.5, -3.0, 3.8), 2.4, 0.5), rectangle_light((-1.5, 3.0, 4.2), 0.6, 1.4)],
        radiance=[(15.0, 12.5, 10.0), (10.0, 15.0, 22.0), (12.5, 6.0, 5.0), (7.5, 12.5, 7.5)])
    camera = Camera.perspective(look_at((0.0, -11.0, 7.5), (0.0, 0.0, 0.8)), resolution, resolution,
                                np.radians(50.0))
    return Scene(triangles, np.array(material_index), Materials.diffuse(materials), lights, camera,
                 background=np.array([0.05, 0.05, 0.06]))


def plane_under_light(resolution: int = 64, light_size: float = 1.0, height: float = 1.0,
                      blocker: np.ndarray | None = None, radiance: float = 1.0) -> Scene:
    """A 4 x 4 grey plane (albedo 0.5) at z = 0 under a square light at ``height`` facing down, seen from
    straight above; ``blocker`` adds (k, 3, 3) triangles."""
    tris = quad_triangles([(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)])
    material_index = [0, 0]
    if blocker is not None:
        tris = np.concatenate([tris, np.asarray(blocker, dtype=np.float64).reshape(-1, 3, 3)])
        material_index += [0] * (len(tris) - 2)
    lights = Lights.from_polygons([rectangle_light((0, 0, height), light_size, light_size)], [(radiance,) * 3])
    camera = Camera.orthographic(look_at((0, 0, 5.0), (0, 0, 0), up=(0, 1, 0)), resolution, resolution, 4.0)
    return Scene(tris, np.array(material_index), Materials.diffuse([(0.5, 0.5, 0.5)]), lights, camera)


def fence(resolution: int = 256) -> Scene:
    """Thin high-contrast geometry: a fence of dark posts and rails over a lit ground before a light wall,
    one area light. For anti-aliasing measurements (edges and thin sharp shadows everywhere)."""
    tris = [quad_triangles([(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)]),
            quad_triangles([(-6, 3, 0), (6, 3, 0), (6, 3, 4), (-6, 3, 4)])]
    material_index = [0, 0, 0, 0]
    for x in np.linspace(-3.0, 3.0, 25):  # scene construction, not a hot path
        tris.append(box_triangles((x, 0.0, 0.6), (0.05, 0.05, 1.2)))
        material_index += [1] * 12
    for z in (0.4, 1.0):
        tris.append(box_triangles((0.0, 0.0, z), (6.2, 0.03, 0.04)))
        material_index += [1] * 12
    lights = Lights.from_polygons([rectangle_light((1.5, -2.5, 4.0), 1.0, 1.0, normal=(-0.2, 0.5, -1.0))],
                                  [(30.0, 28.0, 25.0)])
    camera = Camera.perspective(look_at((0.5, -7.0, 2.2), (0.0, 0.0, 0.8)), resolution, resolution, np.radians(45.0))
    return Scene(np.concatenate(tris), np.array(material_index),
                 Materials.diffuse([(0.8, 0.8, 0.75), (0.03, 0.03, 0.03)]), lights, camera,
                 background=np.array([0.02, 0.02, 0.03]))
