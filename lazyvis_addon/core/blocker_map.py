"""Pass 1: the blocker map (paper section 4.1).

Shadow rays find blocker–light pairs; each pair is flood-filled through the image while the blocker,
seen from each pixel's visible point, overlaps the light. The fill is a wavefront over all active pairs
at once: every iteration tests the whole frontier in array batches and grows it by one ring of
neighbours, with a packed bitset per pixel remembering which pairs a pixel has already been tested for.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import rng
from .blockers import BlockerPolygons
from .geometry import (LightFrames, PLANE_EPS, blocker_in_front_of_light, cones_overlap, cross3, light_groups,
                       receiver_light)
from .parallel import map_batches, thread_count
from .progress import Progress
from .sampling import sample_polygon_solid_angle
from .settings import Settings
from .surface import SurfacePoints, shadow_rays

# Pair tests per array batch: bounds the temporaries (about 2 kB per test).
TEST_BATCH = 65536

_NEIGHBOURS_4 = np.array([(0, -1), (0, 1), (-1, 0), (1, 0)])
_NEIGHBOURS_8 = np.array([(0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1)])


@dataclass
class BlockerMap:
    """Blocker–light pairs stored per pixel, sorted by (pixel, light).

    Attributes
    ----------
    pixel : (E,) int64       window-local pixel index (row-major, row 0 = top).
    light : (E,) int64
    blocker : (E,) int64     blocker polygon (see ``BlockerPolygons``).
    umbra : (N, L) bool      the light is hidden at this pixel (one blocker surrounds it).
    stats : dict             rays cast, seeds, pairs, tests, fill iterations.
    """

    pixel: np.ndarray
    light: np.ndarray
    blocker: np.ndarray
    umbra: np.ndarray
    stats: dict = field(default_factory=dict)

    def count_per_pixel(self, n_pixels: int) -> np.ndarray:
        return np.bincount(self.pixel, minlength=n_pixels).astype(np.int32)

    def crop(self, inner: np.ndarray, n_pixels: int) -> "BlockerMap":
        """The map restricted to the pixels ``inner`` (ascending indices), renumbered 0 .. len(inner)-1."""
        renumber = np.full(n_pixels, -1, np.int64)
        renumber[inner] = np.arange(len(inner))
        pixel = renumber[self.pixel]
        keep = pixel >= 0
        return BlockerMap(pixel[keep], self.light[keep], self.blocker[keep], self.umbra[inner], dict(self.stats))

    @classmethod
    def from_entries(cls, pixel, light, blocker, umbra, stats=None) -> "BlockerMap":
        """Sort and de-duplicate (pixel, light, blocker) entries."""
        pixel, light, blocker = (np.asarray(a, dtype=np.int64) for a in (pixel, light, blocker))
        n_lights = umbra.shape[1]
        n_blockers = int(blocker.max()) + 1 if len(blocker) else 1
        key = np.unique((pixel * n_lights + light) * n_blockers + blocker)
        pixel_light = key // n_blockers
        return cls(pixel_light // n_lights, pixel_light % n_lights, key % n_blockers, umbra, dict(stats or {}))


def test_pairs(surface: SurfacePoints, frames: LightFrames, blockers: BlockerPolygons, pixel: np.ndarray,
               blocker: np.ndarray, light: np.ndarray, threads: int = 1, progress: Progress | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Does ``blocker`` overlap ``light`` seen from the visible point of ``pixel``?

    Parameters
    ----------
    surface : SurfacePoints of the whole window; pixel, blocker, light : (N,) int64.
    progress : advanced by each batch's pair count (and may cancel), when given.

    Returns
    -------
    overlap : (N,) bool   conservative (touching counts).
    umbra : (N,) bool     the blocker alone hides the whole light.
    """
    # At most TEST_BATCH pairs a batch, but enough batches for every thread (culling a few samples).
    batch = min(TEST_BATCH, max(4096, -(-len(pixel) // (4 * max(threads, 1)))))
    starts = range(0, len(pixel), batch)
    parts = map_batches(lambda start: _test_batch(surface, frames, blockers, pixel[start:start + batch],
                                                  blocker[start:start + batch], light[start:start + batch]),
                        starts, threads, progress, [min(batch, len(pixel) - start) for start in starts])
    if not parts:
        return np.zeros(0, bool), np.zeros(0, bool)
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _test_batch(surface, frames, blockers, pixel, blocker, light):
    """Cone overlap of whole blocker polygons against whole lights, signs only (no normalisation needed).

    The light is not clipped to the receiver's horizon here: that keeps the test cheap and only makes it
    more conservative (pass 2 clips exactly). Blockers cut by the light's plane take the general path.
    """
    x = surface.position[pixel]
    normal = surface.geometric_normal[pixel]
    count = blockers.count[blocker]
    rel = blockers.vertices[blocker] - x[:, None]                           # (N, 4, 3), triangles padded
    scale = np.abs(rel).max(axis=2)                                          # (N, 4)
    heights = np.einsum("nvk,nk->nv", rel, normal)
    light_normal = frames.normal[light]
    receiver_height = np.einsum("nk,nk->n", x - frames.origin[light], light_normal)
    side = np.where(frames.two_sided[light] & (receiver_height < 0), -1.0, 1.0)
    blocker_height = side[:, None] * (np.einsum("nvk,nk->nv", rel, light_normal) + receiver_height[:, None])
    light_scale = np.abs(x).max(axis=1) + np.sqrt(frames.area[light])
    in_front = blocker_height > PLANE_EPS * (scale + np.abs(x).max(axis=1)[:, None])
    # The receiver's own blocker, anything on or behind its tangent plane, anything behind the light,
    # and lights the receiver is behind, cannot shadow it.
    own = blockers.of_triangle[surface.index_triangle[pixel]]
    candidate = ((blocker != own) & (heights > 1e-7 * scale).any(axis=1)
                 & in_front.any(axis=1) & (side * receiver_height > PLANE_EPS * light_scale))
    blocker_planes = cross3(rel, np.roll(rel, -1, axis=1))                  # (N, 4, 3)
    triple = np.einsum("nk,nk->n", rel[:, 0], blocker_planes[:, 1])
    candidate &= np.abs(triple) > 1e-12 * scale.max(axis=1) ** 3             # no solid angle otherwise
    blocker_planes *= np.sign(triple)[:, None, None]
    # A padded triangle's edge 2 joins its last vertex to itself: no plane.
    edge_valid = ~((count[:, None] == 3) & (np.arange(4)[None, :] == 2))
    light_rel = frames.vertices[light] - x[:, None]                         # (N, V, 3)
    light_planes = cross3(light_rel, np.roll(light_rel, -1, axis=1)) * -side[:, None, None]
    blocker_vs_light = np.einsum("nik,njk->nij", blocker_planes, light_rel)  # (N, 4, V)
    light_vs_blocker = np.einsum("njk,nik->nji", light_planes, rel)          # (N, V, 4)
    separated = (((blocker_vs_light.max(axis=2) < 0) & edge_valid).any(axis=1)
                 | (light_vs_blocker.max(axis=2) < 0).any(axis=1))
    overlap = candidate & ~separated
    inside = np.where(edge_valid, blocker_vs_light.min(axis=2), np.inf).min(axis=1) > 0
    umbra = overlap & inside & in_front.all(axis=1)
    straddle = np.flatnonzero(candidate & ~in_front.all(axis=1))
    if len(straddle):
        polygon, clipped_count = blocker_in_front_of_light(x[straddle], blockers.vertices[blocker[straddle]],
                                                           count[straddle], frames.origin[light[straddle]],
                                                           light_normal[straddle], side[straddle])
        overlap[straddle], _ = cones_overlap(polygon, clipped_count, light_rel[straddle],
                                             frames.vertex_count[light[straddle]])
    return overlap, umbra


def first_blocker(tracer, blockers: BlockerPolygons, surface: SurfacePoints, pixel: np.ndarray, origin: np.ndarray,
                  direction: np.ndarray, tfar: np.ndarray) -> np.ndarray:
    """The blocker each shadow ray hits first (N,) int64, -1 for none or for the receiver's own blocker."""
    hits = tracer.intersect(origin, direction, tfar)
    found = np.where(hits.index_triangle >= 0, blockers.of_triangle[np.maximum(hits.index_triangle, 0)], -1)
    own = blockers.of_triangle[surface.index_triangle[pixel]]
    return np.where(found != own, found, -1)


def detect_seeds(surface: SurfacePoints, frames: LightFrames, blockers: BlockerPolygons, tracer, settings: Settings,
                 pixel_global: np.ndarray, progress: Progress) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Shadow rays: S per pixel and light, stratified over the light's visible solid angle.

    Returns
    -------
    pixel, blocker, light : (P,) int64   unique seed triples (window-local pixel).
    rays : int                            shadow rays cast.
    """
    n_lights = len(frames)
    samples = settings.shadow_rays
    hit_pixels = np.flatnonzero(surface.hit)
    batch = max(1, settings.pixel_batch // max(1, samples * n_lights) * 4)
    starts = list(range(0, len(hit_pixels), batch))

    groups = [np.flatnonzero(group) for group in light_groups(frames)]

    def detect(start: int):
        pixels = hit_pixels[start:start + batch]
        parts = [detect_group(pixels, lights) for lights in groups]  # lights of similar size: a handful
        parts = [p for p in parts if p is not None]
        if not parts:
            return None
        return tuple(np.concatenate([p[i] for p in parts]) for i in range(3)) + (sum(p[3] for p in parts),)

    def detect_group(pixels: np.ndarray, lights: np.ndarray):
        pix = np.repeat(pixels, len(lights))
        lig = np.tile(lights, len(pixels))
        setup = receiver_light(surface.position[pix], surface.geometric_normal[pix], surface.shading_normal[pix],
                               lig, frames)
        lit = np.flatnonzero(setup.count >= 3)
        if len(lit) == 0:
            return None
        sample = np.tile(np.arange(samples), len(lit))
        rows = np.repeat(lit, samples)
        pix_s, lig_s = pix[rows], lig[rows]
        u = rng.uniforms(settings.seed, settings.frame, rng.STREAM_SHADOW_RAYS, pixel_global[pix_s],
                         lig_s * samples + sample, 2)
        u = rng.stratified_2d(u, sample, samples)
        polygons = setup.directions(frames, setup.uv[lit], lit)
        direction, pdf, _ = sample_polygon_solid_angle(polygons, setup.count[lit], u, repeat=samples)
        origin, tfar, good = shadow_rays(surface, pix_s, direction, pdf, frames.origin[lig_s], frames.normal[lig_s],
                                         setup.side[rows])
        found = first_blocker(tracer, blockers, surface, pix_s[good], origin[good], direction[good], tfar[good])
        blocked = found >= 0
        return pix_s[good][blocked], found[blocked], lig_s[good][blocked], int(good.sum())

    progress.begin_stage("Blocker detection", len(hit_pixels))
    units = [len(hit_pixels[start:start + batch]) for start in starts]
    found = [f for f in map_batches(detect, starts, thread_count(settings.threads), progress, units) if f is not None]
    progress.end_stage()
    found_pixel = [f[0] for f in found]
    found_blocker = [f[1] for f in found]
    found_light = [f[2] for f in found]
    rays = sum(f[3] for f in found)
    if not found_pixel:
        empty = np.zeros(0, np.int64)
        return empty, empty, empty, rays
    pixel = np.concatenate(found_pixel)
    blocker = np.concatenate(found_blocker).astype(np.int64)
    light = np.concatenate(found_light)
    n_blockers = int(blocker.max()) + 1 if len(blocker) else 1
    key = np.unique((pixel * n_lights + light) * n_blockers + blocker)
    return key // n_blockers // n_lights, key % n_blockers, key // n_blockers % n_lights, rays


def flood_fill(surface: SurfacePoints, frames: LightFrames, blockers: BlockerPolygons, shape: tuple[int, int],
               seed_pixel: np.ndarray, seed_blocker: np.ndarray, seed_light: np.ndarray, settings: Settings,
               progress: Progress) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    """Grow every seeded pair through the image while its blocker overlaps its light.

    Parameters
    ----------
    shape : (H, W) of the window; seed_* : (P,) int64 seed triples.

    Returns
    -------
    pixel, blocker, light : (E,) int64   stored entries.
    umbra : (N, L) bool
    stats : dict                          tests, iterations, pairs.
    """
    height, width = shape
    n_pixels = height * width
    n_lights = len(frames)
    umbra = np.zeros((n_pixels, n_lights), bool)
    stats = {"fill_tests": 0, "fill_iterations": 0, "pairs": 0}
    if len(seed_pixel) == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty, empty, umbra, stats
    pair_key, seed_pair = np.unique(seed_blocker * n_lights + seed_light, return_inverse=True)
    pair_blocker, pair_light = pair_key // n_lights, pair_key % n_lights
    stats["pairs"] = len(pair_key)
    offsets = _NEIGHBOURS_8 if settings.connectivity == 8 else _NEIGHBOURS_4

    # Visited bits: one bit per (pixel, pair) in a chunk of pairs; chunk size from the memory budget.
    budget_bytes = settings.memory_budget_mb * 2 ** 20 * 0.25
    pairs_per_chunk = int(budget_bytes // max(n_pixels, 1)) * 8
    if pairs_per_chunk < 8:
        raise MemoryError(f"memory budget of {settings.memory_budget_mb:g} MB is too small for the "
                          f"{width} x {height} blocker map; raise it or render in tiles")
    stored = []
    progress.begin_stage("Flood fill", len(pair_key))
    for chunk_start in range(0, len(pair_key), pairs_per_chunk):  # chunks of pairs, usually one
        chunk_end = min(chunk_start + pairs_per_chunk, len(pair_key))
        in_chunk = (seed_pair >= chunk_start) & (seed_pair < chunk_end)
        visited = np.zeros(((chunk_end - chunk_start + 7) // 8, n_pixels), np.uint8)
        frontier_pixel = seed_pixel[in_chunk]
        frontier_pair = seed_pair[in_chunk] - chunk_start
        _mark(visited, frontier_pair, frontier_pixel)
        while len(frontier_pixel):
            stats["fill_iterations"] += 1
            stats["fill_tests"] += len(frontier_pixel)
            pair = frontier_pair + chunk_start
            ok, hidden = test_pairs(surface, frames, blockers, frontier_pixel, pair_blocker[pair], pair_light[pair],
                                    thread_count(settings.threads))
            # Extended fill: the boundary pixels, where the test first fails, keep the pair too (the
            # penumbra may reach into them), but the fill does not go on from them.
            keep = np.ones_like(ok) if settings.fills_boundary else ok
            stored.append(np.stack([frontier_pixel[keep], pair[keep]]))
            umbra[frontier_pixel[hidden], pair_light[pair[hidden]]] = True
            frontier_pixel, frontier_pair = _next_ring(frontier_pixel[ok], frontier_pair[ok], offsets, height, width,
                                                       surface.hit, visited)
            progress.check_cancel()
        progress.advance(chunk_end - chunk_start)
    progress.end_stage()
    entries = np.concatenate(stored, axis=1)
    pair = entries[1]
    return entries[0], pair_blocker[pair], pair_light[pair], umbra, stats


def _mark(visited: np.ndarray, pair: np.ndarray, pixel: np.ndarray) -> None:
    np.bitwise_or.at(visited, (pair >> 3, pixel), (1 << (pair & 7)).astype(np.uint8))


def _next_ring(pixel, pair, offsets, height, width, hit, visited):
    """Untested neighbours (8- or 4-connected) of the pixels where a pair was just stored."""
    if len(pixel) == 0:
        return pixel, pair
    row, col = np.divmod(pixel, width)
    rows = row[:, None] + offsets[None, :, 0]
    cols = col[:, None] + offsets[None, :, 1]
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    neighbour = (rows * width + cols)[inside]
    pair_n = np.broadcast_to(pair[:, None], rows.shape)[inside]
    keep = hit[neighbour]
    neighbour, pair_n = neighbour[keep], pair_n[keep]
    seen = (visited[pair_n >> 3, neighbour] >> (pair_n & 7).astype(np.uint8)) & 1
    neighbour, pair_n = neighbour[seen == 0], pair_n[seen == 0]
    key = np.unique(pair_n * (height * width) + neighbour)
    pair_n, neighbour = np.divmod(key, height * width)
    _mark(visited, pair_n, neighbour)
    return neighbour, pair_n


def build_blocker_map(surface: SurfacePoints, frames: LightFrames, blockers: BlockerPolygons, tracer,
                      shape: tuple[int, int], pixel_global: np.ndarray, settings: Settings,
                      progress: Progress) -> BlockerMap:
    """Pass 1 for the lazy integrators: detection, flood fill, umbra (paper 4.1 and 5)."""
    seed_pixel, seed_blocker, seed_light, rays = detect_seeds(surface, frames, blockers, tracer, settings,
                                                              pixel_global, progress)
    pixel, blocker, light, umbra, stats = flood_fill(surface, frames, blockers, shape, seed_pixel, seed_blocker,
                                                     seed_light, settings, progress)
    if not settings.umbra_detection:
        umbra[:] = False
    stats.update(shadow_rays=rays, seeds=len(seed_pixel))
    return BlockerMap.from_entries(pixel, light, blocker, umbra, stats)


def reference_blocker_map(surface: SurfacePoints, frames: LightFrames, blockers: BlockerPolygons,
                          shape: tuple[int, int], settings: Settings, progress: Progress) -> BlockerMap:
    """Every blocker is a candidate: the exact (and slow) oracle.

    Pixels are taken in tiles; a blocker is tested against a tile only when its bounding box meets the
    box around the tile's visible points and the light (a segment from any of those points to the light
    lies in that box), which keeps the test exact while skipping most pairs.
    """
    height, width = shape
    n_pixels = height * width
    n_lights = len(frames)
    umbra = np.zeros((n_pixels, n_lights), bool)
    tri_low, tri_high = blockers.vertices.min(axis=1), blockers.vertices.max(axis=1)
    tile = 16
    tiles = [(r, c) for r in range(0, height, tile) for c in range(0, width, tile)]
    stored = []
    tests = 0
    progress.begin_stage("Reference blockers", len(tiles))
    for r, c in tiles:  # tiles of pixels
        rows, cols = np.mgrid[r:min(r + tile, height), c:min(c + tile, width)]
        pixels = (rows * width + cols).reshape(-1)
        pixels = pixels[surface.hit[pixels]]
        if len(pixels) == 0 or len(blockers) == 0:
            progress.advance()
            continue
        points = surface.position[pixels]
        for light in range(n_lights):  # lights: a handful
            corners = frames.vertices[light, :frames.vertex_count[light]]
            low = np.minimum(points.min(axis=0), corners.min(axis=0))
            high = np.maximum(points.max(axis=0), corners.max(axis=0))
            candidates = np.flatnonzero((tri_low <= high).all(axis=1) & (tri_high >= low).all(axis=1))
            if len(candidates) == 0:
                continue
            pix = np.repeat(pixels, len(candidates))
            tri = np.tile(candidates, len(pixels))
            lig = np.full(len(pix), light)
            ok, hidden = test_pairs(surface, frames, blockers, pix, tri, lig, thread_count(settings.threads))
            tests += len(pix)
            stored.append(np.stack([pix[ok], tri[ok], lig[ok]]))
            umbra[pix[hidden], light] = True
        progress.advance()
    progress.end_stage()
    entries = np.concatenate(stored, axis=1) if stored else np.zeros((3, 0), np.int64)
    if not settings.umbra_detection:
        umbra[:] = False
    return BlockerMap.from_entries(entries[0], entries[2], entries[1], umbra, {"reference_tests": tests})
