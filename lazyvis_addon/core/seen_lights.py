"""Lights the camera sees: Blender lights with Ray Visibility > Camera on, drawn over the image as Cycles
draws them.

What Cycles 5.0.1 does, measured through bpy (direct light only; the README's light table):

- a camera ray that passes a light **adds the light's radiance and goes on** to whatever lies behind it:
  a light occludes nothing and adds no alpha (film transparent: alpha 0 over a light against the sky);
- an **area light** is seen from its emitting side only (its back is invisible), with the radiance it
  lights with, ``colour * power * 2^exposure / (pi * area)``, times its Spread's weight on the direction
  towards the camera; squares and rectangles as they are, disks and ellipses as true ellipses;
- a **point or spot lamp** of radius r > 0 is a disk of radius r facing the ray's origin (Soft Falloff on)
  or a sphere (off), of radiance I / (pi r^2), I = P / (4 pi); a spot's is that times its cone's smoothstep
  on the direction from the lamp back along the ray; radius 0 is not seen;
- a **sun** of angle a > 0 is seen where a ray escapes the scene within a / 2 of its direction, with radiance
  E / (pi sin^2(a / 2)) (E its Strength, the irradiance it gives).

Mesh emitters are geometry: pass 1 sees them already. Lights are drawn through Cycles' pixel filter:
SEEN_SAMPLES^2 stratified samples placed as Cycles places its camera samples (``film.filter_offsets``) over
every pixel whose filter reaches a light's screen box (exact inside a light), and OUTLINE_SAMPLES of the
film's scrambled Sobol points where a light's outline, or a surface's edge in front of it, comes within the
filter's reach (an unbiased estimate, seeded like anti-aliasing's edge samples).
"""

from __future__ import annotations

import numpy as np

from . import rng
from .camera import camera_rays, clip_distance, window_pixels
from .facing import cone_attenuation, spread_weight
from .film import filter_offsets, half_extent
from .scene import SEEN_ELLIPSE, SEEN_RECTANGLE, SEEN_SPHERE, SEEN_SUN, SeenLights
from .settings import Settings

# Camera samples per pixel axis over a light's screen box; samples per pixel where an outline is near (a
# light is often a hundred times brighter than what surrounds it: an outline takes many samples).
SEEN_SAMPLES = 4
OUTLINE_SAMPLES = 256


def radiance_along(seen: SeenLights, origins: np.ndarray, directions: np.ndarray, t_hit: np.ndarray,
                   t_max: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """What camera rays see of the lights before their first surface.

    Parameters
    ----------
    origins, directions : (N, 3) float64   rays (unit directions).
    t_hit : (N,) float64                   distance to the first surface (inf where the ray escapes).
    t_max : (N,) float64 or None           the camera's clip end along each ray: lights beyond are not seen
                                           (a sun is, where the ray escapes).

    Returns
    -------
    radiance : (N, 3) float64   the sum over the lights the ray passes (or, for suns, escapes towards).
    which : (N,) int64          a bit per light among the first 63 that the ray sees (to tell outlines).
    """
    n = len(origins)
    reach = t_hit if t_max is None else np.minimum(t_hit, t_max)
    radiance = np.zeros((n, 3))
    which = np.zeros(n, np.int64)
    for light in range(len(seen)):  # the lights the camera sees: a handful
        kind = int(seen.kind[light])
        centre = seen.centre[light]
        weight = np.zeros(n)
        if kind == SEEN_SUN:
            inside = ~np.isfinite(t_hit) & (directions @ centre >= np.cos(seen.radius[light]))
            weight[inside] = 1.0
        elif kind in (SEEN_RECTANGLE, SEEN_ELLIPSE):
            u, v = seen.axes[light]
            normal = np.cross(u, v)
            facing = directions @ normal
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((centre - origins) @ normal) / facing
            front = (facing < 0) & (t > 0) & (t <= reach)
            rows = np.flatnonzero(front)
            offset = origins[rows] + t[rows, None] * directions[rows] - centre
            # Coordinates (a, b) of the point in the (u, v) frame: the 2 x 2 Gram system.
            uu, uv, vv = u @ u, u @ v, v @ v
            pu, pv = offset @ u, offset @ v
            det = uu * vv - uv * uv
            a, b = (vv * pu - uv * pv) / det, (uu * pv - uv * pu) / det
            inside = (np.abs(a) <= 1.0) & (np.abs(b) <= 1.0) if kind == SEEN_RECTANGLE else a * a + b * b <= 1.0
            rows = rows[inside]
            cosine = -facing[rows] / np.linalg.norm(normal)
            weight[rows] = spread_weight(cosine, np.full(len(rows), seen.spread[light]))
        else:
            radius = seen.radius[light]
            to_centre = centre - origins
            along = np.einsum("nk,nk->n", to_centre, directions)
            distance_sq = np.einsum("nk,nk->n", to_centre, to_centre)
            if kind == SEEN_SPHERE:
                closest_sq = distance_sq - along * along
                t = along - np.sqrt(np.maximum(radius * radius - closest_sq, 0.0))
                hit = (closest_sq <= radius * radius) & (along > 0)
            else:  # a disk facing the ray's origin: in the plane through the centre normal to it
                distance = np.sqrt(distance_sq)
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = distance_sq / along  # (centre - o) . n / (d . n) with n = (centre - o) / distance
                    spoke_sq = t * t - distance_sq  # |o + t d - centre|^2 for such a point
                hit = (along > 0) & (spoke_sq <= radius * radius) & (distance > radius)
            rows = np.flatnonzero(hit & (t > 0) & (t <= reach))
            weight[rows] = cone_attenuation(np.broadcast_to(seen.spot_frame[light], (len(rows), 3, 3)),
                                            np.full(len(rows), seen.spot_cos_half[light]),
                                            np.full(len(rows), seen.spot_smooth[light]), -directions[rows])
        radiance += weight[:, None] * seen.radiance[light]
        if light < 63:
            which |= (weight > 0).astype(np.int64) << light
    return radiance, which


def screen_boxes(seen: SeenLights, camera) -> np.ndarray:
    """(N, 4) float64 boxes (x0, y0, x1, y1) in full-frame pixel units (y down) that hold each light's
    image: the projection of points whose hull holds the light; the whole frame where one lies behind the
    camera (or a sun in an orthographic view)."""
    boxes = np.tile(np.array([-np.inf, -np.inf, np.inf, np.inf]), (len(seen), 1))
    rotation = camera.world_from_camera[:3, :3]
    position = camera.world_from_camera[:3, 3]
    perspective = camera.projection == "perspective"
    for light in range(len(seen)):  # a handful
        kind = int(seen.kind[light])
        centre = seen.centre[light]
        if kind == SEEN_SUN:
            if not perspective:
                continue
            helper = np.eye(3)[np.argmin(np.abs(centre))]
            e1 = np.cross(centre, helper)
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(centre, e1)
            reach = np.tan(min(1.01 * seen.radius[light], 1.5)) * np.sqrt(2.0)
            points = position + centre + reach * np.array([s * e1 + t * e2 for s in (-1, 1) for t in (-1, 1)])
        elif kind in (SEEN_RECTANGLE, SEEN_ELLIPSE):
            u, v = seen.axes[light]
            points = centre + np.array([s * u + t * v for s in (-1, 1) for t in (-1, 1)])
        else:
            r = seen.radius[light]
            points = centre + r * np.array([[s, t, w] for s in (-1, 1) for t in (-1, 1) for w in (-1, 1)])
        local = (points - position) @ rotation
        if perspective:
            if not (local[:, 2] < 0).all():
                continue  # a point beside or behind the camera: the whole frame
            sx, sy = local[:, 0] / -local[:, 2], local[:, 1] / -local[:, 2]
        else:
            sx, sy = local[:, 0], local[:, 1]
        left, right, bottom, top = camera.screen_window
        fx = (sx - left) / (right - left) * camera.width
        fy = (top - sy) / (top - bottom) * camera.height
        boxes[light] = fx.min(), fy.min(), fx.max(), fy.max()
    return boxes


def _grid(samples: int) -> np.ndarray:
    """(samples^2, 2) canonical uniforms at the centres of a samples x samples grid."""
    centres = (np.arange(samples) + 0.5) / samples
    return np.stack(np.meshgrid(centres, centres, indexing="ij"), axis=-1).reshape(-1, 2)


def _pixel_means(seen, camera, tracer, xs, ys, offsets, batch: int, progress=None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean radiance (P, 3) over each pixel's samples at ``offsets`` (S, 2) (the same for every pixel) or
    (P, S, 2) (each pixel's own), and the lights (bits, as ``radiance_along``) some of its samples see (P,)
    int64 and all of them see (P,) int64."""
    count = offsets.shape[-2]
    means = np.zeros((len(xs), 3))
    some = np.zeros(len(xs), np.int64)
    every = np.zeros(len(xs), np.int64)
    step = max(batch // count, 1)
    for start in range(0, len(xs), step):  # batches of pixels
        rows = slice(start, start + step)
        px, py = np.repeat(xs[rows], count), np.repeat(ys[rows], count)
        at = offsets[rows].reshape(-1, 2) if offsets.ndim == 3 else np.tile(offsets, (len(xs[rows]), 1))
        origins, directions = camera_rays(camera, px, py, at)
        clip = clip_distance(camera, directions)
        hits = tracer.intersect(origins, directions, clip)
        radiance, which = radiance_along(seen, origins, directions, hits.t, clip)
        means[rows] = radiance.reshape(-1, count, 3).mean(axis=1)
        which = which.reshape(-1, count)
        some[rows] = np.bitwise_or.reduce(which, axis=1)
        every[rows] = np.bitwise_and.reduce(which, axis=1)
        if progress is not None:
            progress.check_cancel()
    return means, some, every


def draw_seen_lights(seen: SeenLights, camera, tracer, settings: Settings, pixel_global: np.ndarray,
                     progress=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the camera's window sees of the lights, through the pixel filter: the window's pixels (K,) int64
    (row-major, window-local) a light's image may reach, the radiance (K, 3) float64 to add to them
    (``pixel_global`` (H * W,) int64 the window's full-frame indices), and the pixels (E,) int64 that took
    OUTLINE_SAMPLES samples.

    Every pixel whose filter reaches a light's screen box takes SEEN_SAMPLES^2 stratified samples; those whose
    samples see different lights, or within the filter's reach of a pixel whose samples see other lights
    than its own (an outline the coarse samples straddle or that only the filter's tails reach), take
    OUTLINE_SAMPLES of the film's scrambled Sobol points instead, as anti-aliasing's edge samples do. The
    work runs over the rectangle of pixels the boxes reach, not the whole window."""
    filter_width, filter_type = settings.effective_filter_width, settings.filter_type
    batch = settings.pixel_batch * 4
    nothing = np.zeros(0, np.int64)
    if len(seen) == 0:
        return nothing, np.zeros((0, 3)), nothing
    extent = half_extent(filter_width, filter_type)
    k = int(np.ceil(extent + 0.5))  # the filter's reach in pixels
    reach = 0.5 + extent + 1e-6  # the samples' reach about the pixel centre
    boxes = screen_boxes(seen, camera)
    # The coarse samples run over the window grown by that reach (within the frame), so that a pixel at
    # the window's edge is refined exactly when it is in the full frame: a border renders the frame's
    # pixels; and only over the part of it within k pixels of a pixel a box reaches (the outline test
    # looks k pixels around each), outside of which every pixel's coarse samples would see nothing.
    x0, y0, x1, y1 = camera.window
    grown = (max(x0 - k, 0), max(y0 - k, 0), min(x1 + k, camera.width), min(y1 + k, camera.height))
    with np.errstate(invalid="ignore"):
        low = np.floor(np.clip(boxes[:, :2].min(axis=0) - reach - 0.5, -2.0 ** 40, 2.0 ** 40))
        high = np.ceil(np.clip(boxes[:, 2:].max(axis=0) + reach - 0.5, -2.0 ** 40, 2.0 ** 40))
    grown = (max(grown[0], int(low[0]) - k), max(grown[1], int(low[1]) - k),
             min(grown[2], int(high[0]) + 1 + k), min(grown[3], int(high[1]) + 1 + k))
    if grown[2] <= grown[0] or grown[3] <= grown[1]:
        return nothing, np.zeros((0, 3)), nothing
    gxs, gys = window_pixels(camera, grown)
    g_height, g_width = grown[3] - grown[1], grown[2] - grown[0]
    centre_x, centre_y = gxs + 0.5, gys + 0.5
    near = np.zeros(len(gxs), bool)
    for bx0, by0, bx1, by1 in boxes:  # a handful
        near |= (centre_x + reach >= bx0) & (centre_x - reach <= bx1) & (centre_y + reach >= by0) & \
            (centre_y - reach <= by1)
    del centre_x, centre_y
    pixels = np.flatnonzero(near)
    if progress is not None:
        progress.begin_stage("Drawing lights", len(pixels))
    offsets = filter_offsets(_grid(SEEN_SAMPLES), filter_width, filter_type)
    means, some, every = _pixel_means(seen, camera, tracer, gxs[pixels], gys[pixels], offsets, batch, progress)
    some_grid = np.zeros((g_height, g_width), np.int64)
    every_grid = np.zeros((g_height, g_width), np.int64)
    some_grid.reshape(-1)[pixels], every_grid.reshape(-1)[pixels] = some, every
    refine = some_grid != every_grid
    padded_some = np.pad(some_grid, k, mode="edge")
    padded_every = np.pad(every_grid, k, mode="edge")
    for dy in range(-k, k + 1):  # a handful of offsets
        for dx in range(-k, k + 1):
            rows, cols = slice(k + dy, k + dy + g_height), slice(k + dx, k + dx + g_width)
            refine |= (padded_some[rows, cols] != some_grid) | (padded_every[rows, cols] != every_grid)
    # Back to the window: the part of the grown rectangle inside it.
    wx0, wy0, wx1, wy1 = max(x0, grown[0]), max(y0, grown[1]), min(x1, grown[2]), min(y1, grown[3])
    if wx1 <= wx0 or wy1 <= wy0:
        return nothing, np.zeros((0, 3)), nothing
    ys_in, xs_in = np.arange(wy0, wy1), np.arange(wx0, wx1)
    inner = ((ys_in - grown[1])[:, None] * g_width + (xs_in - grown[0])[None, :]).reshape(-1)
    drawn_pixels = ((ys_in - y0)[:, None] * (x1 - x0) + (xs_in - x0)[None, :]).reshape(-1)
    coarse = np.zeros((len(gxs), 3))
    coarse[pixels] = means
    drawn = coarse[inner]
    outline = np.flatnonzero(refine.reshape(-1)[inner] & near[inner])
    edge = drawn_pixels[outline]
    index = np.tile(np.arange(OUTLINE_SAMPLES), len(edge))
    u = rng.sobol_2d(settings.seed, settings.frame, rng.STREAM_SEEN_LIGHTS, np.repeat(pixel_global[edge],
                                                                                     OUTLINE_SAMPLES), index)
    fine = filter_offsets(u, filter_width, filter_type).reshape(len(edge), OUTLINE_SAMPLES, 2)
    drawn[outline] = _pixel_means(seen, camera, tracer, gxs[inner[outline]], gys[inner[outline]], fine, batch,
                                  progress)[0]
    if progress is not None:
        progress.advance(len(pixels))
        progress.end_stage()
    return drawn_pixels, drawn, edge
