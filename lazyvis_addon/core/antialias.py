"""Anti-aliasing the paper's way (section 4.4), reconstructed with Blender's pixel filter.

Pass 1 runs with the extended flood fill, so a pixel's blocker list holds for every point seen through
it. Pixels whose neighbours see another polygon, another material or a clearly different radiance get
``aa_samples`` sub-pixel samples on average, more where the radiance step to a neighbour is larger
(``allocate_samples``), placed like Cycles' importance-sampled pixel filter (Blackman-Harris,
``filter_width`` a radius in pixels), at Owen-scrambled Sobol points; each sample is shaded with the
blocker list of the pixel it lands in. Cycles' pixel value is the plain mean of its samples; LazyVis
estimates the same filtered value from every supersampled pixel's samples under the pixel's filter,
weighted by the balance heuristic (``pool_samples``), which needs about half the samples for the same
error. Other pixels keep their centre sample: where nothing changes across a pixel the filtered value is
the centre value.

Coverage rays (``aa_coverage_rays``, beyond the paper) split an edge pixel's value by surface (connected
mesh and material): cheap camera rays that shade nothing measure how much of the pixel's filter each
surface covers, and the shaded samples, pass 1's centres among them, give each surface's mean radiance.
An object's outline then needs no more than a sample on each side, as in a rasteriser's multisample
anti-aliasing (coverage at many points, shading at few; Ragan-Kelley et al., "Decoupled sampling for
graphics pipelines", ACM TOG 30(3), 2011); sharp shadows and texture within one surface still take
samples. In survey sampling this is post-stratification (Holt and Smith, JRSS A 142, 1979).

The window's outermost pixels have neighbours outside it, which the filter (radius 1.5 px by default)
reaches as well: a ring of camera rays one pixel outside the window tells whether those see another
polygon or material (their radiance is not computed: one that sees nothing counts with the background's
radiance for the allocation, one that sees another surface as black).

A sample's inherited list is cut to the pairs that overlap at the sample (``cull_to_samples``; a closed
convex part's pairs stay, as pass 2 clips by the part's whole silhouette). It need not hold where the
sample sees another surface than the pixel's centre (``foreign_samples``): the render verifies those
samples with shadow rays (shading.shade_verified).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit

from . import rng
from .adaptive import close_holes, refine_mask
from .blocker_map import BlockerMap, test_pairs
from .blockers import triangle_components
from .borrowed import borrowed
from .camera import camera_rays, clip_distance, pixel_coordinates
from .film import filter_offsets, filter_table
from .parallel import map_batches, thread_count
from .scene import Scene
from .settings import Settings
from .surface import albedo_scaled_materials, scene_extent, shade_hits, surface_albedo
from .trace import RayTracer


def refine_pixels(scene: Scene, surface, radiance: np.ndarray, shape: tuple[int, int], settings: Settings,
                  tracer=None, window=None, radiance_floor: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The pixels to supersample and the radiance step at each.

    ``tracer``: the render's ray tracer, for the ring of camera rays just outside the window (a temporary
    one is built over ``scene.triangles`` when None). ``window``: the full-frame pixel bounds (x0, y0, x1,
    y1) of ``surface``'s grid (default the camera's window; a band of it, for the marks of the band's
    inner rows). ``radiance_floor``: differences below it never mark a pair (default 1e-4 of the largest
    radiance seen; a band takes the whole window's).

    Returns
    -------
    pixels : (P,) int64 window-local indices, ascending.
    contrast : (P,) float64 largest channel step to the 8 neighbours (``edge_contrast``); a neighbour just
    outside the window that sees nothing counts with the background's radiance, one that sees another
    surface (its radiance is not computed) as black: the filter averages those in.
    """
    height, width = shape
    material = _material(scene, surface.index_triangle)
    seen = radiance + surface.emission
    # Shading normals, compared within the relative threshold (radians): across a smooth-shaded mesh's
    # edges they turn by as little as the surface does, and a normal turning by less than the threshold
    # changes diffuse shading by less than the threshold. Face normals marked every pair of pixels on
    # two triangles of a curved mesh: half of Suzanne's marked pixels at 512 px, whose pilot samples then
    # all settled, and two thirds of the denser Suzanne's; a crease or a face seen against another still
    # marks its pixels.
    grids = (surface.index_triangle.reshape(height, width), material.reshape(height, width),
             surface.shading_normal.reshape(height, width, 3), seen.reshape(height, width, 3))
    reaches_out = settings.filter_reach > 0.5  # samples leave the pixel: the ring outside matters
    if reaches_out:
        grids = _with_outside_ring(scene, grids, tracer, settings, window)
    if radiance_floor is None:
        radiance_floor = 1e-4 * max(float(seen.max()) if seen.size else 0.0, 1e-30)
    mask = refine_mask(*grids, relative_threshold=settings.aa_threshold, normal_angle=settings.aa_threshold,
                       radiance_floor=radiance_floor)
    # Not dilated by the filter's reach: on the fence and rods scenes that marked 35% more pixels for no
    # measurable change in error (the Blackman-Harris tails carry little weight).
    mask = close_holes(mask)
    if not reaches_out:
        pixels = np.flatnonzero(mask)
        return pixels, edge_contrast(seen, shape, pixels)
    # An edge just outside the frame (a floor ending half a pixel below the bottom row) is averaged in by
    # the filter: without the ring, Cycles' bottom row of floating_boxes at 96 px was 16% darker.
    pixels = np.flatnonzero(mask[1:-1, 1:-1])
    return pixels, edge_contrast(_ring_radiance(scene, grids, settings), shape, pixels, padded=True)


def _ring_radiance(scene: Scene, grids, settings: Settings) -> np.ndarray:
    """(H + 2, W + 2, 3) radiance with the outside ring filled in: the background where the ring sees
    nothing, black where it sees another surface than the window pixel next to it (its radiance is not
    computed; a step to black is the guess), the window pixel's own radiance where it sees the same."""
    index_triangle, material, normal, seen = grids
    out = seen.copy()
    ring = np.ones(index_triangle.shape, bool)
    ring[1:-1, 1:-1] = False
    inner = np.pad(index_triangle[1:-1, 1:-1], 1, mode="edge")
    inner_material = np.pad(material[1:-1, 1:-1], 1, mode="edge")
    inner_normal = np.pad(normal[1:-1, 1:-1], [(1, 1), (1, 1), (0, 0)], mode="edge")
    empty = ring & (index_triangle < 0)
    other = ring & (index_triangle >= 0) & ((inner < 0) | (material != inner_material)
                                            | (np.einsum("...k,...k->...", normal, inner_normal) < 0.999))
    out[empty] = 0.0 if settings.transparent_background else scene.background
    out[other] = 0.0
    return out


# Edge pixels get between EDGE_SAMPLES_MIN and EDGE_SAMPLES_SPREAD times the mean samples.
EDGE_SAMPLES_MIN = 2
EDGE_SAMPLES_SPREAD = 4


def edge_contrast(radiance: np.ndarray, shape: tuple[int, int], pixels: np.ndarray, padded: bool = False
                  ) -> np.ndarray:
    """How far each pixel's centre radiance is from its 8 neighbours' (largest channel difference).

    Parameters
    ----------
    radiance : (H * W, 3) float64   radiance seen at the window's pixel centres (emission included), or with
                                    ``padded`` (H + 2, W + 2, 3) with a ring of pixels around the window.
    pixels : (P,) int64             window-local pixels.

    Returns
    -------
    (P,) float64, W m^-2 sr^-1 (without ``padded``, neighbours outside the window count as the pixel itself).
    """
    height, width = shape
    grid = radiance if padded else np.pad(radiance.reshape(height, width, -1), [(1, 1), (1, 1), (0, 0)],
                                          mode="edge")
    row, column = pixels // width + 1, pixels % width + 1
    centre = grid[row, column]
    contrast = np.zeros(len(pixels))
    for dy in (-1, 0, 1):  # the 8 neighbours of every pixel at once
        for dx in (-1, 0, 1):
            if dy or dx:
                contrast = np.maximum(contrast, np.abs(grid[row + dy, column + dx] - centre).max(axis=1))
    return contrast


def allocate_samples(contrast: np.ndarray, mean: int) -> np.ndarray:
    """Samples per edge pixel (P,) int64: ``mean`` on average, in proportion to each pixel's contrast.

    A pixel's error from S samples of an edge of contrast c falls like c / sqrt(S), so for a fixed total
    the summed squared error is least with S in proportion to c (Neyman allocation): a dark post against a
    bright floor gets many samples, a faint penumbra step few. Counts are kept between
    ``EDGE_SAMPLES_MIN`` (an edge between centres that agree still gets a look) and
    ``EDGE_SAMPLES_SPREAD * mean``; the proportional share is rescaled so that the mean stays ``mean``.
    On the fence (bench_antialias) this gives at 5 samples the error of 7 spread evenly.
    """
    return samples_for(contrast, neyman_share(contrast, mean), mean)


def neyman_share(contrast: np.ndarray, mean: int) -> float | None:
    """Samples per unit of contrast (``allocate_samples``) that give the pixels of ``contrast`` (P,) ``mean``
    samples on average once clipped, or None where every pixel simply gets ``mean`` (no room to spread,
    no pixels, or no finite positive contrast)."""
    count = len(contrast)
    if count == 0 or mean <= 1:
        return None
    low, high = min(EDGE_SAMPLES_MIN, mean), EDGE_SAMPLES_SPREAD * mean
    weight = np.asarray(contrast, dtype=np.float64)
    if not np.isfinite(weight).all() or weight.sum() <= 0.0:
        return None
    share = mean * count / weight.sum()
    for _ in range(8):  # fixed-point rescaling of the unclipped pixels: a few rounds settle it
        samples = np.clip(weight * share, low, high)
        free = (samples > low) & (samples < high)
        left = mean * count - samples[~free].sum()
        if not free.any() or left <= 0.0:
            break
        share = left / weight[free].sum()
    return float(share)


def samples_for(contrast: np.ndarray, share: float | None, mean: int) -> np.ndarray:
    """(P,) int64 samples of pixels of ``contrast`` (P,) at ``share`` samples per unit contrast, kept between
    ``EDGE_SAMPLES_MIN`` and ``EDGE_SAMPLES_SPREAD * mean`` (``mean`` each where ``share`` is None, or a
    contrast is not finite)."""
    contrast = np.asarray(contrast, dtype=np.float64)
    if share is None:
        return np.full(len(contrast), max(mean, 1), np.int64)
    low, high = min(EDGE_SAMPLES_MIN, mean), EDGE_SAMPLES_SPREAD * mean
    counts = np.clip(np.round(np.nan_to_num(contrast * share, nan=mean, posinf=high)), low, high)
    return counts.astype(np.int64)


# The anti-aliasing scale of a frame (``FrameScale``) comes from every pixel of a frame of up to this many
# pixels, and from PROBE_PATCHES patches of 3 x 3 pixels spread over a larger one.
FULL_PROBE_PIXELS = 1 << 16
PROBE_PATCHES = 1024


@dataclass(frozen=True)
class FrameScale:
    """What anti-aliasing takes from the whole frame, the same for the frame and for any window of it, so
    that a window's pixels are the frame's (a border render, a farm's tile).

    radiance_floor : float   radiance steps below this never mark a pixel (1e-4 of the brightest centre).
    share : float or None    samples per unit contrast (``neyman_share`` of the frame's marked pixels).
    """

    radiance_floor: float
    share: float | None


def probe_centres(width: int, height: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Full-frame (x, y) of the centres of the probe's patches, (ny,) and (nx,)-shaped as a grid (rows
    ``ys``, columns ``xs``), or None when the frame is small enough to be probed whole
    (``FULL_PROBE_PIXELS``). The patches lie on a regular lattice, their 3 x 3 pixels inside the frame."""
    if width * height <= FULL_PROBE_PIXELS or width < 3 or height < 3:
        return None
    stride = max(3, int(np.sqrt(width * height / PROBE_PATCHES)))
    xs = np.arange(stride // 2, width - 1, stride, dtype=np.int64)
    ys = np.arange(stride // 2, height - 1, stride, dtype=np.int64)
    return np.maximum(xs, 1), np.maximum(ys, 1)


def probe_pixels(xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Full-frame (x, y) (3 ny * 3 nx,) int64 of the patches around ``probe_centres``, row-major over the
    (3 ny, 3 nx) grid that puts the patches side by side (a patch's centre sees only its own 8 pixels
    around it, so ``refine_mask`` and ``edge_contrast`` at the centres read the frame's own neighbours)."""
    offsets = np.array([-1, 0, 1], np.int64)
    grid_x = (xs[:, None] + offsets[None, :]).reshape(-1)
    grid_y = (ys[:, None] + offsets[None, :]).reshape(-1)
    x, y = np.meshgrid(grid_x, grid_y)
    return x.reshape(-1), y.reshape(-1)


def patch_scale(scene: Scene, index_triangle: np.ndarray, shading_normal: np.ndarray, seen: np.ndarray,
                shape: tuple[int, int], settings: Settings) -> FrameScale:
    """``FrameScale`` from the probe's patches: the brightest of their pixels sets the radiance floor, and
    the centres that ``refine_mask`` marks within their patch give the share of their contrasts.

    Parameters
    ----------
    index_triangle : (N,) int; shading_normal : (N, 3); seen : (N, 3) radiance with emission, of the
    ``probe_pixels`` in their order; shape : (3 ny, 3 nx).
    """
    floor = 1e-4 * max(float(seen.max()) if seen.size else 0.0, 1e-30)
    rows, columns = shape
    material = _material(scene, index_triangle)
    mask = refine_mask(index_triangle.reshape(shape), material.reshape(shape), shading_normal.reshape(rows, columns, 3),
                       seen.reshape(rows, columns, 3), relative_threshold=settings.aa_threshold,
                       normal_angle=settings.aa_threshold, radiance_floor=floor)
    centre = (np.arange(1, rows, 3)[:, None] * columns + np.arange(1, columns, 3)[None, :]).reshape(-1)
    marked = centre[mask.reshape(-1)[centre]]
    return FrameScale(floor, neyman_share(edge_contrast(seen, shape, marked), settings.aa_samples))


def _material(scene: Scene, index_triangle: np.ndarray) -> np.ndarray:
    """Material of each hit triangle, -1 where nothing is hit (or the scene has no material table)."""
    if not len(scene.material_index):
        return np.full(len(index_triangle), -1)
    return np.where(index_triangle >= 0, scene.material_index[np.maximum(index_triangle, 0)], -1)


def _with_outside_ring(scene: Scene, grids, tracer, settings: Settings, window=None):
    """``refine_mask``'s (H, W) grids grown by one pixel on every side: triangle, material and shading
    normal seen by camera rays through the centres of the pixels around the window (outside the frame too),
    radiance copied from the nearest window pixel (unknown outside, so it marks nothing there). ``window``:
    the grids' full-frame pixel bounds (default the camera's window)."""
    index_triangle, material, normal, seen = grids
    x0, y0, x1, y1 = scene.camera.window if window is None else window
    ys, xs = np.mgrid[y0 - 1:y1 + 1, x0 - 1:x1 + 1]
    ring = np.ones(xs.shape, bool)
    ring[1:-1, 1:-1] = False
    origins, directions = camera_rays(scene.camera, xs[ring].astype(np.int64), ys[ring].astype(np.int64))
    own = tracer is None
    if own:
        tracer = RayTracer(scene.triangles, threads=settings.threads or None)
    try:
        hits = tracer.intersect(origins, directions, clip_distance(scene.camera, directions))
    finally:
        if own:
            tracer.close()
    outside = hits.index_triangle
    ring_normal = shade_hits(scene, origins, directions, outside, hits.u, hits.v, scene_extent(scene)).shading_normal

    def grown(inner, ring_values):
        out = np.pad(inner, [(1, 1), (1, 1)] + [(0, 0)] * (inner.ndim - 2), mode="edge")
        out[ring] = ring_values
        return out

    return (grown(index_triangle, outside), grown(material, _material(scene, outside)), grown(normal, ring_normal),
            np.pad(seen, [(1, 1), (1, 1), (0, 0)], mode="edge"))


def filter_rays(camera, pixels: np.ndarray, counts, first, settings: Settings, pixel_global: np.ndarray):
    """Camera rays of points ``first .. first + counts - 1`` of each pixel's filter sequence.

    Parameters
    ----------
    pixels : (P,) int64            window-local pixels.
    counts, first : int or (P,)    points per pixel and the index of each pixel's first point.

    Returns
    -------
    origins, directions : (N, 3) float64; position : (N, 2) float64 full-frame raster position (pixels, x
    right, y down; pixel (x, y) spans [x, x + 1) x [y, y + 1)); parent : (N,) int64 window-local pixel;
    sample : (N,) int64 index in its pixel's sequence. Pixel-major, N = sum of the counts.
    """
    counts = np.broadcast_to(np.asarray(counts, dtype=np.int64), (len(pixels),))
    first = np.broadcast_to(np.asarray(first, dtype=np.int64), (len(pixels),))
    parent = np.repeat(pixels, counts)
    xs, ys = pixel_coordinates(camera, parent)
    sample = np.repeat(first, counts) + np.arange(len(parent)) - np.repeat(np.cumsum(counts) - counts, counts)
    # Sobol points: strata of every shape at any power-of-two count, and a later batch continues them.
    u = rng.sobol_2d(settings.seed, settings.frame, rng.STREAM_FILM, pixel_global[parent], sample)
    offset = filter_offsets(u, settings.effective_filter_width, settings.filter_type)
    origins, directions = camera_rays(camera, xs, ys, offset)
    position = np.stack([xs, ys], axis=1) + offset
    return origins, directions, position, parent, sample


def subpixel_samples(scene: Scene, tracer, extent: float, pixels: np.ndarray, settings: Settings,
                     pixel_global: np.ndarray, samples=None, first=0):
    """Camera samples of the chosen pixels placed by the pixel filter.

    Parameters
    ----------
    pixels : (P,) int64          window-local pixels to supersample.
    samples : int or (P,) int64  samples per pixel (default ``settings.aa_samples``), stratified among
                                 themselves (each pixel's first 2^m samples form a net).
    first : int or (P,) int64    index of the first sample (a later batch of samples for the same pixels).

    Returns
    -------
    surface : SurfacePoints of the samples (pixel-major, N = sum of the counts); position : (N, 2) float64
    full-frame raster position of each sample (see ``filter_rays``); sample_global : (N,) int64
    random-number identities.
    """
    camera = scene.camera
    samples = settings.aa_samples if samples is None else samples
    origins, directions, position, parent, sample = filter_rays(camera, pixels, samples, first, settings,
                                                                pixel_global)
    hits = tracer.intersect(origins, directions, clip_distance(camera, directions))
    surface = shade_hits(scene, origins, directions, hits.index_triangle, hits.u, hits.v, extent)
    # Distinct from every real pixel's identity, and distinct per sample: samples do not share noise.
    sample_global = (1 + sample) * (camera.width * camera.height) + pixel_global[parent]
    return surface, position, sample_global


@dataclass(frozen=True)
class SurfaceStrata:
    """The surfaces coverage tells apart (``surface_strata``).

    Attributes
    ----------
    of_triangle : (T,) int64   the stratum of each triangle, numbered from 0.
    parent : (S,) int64        the connected surface (mesh part and material) each stratum is a smooth
                               piece of, numbered from 0.
    """

    of_triangle: np.ndarray
    parent: np.ndarray

    @property
    def count(self) -> int:
        return len(self.parent)


def surface_strata(scene: Scene) -> SurfaceStrata:
    """The strata of coverage: the smooth pieces of connected meshes told apart by material.

    Radiance jumps where one surface meets another (a post before the ground, a painted stripe), and
    where a surface creases: across a flat-shaded mesh's edges at an angle (a box's faces) or a smooth
    mesh's sharp edges the shading normal jumps, and so does the light it reflects. Within a piece it
    varies smoothly, up to shadow edges. So a piece is a set of triangles joined through corners that
    share both position and shading normal (``triangle_components`` with the corner normals; the face
    normal where the scene has no shading normals). A box as one stratum made its pixels' samples pay
    for the step between its faces: with its faces as strata ``bench_antialias.py --resolution 256
    --samples 16`` gives chairs.blend 0.990 % error against a 64-sample truth (1.229 % before) and
    floating_boxes 0.437 % with 102 k samples (0.674 % with 153 k).
    """
    triangles = scene.triangles
    if len(triangles) == 0:
        return SurfaceStrata(np.zeros(0, np.int64), np.zeros(0, np.int64))
    material = scene.material_index.astype(np.int64)
    materials = int(material.max()) + 1
    _, surface = np.unique(triangle_components(triangles) * materials + material, return_inverse=True)
    surface = surface.reshape(-1).astype(np.int64)
    if scene.shading_normals is not None:
        corner_normals = scene.shading_normals
    else:
        face = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
        face /= np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-300)
        corner_normals = np.repeat(face[:, None, :], 3, axis=1)
    piece = triangle_components(triangles, corner_normals)
    # A piece may span two materials (a face painted apart): a stratum is a piece within one surface.
    _, first, stratum = np.unique(piece * (int(surface.max()) + 1) + surface, return_index=True,
                                  return_inverse=True)
    return SurfaceStrata(stratum.reshape(-1).astype(np.int64), surface[first])


def stratum_of(triangle: np.ndarray, strata: SurfaceStrata) -> np.ndarray:
    """(N,) int64 stratum of the triangles (N,) seen (``surface_strata``), -1 where nothing is seen."""
    triangle = np.asarray(triangle, dtype=np.int64)
    if strata.count == 0:
        return np.full(len(triangle), -1, np.int64)
    return np.where(triangle >= 0, strata.of_triangle[np.maximum(triangle, 0)], -1)


# Points a surface needs under a pixel's filter before its plane is fitted (``plane_correction``), and coverage
# rays before its centroid is: three fix a plane, the rest measure how far the radiance departs from it.
PLANE_POINTS = 6


@dataclass
class Coverage:
    """Which surfaces each supersampled pixel's filter covers, and how much, from its coverage rays.

    Attributes
    ----------
    pixel : (C,) int64       index into the supersampled pixels; sorted by (pixel, stratum).
    stratum : (C,) int64     stratum (``surface_strata``), -1 for the background.
    fraction : (C,) float64  share of the pixel's coverage rays that see it (1 in sum per pixel).
    stride : int             ``key = pixel * stride + stratum + 1`` orders the entries.
    rays : int               coverage rays of all the pixels, their shaded samples included.
    albedo : (C, 3) float64 or None   mean albedo over the rays that see each textured surface (NaN on the
                                      others), where the scene has textures (``pool_samples``).
    parent : (S,) int64 or None       ``SurfaceStrata.parent``: the connected surface of each stratum, which
                                      stands in for a stratum known at too few points (None: none does).
    centroid : (C, 2) float64 or None mean full-frame raster position of the rays that see each entry's
                                      surface: the filter-weighted centroid of the surface's part of the
                                      filter, where ``pool_samples`` evaluates each surface's fitted plane
                                      (NaN where fewer than PLANE_POINTS rays see it).
    """

    pixel: np.ndarray
    stratum: np.ndarray
    fraction: np.ndarray
    stride: int
    rays: int = 0
    albedo: np.ndarray | None = None
    parent: np.ndarray | None = None
    centroid: np.ndarray | None = None

    @property
    def key(self) -> np.ndarray:
        return self.pixel * self.stride + self.stratum + 1

    def parent_key(self, pixel: np.ndarray, stratum: np.ndarray) -> np.ndarray:
        """(N,) int64 key of (pixel, the stratum's connected surface), ordered as ``key`` (a surface's number
        is below its strata's count, so the stride serves); the background (-1) is its own surface."""
        surface = np.where(stratum >= 0, self.parent[np.maximum(stratum, 0)], -1) if len(self.parent) else stratum
        return pixel * self.stride + surface + 1


# Coverage rays per shaded sample at least: a pixel's coverage comes from its own rays alone, while its
# surface means pool the neighbours' samples too, so coverage needs more rays than the pixel has samples
# (floating boxes at 96 px, 16 samples: relative RMSE 1.58 % with one ray per sample, 1.07 % with four,
# 1.25 % without coverage).
COVERAGE_RAYS_PER_SAMPLE = 4


def coverage_rays(counts: np.ndarray, settings: Settings) -> np.ndarray:
    """(P,) int64 coverage rays of pixels with ``counts`` (P,) shaded samples: ``aa_coverage_rays``, and at
    least COVERAGE_RAYS_PER_SAMPLE per sample."""
    return np.maximum(COVERAGE_RAYS_PER_SAMPLE * np.asarray(counts, np.int64), settings.aa_coverage_rays)


# Coverage rays traced per batch: bounds the ray arrays and the hits (about 300 bytes a ray at their peak:
# batches of a million took 295 MB on chairs.blend at 512 px, one per band in flight).
COVERAGE_BATCH = 1 << 18


def pixel_coverage(scene: Scene, tracer, pixels: np.ndarray, counts: np.ndarray, sample_stratum: np.ndarray,
                   strata: SurfaceStrata, settings: Settings, pixel_global: np.ndarray, rays: np.ndarray | None = None,
                   sample_albedo: np.ndarray | None = None, sample_position: np.ndarray | None = None) -> Coverage:
    """Coverage of each supersampled pixel from ``coverage_rays(counts)`` points of its filter sequence (or
    ``rays`` (P,) int64, at least ``counts``): its shaded samples are the first ``counts`` of them
    (``sample_stratum`` (N,) int64 says what they hit, pixel-major), the rest are camera rays that only
    find what they hit; with ``sample_albedo`` (N, 3) (the samples' albedo where they see a textured
    surface, NaN elsewhere) also the textured surfaces' mean albedo under the filter (``Coverage.albedo``:
    a texture lookup per ray, no shading).

    Parameters
    ----------
    pixels : (P,) int64; counts : (P,) int64 shaded samples of each; strata : ``surface_strata``.
    sample_position : (N, 2) float64 or None   the samples' raster positions (``filter_rays``), where the
    caller has them (for ``Coverage.centroid``; worked out again otherwise).
    """
    counts = np.asarray(counts, dtype=np.int64)
    rays = coverage_rays(counts, settings) if rays is None else np.maximum(np.asarray(rays, np.int64), counts)
    extra = rays - counts
    first_sample = np.concatenate([[0], np.cumsum(counts)])
    stride = strata.count + 1
    # Pixel ranges of about COVERAGE_BATCH extra rays each.
    cuts = np.searchsorted(np.cumsum(extra), np.arange(COVERAGE_BATCH, int(extra.sum()), COVERAGE_BATCH))
    bounds = np.unique(np.concatenate([[0], cuts, [len(pixels)]]))
    textured = None if sample_albedo is None else albedo_scaled_materials(scene)[scene.material_index]
    keys, hits, albedo_sums, position_sums = [], [], [], []
    for lo, hi in zip(bounds[:-1], bounds[1:]):  # batches of pixels, a million rays each
        origins, directions, extra_position, _, _ = filter_rays(scene.camera, pixels[lo:hi], extra[lo:hi],
                                                                counts[lo:hi], settings, pixel_global)
        own_position = filter_rays(scene.camera, pixels[lo:hi], counts[lo:hi], 0, settings, pixel_global)[2] \
            if sample_position is None else sample_position[first_sample[lo]:first_sample[hi]]
        found = tracer.intersect(origins, directions, clip_distance(scene.camera, directions)) if len(origins) \
            else None
        triangle = found.index_triangle if found is not None else np.zeros(0, np.int64)
        batch = np.arange(lo, hi)
        owner = np.concatenate([np.repeat(batch, counts[lo:hi]), np.repeat(batch, extra[lo:hi])])
        stratum = np.concatenate([sample_stratum[first_sample[lo]:first_sample[hi]], stratum_of(triangle, strata)])
        key, inverse, hit = _grouped(owner, stratum, lo, hi - lo, stride)
        keys.append(key)
        hits.append(hit)
        ray_position = np.concatenate([own_position, extra_position])
        position_sums.append(np.stack([np.bincount(inverse, weights=ray_position[:, axis], minlength=len(key))
                                       for axis in range(2)], axis=1))
        if textured is not None:
            # Albedo of the rays on textured triangles (NaN elsewhere, and so the sums of other surfaces: a
            # surface is one material): the samples' is known, the others' looked up.
            offset = first_sample[hi] - first_sample[lo]
            ray_albedo = np.full((len(owner), 3), np.nan)
            ray_albedo[:offset] = sample_albedo[first_sample[lo]:first_sample[hi]]
            on = np.flatnonzero(triangle >= 0)
            on = on[textured[triangle[on]]]
            ray_albedo[offset + on] = surface_albedo(scene, triangle[on], found.u[on], found.v[on])
            albedo_sums.append(np.stack([np.bincount(inverse, weights=ray_albedo[:, channel],
                                                     minlength=len(key)) for channel in range(3)], axis=1))
    key, hit = np.concatenate(keys), np.concatenate(hits)
    pixel = key // stride
    albedo = np.concatenate(albedo_sums) / hit[:, None] if textured is not None else None
    # A centroid from a ray or two is no better known than the samples' own mean: none (NaN) there.
    centroid = np.where((hit >= PLANE_POINTS)[:, None], np.concatenate(position_sums) / hit[:, None], np.nan)
    return Coverage(pixel, key % stride - 1, hit / rays[pixel], stride, int(rays.sum()), albedo, strata.parent,
                    centroid)


def _grouped(owner: np.ndarray, stratum: np.ndarray, first: int, pixels: int, stride: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(owner * stride + stratum + 1, return_inverse=True, return_counts=True)`` for a batch of
    coverage rays: ``owner`` (N,) int64 in first .. first + pixels - 1, ``stratum`` (N,) int64 in -1 .. stride
    - 2. By counting over (pixel, surface present in the batch) where that range is at most a few times the
    rays, by np.unique's sort otherwise: a scene's surfaces are many (chairs.blend: 11 k, so the keys' range
    was 100 times the rays) but a batch sees few, and the sort of chairs.blend's 7 million coverage rays at
    512 px took 0.73 s of a 13 s render on one thread. The same arrays either way."""
    present = np.bincount(stratum + 1, minlength=stride) > 0
    local_stride = int(present.sum())
    if pixels * local_stride > 4 * len(owner) + 4096:
        key, inverse, hit = np.unique(owner * stride + stratum + 1, return_inverse=True, return_counts=True)
        return key, inverse.reshape(-1), hit
    local = np.cumsum(present) - 1  # a surface's rank among those present: order kept
    counts = np.bincount((owner - first) * local_stride + local[stratum + 1], minlength=pixels * local_stride)
    found = np.flatnonzero(counts)
    rank = np.zeros(len(counts), np.int64)
    rank[found] = np.arange(len(found))
    key = (found // local_stride + first) * stride + np.flatnonzero(present)[found % local_stride]
    return key, rank[(owner - first) * local_stride + local[stratum + 1]], counts[found]


# Shaded samples an edge pixel draws before the rest of its allocation (with coverage rays its centre is
# one more): enough to tell whether anything varies under the pixel's filter at all.
PILOT_SAMPLES = 3


def settled_pixels(pilot_rgba: np.ndarray, pilot_counts: np.ndarray, centre_rgba: np.ndarray,
                   one_surface: np.ndarray, tolerance: np.ndarray) -> np.ndarray:
    """Which edge pixels need no samples beyond their pilot: (P,) bool.

    The neighbour test (``refine_pixels``) looks at radiance one pixel apart, but the pixel's value only
    depends on what lies under its filter. A pixel is settled when its filter covers one surface
    (``one_surface``: the coverage rays, the pilot samples and the centre all see the same one) and every
    pilot sample's RGBA is within ``tolerance`` of the centre's: then each of its samples, and so its
    filtered value, is within ``tolerance`` of the centre's, whatever more samples would add. Under a
    narrow filter (the sample .blends' 0.01 px) nearly every pixel settles; under Cycles' 1.5 px, those
    on a smooth stretch of one surface do.

    Parameters
    ----------
    pilot_rgba : (N, 4) float64     the pilot samples, pixel-major (``pilot_counts`` (P,) int64 each, >= 1).
    centre_rgba : (P, 4) float64    each pixel's centre sample (pass 1).
    one_surface : (P,) bool
    tolerance : (P,) float64        largest deviation allowed, in the RGBA's units.
    """
    pilot_counts = np.asarray(pilot_counts, dtype=np.int64)
    owner = np.repeat(np.arange(len(pilot_counts)), pilot_counts)
    deviation = np.zeros(len(pilot_counts))
    if len(owner):
        np.maximum.at(deviation, owner, np.abs(pilot_rgba - centre_rgba[owner]).max(axis=1))
    return one_surface & (pilot_counts > 0) & (deviation <= tolerance)


# Samples per unit of a pixel's spread (``surface_spread``) against per unit of its contrast: the spread of
# three pilot samples and a centre underestimates the surfaces' variation, the more so on small surfaces.
# Measured on 512 px bands against 64-sample references (the contrast allocation's error there, at its
# samples): 4 gives floating_boxes 0.548 / 0.578 % (0.545 / 0.577) with 57 % of the samples, the tree 0.761 /
# 0.818 % (0.752 / 0.807) with 70 %, the chairs 0.882 / 0.938 % (0.861 / 0.917) with 83 %; 2 saved more
# (52-73 %) at up to 5 % more error.
SPREAD_WEIGHT = 4.0


def surface_spread(pixels: np.ndarray, shape: tuple[int, int], reach: float, coverage: Coverage,
                   pilot_rgba: np.ndarray, pilot_stratum: np.ndarray, pilot_counts: np.ndarray,
                   centre_rgba: Callable[[np.ndarray], np.ndarray], centre_stratum: Callable[[np.ndarray], np.ndarray],
                   contrast: np.ndarray, pilot_texture: np.ndarray | None = None,
                   centre_texture: Callable[[np.ndarray], np.ndarray] | None = None,
                   pilot_offset: np.ndarray | None = None) -> np.ndarray:
    """How much the radiance varies within the surfaces under each pixel's filter: (P,) float64, W m^-2
    sr^-1, SPREAD_WEIGHT times the root of the sum over the surfaces its coverage rays see of their share
    times their span squared (largest channel's max - min over the points known on them there: its pilot
    samples and the pass-1 centres of the pixels within the filter's reach, its own among them). A surface
    known at fewer than two points counts with the pixel's ``contrast``.

    Why: the contrast that first allocates a pixel's samples (``allocate_samples``) is its step to a
    neighbour, the jump between two surfaces at an object's outline included; but with coverage rays that
    jump costs no shaded samples (``pool_samples``): what the shaded samples estimate is each surface's
    mean, and a surface i covering f_i of the filter with deviation s_i, sampled in proportion, leaves a
    variance of sum_i f_i s_i^2 / S after S samples. The spread stands for sqrt(sum_i f_i s_i^2), the
    deviation the Neyman allocation weighs. With ``pilot_offset`` the span is that of the points'
    departures from the plane fitted to them (``_span_at``): ``pool_samples``' regression estimate leaves
    only those to the samples.

    Parameters
    ----------
    pixels : (P,) int64 window-local; shape : (H, W) the window; reach : the filter's radius, pixels.
    coverage : the pilot's ``pixel_coverage`` of ``pixels``.
    pilot_rgba : (N, 4) float64, pilot_stratum : (N,) int64   the pilot samples, pixel-major,
    pilot_counts : (P,) int64 of them each.
    centre_rgba, centre_stratum : window-local pixels (M,) -> their centres' RGBA (M, 4) float64 and
    surface (M,) int64 (``stratum_of``).
    pilot_offset : (N, 2) float64 or None   the pilot samples' raster offsets from their pixel's centre.
    contrast : (P,) float64 (``edge_contrast``).
    pilot_texture, centre_texture : with the coverage's albedo, the pilot samples' texture parts (N, 6)
    (reflected radiance and albedo, NaN off textures: ``supersampling._texture_part``) and the centres'. On a
    textured surface a point's reflected radiance counts divided by its albedo, times the coverage rays'
    mean albedo there: the texture's pattern is the coverage's to resolve (``pool_samples``), only the
    light's variation is left to the samples.
    """
    height, width = shape
    count = len(pixels)
    row, column = np.divmod(np.asarray(pixels, np.int64), width)
    grow = int(np.floor(reach))
    owners, neighbours, offsets = [], [], []
    for dy in range(-grow, grow + 1):  # the centres under the filter: (2 grow + 1)^2 shifts, a handful
        for dx in range(-grow, grow + 1):
            inside = np.flatnonzero((row + dy >= 0) & (row + dy < height) & (column + dx >= 0) & (column + dx < width))
            owners.append(inside)
            neighbours.append((row[inside] + dy) * width + column[inside] + dx)
            offsets.append(np.broadcast_to(np.array([dx, dy], np.float64), (len(inside), 2)))
    lattice = np.concatenate(neighbours)
    owner = np.concatenate(owners + [np.repeat(np.arange(count), pilot_counts)])
    offset = None if pilot_offset is None else np.concatenate(offsets + [pilot_offset])
    # Points grouped by (pixel, surface), keyed as the coverage is.
    key = owner * coverage.stride + np.concatenate([centre_stratum(lattice), pilot_stratum]) + 1
    rgba = np.concatenate([centre_rgba(lattice), pilot_rgba])
    if coverage.albedo is not None and pilot_texture is not None and pilot_texture.shape[1] and len(key):
        part = np.concatenate([centre_texture(lattice), pilot_texture])
        reflected, albedo = part[:, :3], part[:, 3:]
        entry = np.minimum(np.searchsorted(coverage.key, key), max(len(coverage.key) - 1, 0))
        covered = np.where((coverage.key[entry] == key)[:, None], coverage.albedo[entry], np.nan) \
            if len(coverage.key) else np.full_like(albedo, np.nan)
        light = np.isfinite(albedo) & np.isfinite(covered) & (albedo > 0.0)
        rgba[:, :3] += np.where(light, reflected / np.where(light, albedo, 1.0) * covered - reflected, 0.0)
        if offset is not None:  # pool_samples fits no plane on a texture (its pattern is none): nor here
            offset = np.where(np.isfinite(albedo).any(axis=1)[:, None], 0.0, offset)
    if len(key) == 0:
        return np.zeros(count)
    # A stratum known at fewer than two points counts with its connected surface's span there (a box's
    # thin side face in the pixel: the box's faces around it), and where that too is unknown with the
    # pixel's contrast.
    unknown = contrast[coverage.pixel]
    if coverage.parent is not None:
        stride = coverage.stride
        unknown = _span_at(coverage.parent_key(key // stride, key % stride - 1), rgba,
                           coverage.parent_key(coverage.pixel, coverage.stratum), unknown, offset)
    entry_span = _span_at(key, rgba, coverage.key, unknown, offset)
    return SPREAD_WEIGHT * np.sqrt(np.bincount(coverage.pixel, weights=coverage.fraction * entry_span ** 2,
                                               minlength=count))


def _span_at(key: np.ndarray, rgba: np.ndarray, wanted: np.ndarray, unknown: np.ndarray,
             offset: np.ndarray | None = None) -> np.ndarray:
    """(W,) float64 span (largest channel's max - min) of the points ``rgba`` (N, 4) with each ``wanted``
    (W,) int64 of their ``key`` (N,) int64, ``unknown`` (W,) where fewer than two points have it. With
    ``offset`` (N, 2) float64 (the points' raster offsets from their pixel's centre) the span of their
    departures from the plane fitted to each key's points (``plane_slopes``; the plain span where it is not
    fitted): what ``pool_samples``' regression estimate leaves to the samples."""
    order = np.argsort(key, kind="stable")
    key, rgba = key[order], rgba[order]
    first = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))
    known = key[first]
    points = np.diff(np.append(first, len(key)))
    if offset is not None and len(key):
        # The plane of each key's points, fitted as pool_samples fits it (unit weights here), and their
        # departures from it.
        offset = np.ascontiguousarray(offset[order], np.float64)
        group = np.repeat(np.arange(len(first)), points)
        moments = np.zeros((len(first), 14))
        _add_moments(group, np.ones(len(key)), offset, np.ascontiguousarray(rgba, np.float64), moments)
        slope_x, slope_y, x_mean, _ = plane_slopes(moments[:, 0], np.add.reduceat(rgba, first, axis=0)
                                                   / points[:, None], moments)
        span = np.empty(len(first))
        _residual_spans(np.append(first, len(key)), offset, np.ascontiguousarray(rgba, np.float64), slope_x, slope_y,
                        x_mean, span)
    else:
        span = (np.maximum.reduceat(rgba, first, axis=0) - np.minimum.reduceat(rgba, first, axis=0)).max(axis=1)
    slot = np.minimum(np.searchsorted(known, wanted), len(known) - 1)
    measured = (known[slot] == wanted) & (points[slot] >= 2)
    return np.where(measured, span[slot], unknown)


@njit(cache=True, nogil=True)
def _add_moments(slot, weight, offset, rgba, moments):
    """Adds each point's terms to its entry's ``plane_slopes`` moments (C, 14): the point, the weighted
    offset (dx, dy), its products and its products with RGBA (``slot`` (N,) int64 entries, ``weight`` (N,),
    ``offset`` (N, 2), ``rgba`` (N, 4) float64). Compiled: one pass over the points instead of 14 weighted
    bincounts and their temporaries."""
    slot, weight, offset, rgba, moments = borrowed(slot), borrowed(weight), borrowed(offset), borrowed(rgba), \
        borrowed(moments)
    for i in range(len(slot)):
        _add_point_moments(moments, slot[i], weight[i], offset[i, 0], offset[i, 1], rgba, i)


@njit(cache=True, nogil=True, inline="always")
def _add_point_moments(moments, e, w, dx, dy, rgba, i):
    """Adds point i's terms (weight ``w``, offset (dx, dy), RGBA ``rgba[i]``) to entry e's moments."""
    moments[e, 0] += 1.0
    moments[e, 1] += w * dx
    moments[e, 2] += w * dy
    moments[e, 3] += w * dx * dx
    moments[e, 4] += w * dx * dy
    moments[e, 5] += w * dy * dy
    for c in range(4):
        moments[e, 6 + c] += w * dx * rgba[i, c]
        moments[e, 10 + c] += w * dy * rgba[i, c]


@njit(cache=True, nogil=True)
def _residual_spans(bounds, offset, rgba, slope_x, slope_y, x_mean, out):
    """Per group g of points ``bounds[g] .. bounds[g + 1] - 1`` (offsets (N, 2), RGBA (N, 4)) and its plane
    (slopes (G, 4), mean offset (G, 2): ``plane_slopes``): the largest channel's span of the points'
    departures from the plane, into ``out`` (G,). Compiled: as numpy gathers of (N, 4) it took twice
    ``_span_at``'s other work."""
    bounds, offset, rgba, out = borrowed(bounds), borrowed(offset), borrowed(rgba), borrowed(out)
    slope_x, slope_y, x_mean = borrowed(slope_x), borrowed(slope_y), borrowed(x_mean)
    for g in range(len(bounds) - 1):  # groups, each over its points
        widest = 0.0
        for c in range(4):
            low, high = np.inf, -np.inf
            for i in range(bounds[g], bounds[g + 1]):
                value = rgba[i, c] - slope_x[g, c] * (offset[i, 0] - x_mean[g, 0]) \
                    - slope_y[g, c] * (offset[i, 1] - x_mean[g, 1])
                low, high = min(low, value), max(high, value)
            widest = max(widest, high - low)
        out[g] = widest


@njit(cache=True, nogil=True)
def _filter_density(knots, t):
    """``film.offset_density`` of one coordinate ``t`` from the table's ``knots`` (its first size - 1
    entries): the same arithmetic, one value."""
    size = len(knots) + 1
    mass = 1.0 / (size - 1)
    interval = np.searchsorted(knots, t, side="right") - 1
    density = 0.0
    if interval >= 0 and interval < size - 2:
        span = knots[interval + 1] - knots[interval]
        if span > 0.0:
            density = mass / span
    stray_end = knots[size - 2]  # the last interval reads from this entry towards the stray 0
    if t >= 0.0 and t <= stray_end:
        density += mass / stray_end
    return density


@njit(cache=True, nogil=True)
def _pool_sums(position, owner, rgba, index, drawn, window, steps, knots, lattice_density, stratum, coverage_key,
               stride, scaled_part, pixel_centre, totals, surface_totals, moments):
    """``pool_samples``' sums over its N samples, in place: per pooled pixel (``totals`` (P, 5): the weighted
    RGBA and the weights), and with a coverage (``coverage_key`` (E,) sorted, non-empty ``stratum`` (N,)) per
    (pixel, surface) entry (``surface_totals`` (E, 5 or 11): also the albedo-scaled radiance and albedo of
    ``scaled_part`` (N, 6) where that is given) and the plane's ``moments`` (E, 14, or (E, 0): none).

    ``index`` (H * W,) int64: the pooled row of each window-local pixel, -1 for none; ``drawn`` (P + 1,)
    float64 the samples each pixel drew (the last entry 0); ``window`` (4,) int64; ``steps`` (J,) the
    candidate offsets from a sample's cell; ``knots`` the filter table's (``_filter_density``). Compiled:
    one pass over the samples, each over its J x J candidate pixels and the few entries of each, instead
    of batches of (B, J, J) arrays, their masks, a binary search of every pair's key and two dozen
    bincounts (``pool_samples`` on the chairs at 512 px, one thread: 0.86 -> 0.30 s, without the GIL);
    the sums are those of the samples in order, whatever batches a caller would cut."""
    position, owner, rgba, index, drawn = borrowed(position), borrowed(owner), borrowed(rgba), borrowed(index), \
        borrowed(drawn)
    steps, knots, stratum, coverage_key = borrowed(steps), borrowed(knots), borrowed(stratum), borrowed(coverage_key)
    scaled_part, pixel_centre, totals = borrowed(scaled_part), borrowed(pixel_centre), borrowed(totals)
    surface_totals, moments = borrowed(surface_totals), borrowed(moments)
    x0, y0, x1, y1 = window[0], window[1], window[2], window[3]
    width = x1 - x0
    count = len(steps)
    entries = len(coverage_key)
    # Each pooled pixel's entries: a run of the sorted keys (pixel * stride + surface + 1).
    entry_first = np.searchsorted(coverage_key, np.arange(len(totals) + 1) * stride)
    covered = len(stratum) > 0
    textured = len(scaled_part) > 0
    fitted = moments.shape[1] > 0
    density = np.zeros(count * count)
    target = np.zeros(count * count, np.int64)
    density_x = np.zeros(count)
    for s in range(len(position)):
        px, py = position[s, 0], position[s, 1]
        cx, cy = np.int64(np.floor(px)), np.int64(np.floor(py))
        for j in range(count):
            qx = cx + steps[j]
            density_x[j] = _filter_density(knots, px - qx) if qx >= x0 and qx < x1 else 0.0
        mixture = 0.0
        for jy in range(count):
            qy = cy + steps[jy]
            density_y = _filter_density(knots, 1.0 - (py - qy)) if qy >= y0 and qy < y1 else 0.0
            row = (min(max(qy, y0), y1 - 1) - y0) * width
            for jx in range(count):
                k = jy * count + jx
                q = index[row + min(max(cx + steps[jx], x0), x1 - 1) - x0]
                target[k] = q
                density[k] = density_y * density_x[jx] if q >= 0 else 0.0
                if q >= 0:
                    mixture += drawn[q] * density[k]
        mixture += lattice_density
        lonely = False
        if mixture <= 0.0:  # a sample lies where its own pixel's density is positive: rounding only
            for k in range(count * count):
                density[k] = 0.0
            mixture = 1.0
            lonely = owner[s] >= 0
        for k in range(count * count + 1):
            if k < count * count:
                weight = density[k] / mixture
                if not weight > 0.0:
                    continue
                pixel = target[k]
            else:  # unreachable in exact arithmetic: such a sample counts for its own pixel alone
                if not lonely:
                    continue
                weight = 1.0
                pixel = owner[s]
            for c in range(4):
                totals[pixel, c] += weight * rgba[s, c]
            totals[pixel, 4] += weight
            if not covered or entries == 0:
                continue
            key = pixel * stride + stratum[s] + 1
            slot = entry_first[pixel]
            while slot < entry_first[pixel + 1] and coverage_key[slot] != key:  # the pixel's few surfaces
                slot += 1
            if slot == entry_first[pixel + 1]:  # a surface the pixel's coverage rays missed: no share there
                continue
            for c in range(4):
                surface_totals[slot, c] += weight * rgba[s, c]
            surface_totals[slot, 4] += weight
            if textured:
                for c in range(6):
                    surface_totals[slot, 5 + c] += weight * scaled_part[s, c]
            if fitted:
                _add_point_moments(moments, slot, weight, px - pixel_centre[pixel, 0], py - pixel_centre[pixel, 1],
                                   rgba, s)


def compile_antialias() -> tuple:
    """Compile anti-aliasing's kernels (or load them from Numba's cache); returns them."""
    _add_moments(np.zeros(1, np.int64), np.ones(1), np.zeros((1, 2)), np.zeros((1, 4)), np.zeros((1, 14)))
    _residual_spans(np.array([0, 1]), np.zeros((1, 2)), np.zeros((1, 4)), np.zeros((1, 4)), np.zeros((1, 4)),
                    np.zeros((1, 2)), np.empty(1))
    table = np.linspace(0.0, 1.0, 8)
    _pool_sums(np.full((1, 2), 0.5), np.zeros(1, np.int64), np.zeros((1, 4)), np.zeros(1, np.int64), np.ones(2),
               np.array([0, 0, 1, 1], np.int64), np.arange(-2, 2, dtype=np.int64), table, 0.0, np.zeros(1, np.int64),
               np.zeros(1, np.int64), 1, np.zeros((1, 6)), np.full((1, 2), 0.5), np.zeros((1, 5)), np.zeros((1, 11)),
               np.zeros((1, 14)))
    return (_add_moments, _residual_spans, _pool_sums, _filter_density)


def narrow_filter(settings: Settings) -> bool:
    """Whether the pixel filter is so narrow that a pixel seeing one triangle under all of it has its
    centre's value: its reach r (pixels) at most sqrt(aa_settle_tolerance) / 2.

    Radiance on one triangle under area lights is smooth (the visible part of each light moves
    continuously with the point), and its mean over a symmetric filter differs from the centre value
    only by the second-order term: the filter's variance (below r^2) times half the radiance's
    Laplacian, so of order r^2 times the pixel's scale where the radiance bends by its scale over a
    pixel, within ``aa_settle_tolerance`` of it. The sample .blends' 0.01 px filter (Cycles' point
    sample) qualifies; Blender's default 1.5 px does not. Left out: a kink of a penumbra passing within
    r of the centre (an error of about r times the step to a neighbour, on the few pixels so placed),
    and textures, which have edges within a triangle (their pixels keep the pilot).
    """
    return settings.filter_reach <= 0.5 * np.sqrt(settings.aa_settle_tolerance)


def centre_suffices(scene: Scene, tracer, pixels: np.ndarray, centre_triangle: np.ndarray, settings: Settings,
                    pixel_global: np.ndarray) -> np.ndarray:
    """(P,) bool: which edge pixels need no shaded samples under a ``narrow_filter``: every one of their
    ``aa_coverage_rays`` (at least COVERAGE_RAYS_PER_SAMPLE) camera rays through the filter's points
    sees the triangle the centre sees, and its material has no texture. Camera rays only, no shading:
    where the neighbours differ because an edge passes between the centres, not under the filter, the
    pixel keeps its centre (on the tree at 128 px, 88% of its edge pixels)."""
    out = np.zeros(len(pixels), bool)
    if not narrow_filter(settings) or len(pixels) == 0:
        return out
    rays = max(settings.aa_coverage_rays, COVERAGE_RAYS_PER_SAMPLE)
    material = _material(scene, centre_triangle)
    textured = np.zeros(len(pixels), bool)
    if scene.materials.texture_index is not None and len(scene.material_index):
        textured = (material >= 0) & (scene.materials.texture_index[np.maximum(material, 0)] >= 0)
    # Only these can keep their centre: no rays for the others (a textured frame's edge pixels are mostly
    # texture edges).
    candidates = np.flatnonzero((centre_triangle >= 0) & ~textured)
    threads = thread_count(settings.threads)
    step = max(1, COVERAGE_BATCH // rays // threads)  # the batches in flight: a million rays in all

    def test(lo: int) -> None:
        rows = candidates[lo:lo + step]
        origins, directions, _, _, _ = filter_rays(scene.camera, pixels[rows], rays, 0, settings, pixel_global)
        seen = tracer.intersect(origins, directions, clip_distance(scene.camera, directions)).index_triangle \
            .reshape(-1, rays)
        out[rows] = (seen == centre_triangle[rows, None]).all(axis=1)
    map_batches(test, range(0, len(candidates), step), threads)  # batches of pixels on the thread pool
    return out


def covers_one_surface(coverage: Coverage, centre_stratum: np.ndarray) -> np.ndarray:
    """(P,) bool: the pixel's coverage rays (its shaded samples among them) all see its centre's surface."""
    entries = np.bincount(coverage.pixel, minlength=len(centre_stratum))
    first = np.searchsorted(coverage.pixel, np.arange(len(centre_stratum)))
    only = coverage.stratum[np.minimum(first, max(len(coverage.stratum) - 1, 0))] if len(coverage.stratum) else \
        np.full(len(centre_stratum), -2)
    return (entries == 1) & (only == centre_stratum)


def landing_pixels(position: np.ndarray) -> np.ndarray:
    """(S, 2) int64 full-frame (x, y) of the pixel each raster position (S, 2) lies in."""
    return np.floor(position).astype(np.int64)


def foreign_samples(sub, landing: np.ndarray, grid_surface, grid: tuple[int, int, int, int]) -> np.ndarray:
    """Which samples see another surface than the centre of the pixel they land in.

    A pixel's blocker list is made for the surface seen at its centre (the extended fill makes it hold
    across the pixel on that surface), not for a slat's face or a nearer object seen between two centres.

    Parameters
    ----------
    sub : SurfacePoints of the S samples; landing : (S, 2) full-frame (x, y) of the pixel each lands in.
    grid_surface : SurfacePoints of pass 1's pixels over ``grid`` = (x0, y0, x1, y1) (row-major).

    Returns
    -------
    (S,) bool: the sample hits something and its landing pixel's centre sees nothing, or a plane with
    another geometric normal (more than 2.6 degrees), or the sample lies off that plane (a parallel step).
    """
    x0, y0, x1, y1 = grid
    cell = (np.clip(landing[:, 1], y0, y1 - 1) - y0) * (x1 - x0) + np.clip(landing[:, 0], x0, x1 - 1) - x0
    normal = grid_surface.geometric_normal[cell]
    step = sub.position - grid_surface.position[cell]
    other_normal = np.einsum("nk,nk->n", normal, sub.geometric_normal) < 0.999
    off_plane = np.abs(np.einsum("nk,nk->n", normal, step)) > 1e-3 * np.linalg.norm(step, axis=1)
    return sub.hit & (~grid_surface.hit[cell] | other_normal | off_plane)


def inherit_blockers(blockers: BlockerMap, grid: tuple[int, int, int, int], landing: np.ndarray,
                     n_lights: int) -> BlockerMap:
    """A blocker map for samples: each sample gets the list of the pixel it lands in.

    Parameters
    ----------
    blockers : the map over ``grid`` = (x0, y0, x1, y1) of the full frame (row-major pixels).
    landing : (S, 2) full-frame (x, y); samples landing off the grid take the nearest grid pixel's list.
    """
    x0, y0, x1, y1 = grid
    gx = np.clip(landing[:, 0], x0, x1 - 1) - x0
    gy = np.clip(landing[:, 1], y0, y1 - 1) - y0
    cell = gy * (x1 - x0) + gx
    start = np.searchsorted(blockers.pixel, cell, side="left")
    stop = np.searchsorted(blockers.pixel, cell, side="right")
    count = stop - start
    owner = np.repeat(np.arange(len(cell)), count)
    entry = np.repeat(start, count) + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count))
    # The umbra flag was decided at the pixel's centre only: sub-pixel points are clipped in full.
    return BlockerMap(owner, blockers.light[entry], blockers.blocker[entry],
                      np.zeros((len(cell), n_lights), bool))


def cull_to_samples(blockers: BlockerMap, sub, frames, polygons, settings: Settings, progress) -> BlockerMap:
    """The inherited lists cut down to the pairs that overlap at each sample, with umbra per sample (pairs
    of closed convex parts are kept as they are).

    A pixel's list holds every pair needed anywhere in the pixel; at one sample most of them miss the light
    (Suzanne at 96 px: 17 pairs per sample inherited). The flood fill's cone test, conservative, drops
    those before pass 2 clips by them, and a blocker that alone hides a light from the sample (umbra, when
    umbra detection is on) skips that light there.
    """
    # A pair of a closed convex part stays untested even where its own face misses the light: pass 2 clips
    # by the part's whole silhouette, which covers the part's faces the pixel's list lacks (faces seen
    # nearly edge-on overlap a light only between pixel centres, where no fill reaches them), and drops a
    # silhouette that misses the light, or hides it, at its first test.
    parts = polygons.parts
    in_part = parts.of_blocker[blockers.blocker] >= 0 if parts is not None else np.zeros(len(blockers.pixel), bool)
    tested = np.flatnonzero(~in_part)
    progress.begin_stage("Sample blockers", len(tested))
    overlap, umbra = test_pairs(sub, frames, polygons, blockers.pixel[tested], blockers.blocker[tested],
                                blockers.light[tested], thread_count(settings.threads), progress)
    progress.end_stage()
    hidden = np.zeros_like(blockers.umbra)
    if settings.umbra_detection:
        hidden[blockers.pixel[tested[umbra]], blockers.light[tested[umbra]]] = True
    keep = in_part.copy()
    keep[tested[overlap]] = True
    keep &= ~hidden[blockers.pixel, blockers.light]
    return BlockerMap(blockers.pixel[keep], blockers.light[keep], blockers.blocker[keep], blockers.umbra | hidden)


def sample_rgba(sample_radiance: np.ndarray, surface, scene: Scene, settings: Settings) -> np.ndarray:
    """RGBA (N, 4) of N camera samples: shaded radiance where a surface is hit, the background (or
    transparent) elsewhere."""
    return rgba_of(sample_radiance, surface.hit, surface.emission, scene, settings)


def rgba_of(radiance: np.ndarray, hit: np.ndarray, emission: np.ndarray | None, scene: Scene, settings: Settings
            ) -> np.ndarray:
    """RGBA (N, 4) of N camera rays from the reflected ``radiance`` (N, 3) where they ``hit`` (N,) bool a
    surface, plus its ``emission`` (N, 3) (None: none), and the background (or transparent) elsewhere."""
    rgba = np.zeros((len(radiance), 4))
    rgba[hit, :3] = radiance[hit]
    if emission is not None:
        rgba[hit, :3] += emission[hit]
    rgba[hit, 3] = 1.0
    if not settings.transparent_background:
        rgba[~hit, :3] = scene.background
        rgba[~hit, 3] = 1.0
    return rgba


def lattice_pixels(pixels: np.ndarray, shape: tuple[int, int], reach: float) -> np.ndarray:
    """Window-local pixels (ascending) whose centres lie under the filter of any of ``pixels``: the
    supersampled pixels grown by the filter's reach (a pixel's footprint at radius 1.5 holds the centres
    of its 8 neighbours)."""
    height, width = shape
    grow = int(np.floor(reach))
    mask = np.zeros((height + 2 * grow, width + 2 * grow), bool)
    row, column = np.divmod(np.asarray(pixels, np.int64), width)
    for dy in range(-grow, grow + 1):  # shifts of the filter's reach: a handful
        for dx in range(-grow, grow + 1):
            mask[row + grow + dy, column + grow + dx] = True
    return np.flatnonzero(mask[grow:grow + height, grow:grow + width])


def plane_correction(weight: np.ndarray, mean: np.ndarray, moments: np.ndarray, centroid: np.ndarray
                     ) -> np.ndarray:
    """What a surface's weighted mean of samples gains as a regression estimate: (C, 4) float64 RGBA.

    Within one surface under a pixel's filter the radiance is smooth away from shadow edges: close to a
    plane in raster position. The filtered value of a plane over the surface's part of the filter is the
    plane at that part's filter-weighted centroid (``Coverage.centroid``, known from the cheap coverage
    rays), so the regression estimate ``mean + b (centroid - x_mean)``, with ``b`` the weighted
    least-squares slope of the samples' RGBA in their offsets ``x``, is exact for a plane and leaves only
    the residuals from it to the samples' noise (a penumbra crossing the filter costs far fewer samples).
    It is consistent, as the mean is: ``x_mean`` tends to the centroid. Where a surface has fewer than
    PLANE_POINTS points or their offsets do not span two directions the correction is 0.

    Parameters
    ----------
    weight : (C,) float64       sum of the points' weights per entry (0: no point).
    mean : (C, 4) float64       their weighted mean RGBA.
    moments : (C, 14) float64   points; weighted sums of dx, dy, dx^2, dx dy, dy^2; of dx RGBA (4), dy RGBA (4)
                                (offsets from the pixel's centre, pixels).
    centroid : (C, 2) float64   the surface's centroid under the filter, offset from the pixel's centre (NaN:
                                unknown, no correction).
    """
    slope_x, slope_y, x_mean, (cxx, cxy, cyy) = plane_slopes(weight, mean, moments)
    step = np.nan_to_num(centroid - x_mean)  # no centroid (NaN): no correction
    # The plane is taken no further from the points' mean than one standard deviation of their offsets
    # (Mahalanobis distance 1): there the correction is at most the points' own deviation, and a curved
    # stretch of light (a bright spot's flank) is not extrapolated into a negative value.
    determinant = np.maximum(cxx * cyy - cxy * cxy, 1e-300)
    distance2 = (cyy * step[:, 0] ** 2 - 2 * cxy * step[:, 0] * step[:, 1] + cxx * step[:, 1] ** 2) / determinant
    step = step / np.sqrt(np.maximum(distance2, 1.0))[:, None]
    return slope_x * step[:, 0, None] + slope_y * step[:, 1, None]


def plane_slopes(weight: np.ndarray, mean: np.ndarray, moments: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted least-squares slopes of RGBA in raster offset per entry (``plane_correction``'s arguments):
    d RGBA / dx and / dy, (C, 4) float64 each (0 where the plane is not fitted), and the weighted mean
    offset (C, 2) float64 and the weighted covariance of the offsets (xx, xy, yy: three (C,) float64)."""
    total = np.where(weight > 0.0, weight, 1.0)
    x_mean = moments[:, 1:3] / total[:, None]
    cxx = moments[:, 3] / total - x_mean[:, 0] ** 2
    cxy = moments[:, 4] / total - x_mean[:, 0] * x_mean[:, 1]
    cyy = moments[:, 5] / total - x_mean[:, 1] ** 2
    cx_value = moments[:, 6:10] / total[:, None] - x_mean[:, 0, None] * mean
    cy_value = moments[:, 10:14] / total[:, None] - x_mean[:, 1, None] * mean
    determinant = cxx * cyy - cxy * cxy
    # Offsets along a line (or a point) leave the slope across it unknown: no correction there.
    spanned = (moments[:, 0] >= PLANE_POINTS) & (weight > 0.0) & (determinant > 1e-3 * ((cxx + cyy) / 2) ** 2) \
        & (cxx + cyy > 1e-12)
    inverse = np.where(spanned, 1.0 / np.where(spanned, determinant, 1.0), 0.0)
    slope_x = (cyy[:, None] * cx_value - cxy[:, None] * cy_value) * inverse[:, None]
    slope_y = (cxx[:, None] * cy_value - cxy[:, None] * cx_value) * inverse[:, None]
    return slope_x, slope_y, x_mean, (cxx, cxy, cyy)


def pool_samples(rgba: np.ndarray, position: np.ndarray, owner: np.ndarray, pixels: np.ndarray, counts,
                 window: tuple[int, int, int, int], settings: Settings, sample_stratum: np.ndarray | None = None,
                 coverage: Coverage | None = None, lattice_density: float = 0.0,
                 texture: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Filtered RGBA of the supersampled pixels from all their samples, their neighbours' included.

    The filter footprints of neighbouring pixels overlap (radius 1.5 px by default), so a sample drawn for
    one pixel also lies under its neighbours' filters. Each pixel p takes every sample s under its filter,
    weighted by the balance heuristic over the pixels that drew samples there:
    ``w_ps = g_p(x_s) / sum_q S_q g_q(x_s)``, with ``g_q`` the exact density with which pixel q places each
    of its S_q samples (``film.offset_density``) and q over the supersampled pixels; the value is
    ``sum_s w_ps rgba_s / sum_s w_ps``. This estimates the same filtered value as the plain mean of p's own
    samples (Cycles' estimator; the ratio form is consistent, biased by O(1/S)) with several times the
    samples: on the fence bench 9 samples pooled err like 16 unpooled. With a box filter nothing
    overlaps and this is the plain mean.

    With ``coverage`` the sum is split by surface (post-stratification): the value is
    ``sum_k c_pk m_pk / sum_k c_pk`` over the surfaces k that p's samples reach, with ``c_pk`` the share of
    p's coverage rays on surface k and ``m_pk`` the weighted mean above taken over the samples on k alone.
    The jump between surfaces then costs nothing: only the variation within a surface is left to the
    shaded samples. A surface (a stratum: a smooth piece of a mesh) that p's coverage rays saw but no
    sample reached takes the mean of the samples on the other pieces of its connected surface, and where
    none reached those either gives up its share (the others are scaled up); with p's own samples among
    its coverage rays every pixel keeps a surface. The
    estimate is again a ratio of consistent estimates of the same filtered value. Where the coverage
    has its centroids, each ``m_pk`` is a regression estimate (``plane_correction``): the plane fitted to
    the samples on k, taken at the centroid of k's part of the filter, plus the weighted mean of the
    samples' departures from it; a smooth ramp of light (a penumbra) then costs only its departure from a
    plane (``surface_spread`` allocates by that departure).

    With ``texture`` and the coverage's albedo, a textured diffuse surface's mean is scaled by its albedo's
    mean over the coverage rays (a texture lookup each, many) over its mean over the samples (the same
    weights): ``m_pk + r_pk (A_pk / a_pk - 1)``, with ``r_pk`` the weighted mean of the samples' reflected
    radiance (all of which the albedo scales: no glossy lobe). Under light that is even across the filter
    the radiance is the albedo times one irradiance, and this is exact however few samples fall on each
    part of the texture's pattern (a checker's jumps then cost no samples, as surface jumps cost none with
    coverage); otherwise it is a ratio estimator, consistent (``a_pk`` tends to ``A_pk``).

    ``lattice_density`` > 0 says that some of the samples are pass 1's pixel centres (``owner`` -1): a
    lattice of one point per pixel, which joins the balance heuristic as a technique of that density
    everywhere (``w_ps = g_p(x_s) / (lattice_density + sum_q S_q g_q(x_s))``). The centres are shaded
    already; where surfaces jump the coverage has taken the jump out, and what is left (a shadow edge on
    one surface) they sample like a stratified grid. Their weight falls as 1 / (1 + S), so the estimate
    stays consistent; at S = 1 a centre and a random sample share a pixel about equally.

    Parameters
    ----------
    rgba : (N, 4) float64           the samples' RGBA (``sample_rgba``).
    position : (N, 2) float64       their full-frame raster positions (``subpixel_samples``).
    owner : (N,) int64              the index into ``pixels`` of the pixel each sample was drawn for (-1
                                    for a lattice point).
    pixels : (P,) int64             the supersampled window-local pixels.
    counts : int or (P,) int64      samples drawn for each of them (S_q).
    window : (x0, y0, x1, y1)       the camera window (full-frame pixel bounds).
    sample_stratum : (N,) int64     surface each sample sees (-1: background), with ``coverage``.
    coverage : Coverage or None     the pixels' coverage (``pixel_coverage``).
    lattice_density : float         points per pixel area of the lattice among the samples (0: none).
    texture : ((N, 3), (N, 3)) float64 or None   the samples' radiance that their albedo scales (their
                                    reflected light: RGB less emission) and their albedo, NaN where they
                                    see no textured surface (with ``coverage.albedo``).

    Returns
    -------
    (P, 4) float64 filtered RGBA of ``pixels``.
    """
    x0, y0, x1, y1 = window
    width = x1 - x0
    index = np.full((y1 - y0) * width, -1, np.int64)
    index[pixels] = np.arange(len(pixels))
    drawn = np.zeros(len(pixels) + 1)  # samples per pooled pixel; the last entry (index -1) is "none"
    drawn[:-1] = counts
    reach = settings.filter_reach
    # (J,) candidate pixel offsets from the cell a sample lies in: a pixel q reaches a sample at offset
    # t = x - q in [0.5 - reach, 0.5 + reach], so with x - cell in [0, 1) q - cell runs from
    # ceil(-0.5 - reach) to below ceil(0.5 + reach) (4 offsets at the default radius 1.5).
    steps = np.arange(int(np.ceil(-0.5 - reach)), int(np.ceil(0.5 + reach)), dtype=np.int64)
    # Sums of RGBA and of the weights per pixel, and per (pixel, surface) entry of the coverage.
    totals = np.zeros((len(pixels), 5))
    entries = len(coverage.pixel) if coverage is not None else 0
    coverage_key = np.ascontiguousarray(coverage.key, np.int64) if coverage is not None else np.zeros(0, np.int64)
    textured = texture is not None and coverage is not None and coverage.albedo is not None
    # Per entry: RGBA, the weights, and on textured surfaces the albedo-scaled radiance and the albedo.
    surface_totals = np.zeros((entries, 11 if textured else 5))
    scaled_part = np.ascontiguousarray(np.concatenate([texture[0], np.nan_to_num(texture[1], nan=0.0)], axis=1),
                                       np.float64) if textured else np.zeros((0, 6))
    # Per entry, for the plane fitted in raster position (offsets from the pixel's centre, pixels): the
    # points, the weighted sums of the offset, of its products and of its products with RGBA.
    fitted = coverage is not None and coverage.centroid is not None
    moments = np.zeros((entries, 14 if fitted else 0))
    pixel_centre = np.stack([x0 + np.asarray(pixels) % width, y0 + np.asarray(pixels) // width], axis=1) + 0.5
    table = filter_table(settings.effective_filter_width, settings.filter_type)
    stratum = np.ascontiguousarray(sample_stratum, np.int64) if coverage is not None else np.zeros(0, np.int64)
    _pool_sums(np.ascontiguousarray(position, np.float64), np.ascontiguousarray(owner, np.int64),
               np.ascontiguousarray(rgba, np.float64), index, drawn, np.array([x0, y0, x1, y1], np.int64), steps,
               np.ascontiguousarray(table[:len(table) - 1]), float(lattice_density), stratum, coverage_key,
               coverage.stride if coverage is not None else 1, scaled_part,
               np.ascontiguousarray(pixel_centre, np.float64), totals, surface_totals, moments)
    plain = totals[:, :4] / np.maximum(totals[:, 4:], 1e-300)
    if coverage is None:
        return plain
    reached = surface_totals[:, 4] > 0.0
    own = reached  # entries whose own samples reached them: a plane is fitted only to a stratum's own points
    if coverage.parent is not None and entries and not reached.all():
        # A stratum that no sample reached takes the samples on the rest of its connected surface under
        # the pixel's filter (a box's sliver of a side face: the box's other faces), rather than giving its
        # share up to every surface the pixel sees.
        _, surface = np.unique(coverage.parent_key(coverage.pixel, coverage.stratum), return_inverse=True)
        surface = surface.reshape(-1)
        pooled = np.stack([np.bincount(surface, weights=column) for column in surface_totals.T], axis=1)
        surface_totals = np.where(reached[:, None], surface_totals, pooled[surface])
        reached = surface_totals[:, 4] > 0.0
    share = np.where(reached, coverage.fraction, 0.0)
    mean = surface_totals[:, :4] / np.where(reached, surface_totals[:, 4], 1.0)[:, None]
    if fitted:
        # A surface under the whole filter has its centroid at the pixel's centre (a symmetric filter):
        # exactly, not as its rays' mean.
        centroid = np.where((coverage.fraction >= 1.0)[:, None], 0.0, coverage.centroid - pixel_centre[coverage.pixel])
        correction = plane_correction(surface_totals[:, 4], mean, moments, centroid)
        correction[~own] = 0.0  # (a face no sample reached takes its neighbours' mean: their plane is not its)
        if textured:  # a texture's pattern is no plane: its surfaces keep the albedo ratio below alone
            correction[np.isfinite(coverage.albedo).any(axis=1)] = 0.0
        # Radiance is not negative, nor alpha beyond [0, 1]: the estimate projected onto that range (which
        # holds the filtered value) errs no more than before, and a plane extrapolated past a surface's
        # dark edge shows no negative pixel.
        mean = np.clip(mean + correction, 0.0, [np.inf, np.inf, np.inf, 1.0])
    if textured:
        scaled = surface_totals[:, 5:8] / np.where(reached, surface_totals[:, 4], 1.0)[:, None]
        sampled = surface_totals[:, 8:11] / np.where(reached, surface_totals[:, 4], 1.0)[:, None]
        rays = coverage.albedo
        conditioned = reached[:, None] & np.isfinite(rays) & (sampled > 0.0)
        ratio = np.where(conditioned, rays / np.where(conditioned, sampled, 1.0), 1.0)
        mean[:, :3] += scaled * (ratio - 1.0)
    kept = np.bincount(coverage.pixel, weights=share, minlength=len(pixels))
    stratified = np.stack([np.bincount(coverage.pixel, weights=share * mean[:, channel], minlength=len(pixels))
                           for channel in range(4)], axis=1) / np.maximum(kept, 1e-300)[:, None]
    # A pixel none of whose covered surfaces any sample reached (its own samples are among its coverage
    # rays, so only a pixel without samples of its own) keeps the plain mean.
    return np.where((kept > 0.0)[:, None], stratified, plain)
