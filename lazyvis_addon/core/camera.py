"""Camera rays through pixel centres of the rendered window."""

from __future__ import annotations

import numpy as np

from .scene import Camera


def window_pixels(camera: Camera, window=None) -> tuple[np.ndarray, np.ndarray]:
    """Full-frame coordinates of a window's pixels in row-major order (row 0 = top).

    window : (x0, y0, x1, y1) or None for the camera's own window.

    Returns
    -------
    x, y : (N,) int64 with N = H * W of the window.
    """
    x0, y0, x1, y1 = camera.window if window is None else window
    ys, xs = np.mgrid[y0:y1, x0:x1]
    return xs.reshape(-1).astype(np.int64), ys.reshape(-1).astype(np.int64)


def pixel_coordinates(camera: Camera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Full-frame coordinates x, y (P,) int64 of window-local pixels (P,) (row-major indices into the
    camera's window): ``window_pixels``' entries at ``pixels``, without the whole window's grid."""
    x0, y0, x1, _ = camera.window
    rows, columns = np.divmod(np.asarray(pixels, dtype=np.int64), x1 - x0)
    return columns + x0, rows + y0


def camera_rays(camera: Camera, x: np.ndarray, y: np.ndarray, offset: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """World-space rays through points of full-frame pixels.

    Parameters
    ----------
    x, y : (N,) int64      full-frame pixel coordinates (y down from the top row).
    offset : (N, 2) float64 or None
        Position inside the pixel in [0, 1)^2; None means the pixel centre.

    Returns
    -------
    origins : (N, 3) float64 on the camera's clip-start plane (Cycles starts camera rays there),
    directions : (N, 3) float64 unit.
    """
    fx = x + (0.5 if offset is None else offset[:, 0])
    fy = y + (0.5 if offset is None else offset[:, 1])
    left, right, bottom, top = camera.screen_window
    sx = left + fx / camera.width * (right - left)
    sy = top - fy / camera.height * (top - bottom)
    rotation = camera.world_from_camera[:3, :3]
    position = camera.world_from_camera[:3, 3]
    if camera.projection == "perspective":
        local = np.stack([sx, sy, -np.ones_like(sx)], axis=1)
        directions = local @ rotation.T
        origins = np.broadcast_to(position, directions.shape).copy()
    else:
        local = np.stack([sx, sy, np.zeros_like(sx)], axis=1)
        origins = local @ rotation.T + position
        directions = np.broadcast_to(-rotation[:, 2], origins.shape).copy()
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    if camera.clip_start > 0:
        origins += directions * (camera.clip_start / (directions @ -rotation[:, 2]))[:, None]
    return origins, directions


def clip_distance(camera: Camera, directions: np.ndarray) -> np.ndarray | None:
    """How far camera rays (unit ``directions`` (N, 3), from ``camera_rays``) go before the clip-end plane:
    (N,) float64, or None when the camera does not clip (clip_end infinite)."""
    if not np.isfinite(camera.clip_end):
        return None
    forward = -camera.world_from_camera[:3, 2]
    forward = forward / np.linalg.norm(forward)
    return (camera.clip_end - camera.clip_start) / (directions @ forward)


def planar_depth(camera: Camera, points: np.ndarray) -> np.ndarray:
    """Distance of world points in front of the camera along its viewing axis (N,) float64."""
    forward = -camera.world_from_camera[:3, 2]
    forward = forward / np.linalg.norm(forward)
    return (points - camera.world_from_camera[:3, 3]) @ forward
