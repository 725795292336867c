"""A preview PNG of a linear image (sRGB transfer, clipped: Blender's "Standard" view), zlib only."""

from __future__ import annotations

import struct
import zlib

import numpy as np


def linear_to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear float -> (H, W, 3) uint8 with the sRGB transfer function."""
    rgb = np.clip(np.nan_to_num(rgb, nan=0.0), 0.0, 1.0)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def write_png(path, rgb8: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 image, row 0 at the top."""
    height, width, _ = rgb8.shape
    rows = np.concatenate([np.zeros((height, 1), np.uint8), rgb8.reshape(height, width * 3)], axis=1)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    with open(path, "wb") as handle:
        handle.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows.tobytes(), 6))
                     + chunk(b"IEND", b""))
