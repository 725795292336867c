"""Primary visibility: what each pixel sees, with the normals and offsets the passes need."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bsdf import glossy_materials
from .scene import FACING_SUN, Scene
from .terminator import terminator_lift
from .texture import interpolate_corner_attribute

# Shadow-ray origins move off the surface by this many units of the hit point's coordinate magnitude
# (float32 Embree keeps ~7 digits), plus a floor relative to the scene's extent: scale independent.
OFFSET_RELATIVE = 2e-5
OFFSET_SCENE = 1e-7


@dataclass
class SurfacePoints:
    """The visible point of every pixel of a batch (or of the window).

    Attributes
    ----------
    hit : (N,) bool                   a surface is seen.
    position : (N, 3) float64         visible point x (world), exact on the triangle (from barycentrics).
    geometric_normal : (N, 3)         unit, turned to face the camera (receivers are two-sided).
    shading_normal : (N, 3)           unit, interpolated if the scene has shading normals, on the
                                      geometric normal's side.
    index_triangle : (N,) int64       -1 where nothing is hit.
    albedo : (N, 3) float64
    emission : (N, 3) float64         radiance the surface itself emits (mesh emitters).
    offset : (N,) float64             shadow-ray origin offset along the geometric normal (world units).
    material : (N,) int64             row of ``scene.materials``, -1 where nothing is hit.
    view : (N, 3) float64             unit direction from the point towards the camera (ω_o).
    lift : (N, 3) float64             where Cycles' Shadow Terminator Geometry Offset moves shadow rays'
                                      origin at full strength: onto the smooth surface the vertex normals
                                      describe (``terminator.terminator_lift``; 0 on flat-shaded triangles).
    lift_cutoff : (N,) float64        the object's offset setting: how grazing light must be for the lift
                                      to apply (0: never; ``terminator.lift_amount``).
    """

    hit: np.ndarray
    position: np.ndarray
    geometric_normal: np.ndarray
    shading_normal: np.ndarray
    index_triangle: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    offset: np.ndarray
    material: np.ndarray
    view: np.ndarray
    lift: np.ndarray
    lift_cutoff: np.ndarray

    def __len__(self) -> int:
        return len(self.hit)

    def take(self, index: np.ndarray) -> "SurfacePoints":
        return SurfacePoints(self.hit[index], self.position[index], self.geometric_normal[index],
                             self.shading_normal[index], self.index_triangle[index], self.albedo[index],
                             self.emission[index], self.offset[index], self.material[index], self.view[index],
                             self.lift[index], self.lift_cutoff[index])


def scene_extent(scene: Scene) -> float:
    """Diagonal of the bounding box of triangles and lights (world units; 1 for an empty scene)."""
    lamps = scene.facing.centre[scene.facing.kind != FACING_SUN]
    points = [scene.triangles.reshape(-1, 3), scene.lights.vertices.reshape(-1, 3), lamps]
    points = np.concatenate([p for p in points if len(p)]) if any(len(p) for p in points) else np.zeros((0, 3))
    if len(points) == 0:
        return 1.0
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) or 1.0


def scene_centre(scene: Scene) -> np.ndarray:
    """Centre (3,) of the bounding box of triangles, polygon lights and lamps (the origin if empty)."""
    lamps = scene.facing.centre[scene.facing.kind != FACING_SUN]
    points = [p for p in (scene.triangles.reshape(-1, 3), scene.lights.vertices.reshape(-1, 3), lamps) if len(p)]
    if not points:
        return np.zeros(3)
    points = np.concatenate(points)
    return 0.5 * (points.max(axis=0) + points.min(axis=0))


def albedo_scaled_materials(scene: Scene) -> np.ndarray:
    """(M,) bool: the materials whose albedo comes from a texture and scales all they reflect (no glossy
    lobe), so that under even light their radiance is the albedo times one irradiance."""
    return (scene.materials.texture_index >= 0) & ~glossy_materials(scene.materials)


def has_albedo_scaled(scene: Scene) -> bool:
    """Whether some material is one of ``albedo_scaled_materials``. Per material, not per triangle: it is
    asked for every run of anti-aliasing samples, and a material no triangle uses only costs a texture
    part of NaNs (``supersampling._texture_part``), which changes no pixel."""
    return bool(albedo_scaled_materials(scene).any())


def surface_albedo(scene: Scene, triangle: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Diffuse albedo (N, 3) float64 at barycentrics ``u``, ``v`` (N,) of triangles ``triangle`` (N,) int64 (all
    hit): the material's, or its texture's colour at the point's UV."""
    material = scene.material_index[triangle]
    albedo = np.array(scene.materials.albedo[material], dtype=np.float64)
    texture = scene.materials.texture_index[material]
    if (texture >= 0).any():
        uv = interpolate_corner_attribute(scene.corner_uvs, triangle, u, v)
        for index in np.unique(texture[texture >= 0]):  # textures: a handful
            chosen = texture == index
            albedo[chosen] = scene.textures[index].lookup(uv[chosen])[:, :3]
    return albedo


def shade_hits(scene: Scene, ray_origins: np.ndarray, ray_directions: np.ndarray, index_triangle: np.ndarray,
               u: np.ndarray, v: np.ndarray, extent: float) -> SurfacePoints:
    """Surface points from primary hits (index_triangle -1 = miss), all arrays (N, ...)."""
    n = len(index_triangle)
    hit = index_triangle >= 0
    tri = np.where(hit, index_triangle, 0)
    position = np.zeros((n, 3))
    geometric = np.zeros((n, 3))
    shading = np.zeros((n, 3))
    albedo = np.zeros((n, 3))
    emission = np.zeros((n, 3))
    material_row = np.full(n, -1, np.int64)
    if hit.any() and len(scene.triangles):
        corners = scene.triangles[tri[hit]]
        uh, vh = u[hit][:, None], v[hit][:, None]
        position[hit] = (1.0 - uh - vh) * corners[:, 0] + uh * corners[:, 1] + vh * corners[:, 2]
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        facing = np.where(np.einsum("nk,nk->n", normal, ray_directions[hit]) > 0, -1.0, 1.0)
        normal *= facing[:, None]
        geometric[hit] = normal
        if scene.shading_normals is not None:
            vertex_normals = scene.shading_normals[tri[hit]]
            smooth = (1.0 - uh - vh) * vertex_normals[:, 0] + uh * vertex_normals[:, 1] + vh * vertex_normals[:, 2]
            smooth *= facing[:, None]
            length = np.linalg.norm(smooth, axis=1, keepdims=True)
            smooth = np.where(length > 1e-12, smooth / np.maximum(length, 1e-300), normal)
            # A shading normal on the far side of the surface would light it from behind: bend it back.
            below = np.einsum("nk,nk->n", smooth, normal)
            smooth = np.where((below <= 0)[:, None], normal, smooth)
            shading[hit] = smooth
        else:
            shading[hit] = normal
        material = scene.material_index[tri[hit]]
        material_row[hit] = material
        albedo[hit] = surface_albedo(scene, tri[hit], u[hit], v[hit])
        emission[hit] = scene.materials.emission[material]
    offset = OFFSET_RELATIVE * np.abs(position).max(axis=1) + OFFSET_SCENE * extent
    length = np.linalg.norm(ray_directions, axis=1, keepdims=True)
    view = -ray_directions / np.maximum(length, 1e-300)
    lift = np.zeros((n, 3))
    lift_cutoff = np.zeros(n)
    if scene.terminator_offset is not None and scene.shading_normals is not None and hit.any():
        lift_cutoff[hit] = scene.terminator_offset[tri[hit]]
        lifted = np.flatnonzero(lift_cutoff > 0)
        if len(lifted):
            lift[lifted] = terminator_lift(scene.triangles[tri[lifted]], scene.shading_normals[tri[lifted]],
                                           u[lifted], v[lifted], geometric[lifted])
    return SurfacePoints(hit, position, geometric, shading, np.where(hit, index_triangle, -1), albedo, emission,
                         offset, material_row, view, lift, lift_cutoff)


def shadow_rays(surface: SurfacePoints, pixel: np.ndarray, direction: np.ndarray, pdf: np.ndarray,
                light_origin: np.ndarray, light_normal: np.ndarray, side: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shadow rays from visible points towards sampled directions on lights.

    Parameters
    ----------
    pixel : (N,) int64 rows of ``surface``; direction : (N, 3) unit; pdf : (N,) (0 = no sample);
    light_origin, light_normal : (N, 3); side : (N,) +1 / -1 (the light's side the receiver is on).

    Returns
    -------
    origin : (N, 3)   the visible point moved off its surface along the geometric normal.
    tfar : (N,)       distance to the light's plane along the ray, a little short of it so that the
                      light's own surroundings (a ceiling it is set into) are not reported.
    good : (N,) bool  the ray heads for the light's emitting side from in front of it.
    """
    origin = surface.position[pixel] + surface.offset[pixel, None] * surface.geometric_normal[pixel]
    toward = -side * np.einsum("nk,nk->n", direction, light_normal)
    height = side * np.einsum("nk,nk->n", origin - light_origin, light_normal)
    good = (pdf > 0) & (toward > 0) & (height > 0)
    tfar = np.where(good, height / np.where(good, toward, 1.0), 0.0) * (1.0 - 1e-6)
    return origin, tfar, good
