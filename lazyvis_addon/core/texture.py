"""Image textures for the base colour, looked up the way Cycles does it, and per-corner attributes.

Conventions (Blender's, checked against Cycles 5.0.1 renders in tests/test_texture.py):

- Texels are stored in Blender's ``image.pixels`` order: ``texels[row, col]`` with **row 0 the bottom
  row**, so UV (0, 0) is the image's bottom-left corner and (1, 1) its top-right; texel (col, row) covers
  ``[col / W, (col + 1) / W) x [row / H, (row + 1) / H)`` and its centre is ``((col + 0.5) / W,
  (row + 0.5) / H)``.
- Closest: the texel containing the point, ``floor(u W)``.
- Linear: bilinear between the four texel centres around the point: ``x = u W - 0.5``,
  ``i = floor(x)``, weight ``x - i`` on texel ``i + 1``.
- Extension: REPEAT (periodic), EXTEND (clamp to the edge texel), CLIP (every texel outside the image
  reads as transparent black, RGBA = 0, so Linear fades to half the edge texel exactly on the border and
  reaches 0 half a texel outside), MIRROR (period 2W, edge texels repeated: ..., 1, 0 | 0, 1, ...).
- Colour: Cycles keeps an image whose colour space is sRGB **sRGB-encoded** and decodes after
  interpolating (``compress_as_srgb`` in ``scene/image.cpp``, decode in ``kernel/svm/image.h``); other
  supported spaces are linear and used as they are. So a Linear lookup halfway between a black and a
  white sRGB texel is ``srgb_to_linear(0.5) = 0.214``, not 0.5. ``texels`` hold what Cycles
  interpolates; ``linear_pixels`` gives the decoded image.
- Alpha: colour is associated (premultiplied) at load in the stored encoding, as Cycles does, unless
  the image is Non-Color or its alpha mode is CHANNEL_PACKED or NONE (NONE also sets alpha to 1).
  ``lookup`` returns what the Image Texture node's Color socket gives when its Alpha socket is not linked
  (associated colour).

Cycles' source (blender/blender, intern/cycles): ``kernel/device/cpu/image.h`` (``interp_closest``,
``interp_linear``, ``wrap_periodic``/``wrap_clamp``/``wrap_mirror``, ``read_clip`` returning
``zero_float4()``), ``util/color.h`` (``color_srgb_to_linear``: ``c / 12.92`` below 0.04045, negative
values to 0, else ``((c + 0.055) / 1.055)^2.4``; alpha untouched), ``scene/colorspace.cpp`` and
``scene/image.cpp`` (which spaces count as sRGB or linear), ``blender/image.cpp`` (byte images
premultiplied as ``c * a / 255`` in integers; float images arrive already in scene linear).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

INTERPOLATIONS = ("Closest", "Linear")
EXTENSIONS = ("REPEAT", "EXTEND", "CLIP", "MIRROR")
ALPHA_MODES = ("STRAIGHT", "PREMUL", "CHANNEL_PACKED", "NONE")

# Blender colour space names (Blender 5.0 OCIO config) by how Cycles treats them.
SRGB_SPACES = ("sRGB",)
LINEAR_SPACES = ("Linear Rec.709", "scene_linear", "Non-Color")
DATA_SPACES = ("Non-Color",)


def srgb_to_linear(encoded) -> np.ndarray:
    """The exact sRGB decoding curve as Cycles applies it: (...) -> (...) float64, negatives to 0."""
    c = np.asarray(encoded, dtype=np.float64)
    low = np.maximum(c, 0.0) / 12.92
    high = np.power((np.maximum(c, 0.04045) + 0.055) / 1.055, 2.4)
    return np.where(c < 0.04045, low, high)


def linear_to_srgb(linear) -> np.ndarray:
    """The exact sRGB encoding curve: (...) -> (...) float64, negatives to 0."""
    c = np.asarray(linear, dtype=np.float64)
    low = np.maximum(c, 0.0) * 12.92
    high = 1.055 * np.power(np.maximum(c, 0.0031308), 1.0 / 2.4) - 0.055
    return np.where(c < 0.0031308, low, high)


@dataclass(frozen=True)
class ImageTexture:
    """An image for the base colour, sampled like Cycles' Image Texture node (flat projection).

    Attributes
    ----------
    texels : (H, W, 4) float32   RGBA, row 0 = bottom row, colour associated with alpha (unless data or
                                 channel-packed), in the encoding Cycles interpolates in: sRGB-encoded when
                                 ``srgb``, scene-linear otherwise.
    srgb : bool                  decode the sRGB curve after interpolation.
    interpolation : str          "Closest" or "Linear" (Blender's identifiers).
    extension : str              "REPEAT", "EXTEND", "CLIP" or "MIRROR".
    """

    texels: np.ndarray
    srgb: bool = False
    interpolation: str = "Linear"
    extension: str = "REPEAT"

    def __post_init__(self):
        if self.texels.ndim != 3 or self.texels.shape[2] != 4 or min(self.texels.shape[:2]) < 1:
            raise ValueError(f"texels must be (H, W, 4) with H, W >= 1, got {self.texels.shape}")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation {self.interpolation!r} not supported; expected one of {INTERPOLATIONS}")
        if self.extension not in EXTENSIONS:
            raise ValueError(f"extension {self.extension!r} not supported; expected one of {EXTENSIONS}")

    @classmethod
    def from_pixels(cls, pixels: np.ndarray, colorspace: str = "sRGB", interpolation: str = "Linear",
                    extension: str = "REPEAT", alpha_mode: str = "STRAIGHT",
                    top_row_first: bool = False) -> "ImageTexture":
        """Build a texture from an image's pixels as Blender holds them.

        Parameters
        ----------
        pixels : (H, W, C) float (any precision) or uint8, C in 1..4
            Values in the image's own colour space: Blender's ``image.pixels`` reshaped to (H, W, C)
            (bottom row first), or uint8 bytes of an 8-bit image (premultiplied exactly as Cycles does
            for byte images). Missing channels: grey for C = 1, blue 0 and alpha 1 as Cycles fills them.
        colorspace : str       ``image.colorspace_settings.name``; SRGB_SPACES or LINEAR_SPACES. Float
                               images from Blender are already scene-linear: pass "Linear Rec.709".
        interpolation, extension : see the class attributes.
        alpha_mode : str       ``image.alpha_mode``, one of ALPHA_MODES.
        top_row_first : bool   the rows are in file order (top first), e.g. from a PNG or EXR reader.

        Raises
        ------
        ValueError  unsupported colour space, alpha mode, shape, interpolation or extension.
        """
        if colorspace not in SRGB_SPACES + LINEAR_SPACES:
            raise ValueError(f"colour space {colorspace!r} not supported; expected one of "
                             f"{SRGB_SPACES + LINEAR_SPACES}")
        if alpha_mode not in ALPHA_MODES:
            raise ValueError(f"alpha mode {alpha_mode!r} not supported; expected one of {ALPHA_MODES}")
        pixels = np.asarray(pixels)
        if pixels.ndim == 2:
            pixels = pixels[:, :, None]
        if pixels.ndim != 3 or not 1 <= pixels.shape[2] <= 4:
            raise ValueError(f"pixels must be (H, W, C) with C in 1..4, got {pixels.shape}")
        if top_row_first:
            pixels = pixels[::-1]
        is_byte = pixels.dtype == np.uint8
        rgba = _expand_channels(pixels.astype(np.int64) if is_byte else pixels.astype(np.float64),
                                255 if is_byte else 1.0)
        if alpha_mode == "NONE":
            rgba[..., 3] = 255 if is_byte else 1.0
        associate = alpha_mode == "STRAIGHT" and colorspace not in DATA_SPACES
        if associate:
            if is_byte:
                rgba[..., :3] = rgba[..., :3] * rgba[..., 3:] // 255
            else:
                rgba[..., :3] *= rgba[..., 3:]
        texels = rgba / 255.0 if is_byte else rgba
        return cls(np.ascontiguousarray(texels, dtype=np.float32), colorspace in SRGB_SPACES, interpolation,
                   extension)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in texels."""
        return self.texels.shape[0], self.texels.shape[1]

    @property
    def linear_pixels(self) -> np.ndarray:
        """(H, W, 4) float32 scene-linear RGBA (row 0 = bottom): what Closest returns at texel centres."""
        if not self.srgb:
            return self.texels
        decoded = self.texels.astype(np.float64)
        decoded[..., :3] = srgb_to_linear(decoded[..., :3])
        return decoded.astype(np.float32)

    def lookup(self, uv: np.ndarray) -> np.ndarray:
        """Sample the texture.

        Parameters
        ----------
        uv : (N, 2) float64    texture coordinates (u right, v up); any real values, wrapped by ``extension``.

        Returns
        -------
        (N, 4) float64 scene-linear RGBA (colour associated with alpha); rows with a non-finite UV are 0.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        height, width = self.shape
        finite = np.isfinite(uv).all(axis=1)
        u = np.where(finite, uv[:, 0], 0.0) * width
        v = np.where(finite, uv[:, 1], 0.0) * height
        if self.interpolation == "Closest":
            result = self._read(np.floor(u).astype(np.int64), np.floor(v).astype(np.int64))
        else:
            u, v = u - 0.5, v - 0.5
            i, j = np.floor(u), np.floor(v)
            tx, ty = (u - i)[:, None], (v - j)[:, None]
            i, j = i.astype(np.int64), j.astype(np.int64)
            result = ((1.0 - ty) * ((1.0 - tx) * self._read(i, j) + tx * self._read(i + 1, j))
                      + ty * ((1.0 - tx) * self._read(i, j + 1) + tx * self._read(i + 1, j + 1)))
        if self.srgb:
            result[:, :3] = srgb_to_linear(result[:, :3])
        result[~finite] = 0.0
        return result

    def _read(self, col: np.ndarray, row: np.ndarray) -> np.ndarray:
        """Texels at integer (N,) columns and rows outside or inside the image, per ``extension``: (N, 4)."""
        height, width = self.shape
        if self.extension == "CLIP":
            inside = (col >= 0) & (col < width) & (row >= 0) & (row < height)
            values = self.texels[np.clip(row, 0, height - 1), np.clip(col, 0, width - 1)].astype(np.float64)
            values[~inside] = 0.0
            return values
        if self.extension == "REPEAT":
            col, row = np.mod(col, width), np.mod(row, height)
        elif self.extension == "EXTEND":
            col, row = np.clip(col, 0, width - 1), np.clip(row, 0, height - 1)
        else:  # MIRROR
            col, row = _mirror(col, width), _mirror(row, height)
        return self.texels[row, col].astype(np.float64)


def _mirror(index: np.ndarray, size: int) -> np.ndarray:
    """Reflect integer indices with period 2 * size, repeating the edge texel (Cycles' wrap_mirror)."""
    m = np.mod(np.abs(index + (index < 0)), 2 * size)
    return np.where(m >= size, 2 * size - m - 1, m)


def _expand_channels(pixels: np.ndarray, one) -> np.ndarray:
    """(H, W, C) -> (H, W, 4) copy, filling channels as Cycles' loaders do (grey, blue 0, alpha ``one``)."""
    height, width, channels = pixels.shape
    rgba = np.zeros((height, width, 4), dtype=pixels.dtype)
    if channels == 1:
        rgba[..., :3] = pixels
    else:
        rgba[..., :channels] = pixels
    if channels < 4:
        rgba[..., 3] = one
    return rgba


def interpolate_corner_attribute(corner_values: np.ndarray, index_triangle: np.ndarray, u: np.ndarray,
                                 v: np.ndarray) -> np.ndarray:
    """A per-triangle-corner attribute (UVs, colours) at points given by barycentrics.

    Parameters
    ----------
    corner_values : (T, 3, D) float   the attribute at each triangle's three corners, in the corner order
                                      of ``scene.triangles``.
    index_triangle : (N,) int64       triangle of each point, -1 for none.
    u, v : (N,) float64               barycentrics with the convention of ``surface.shade_hits``:
                                      point = (1 - u - v) c0 + u c1 + v c2.

    Returns
    -------
    (N, D) float64, zero where ``index_triangle`` is -1.
    """
    corner_values = np.asarray(corner_values, dtype=np.float64)
    index_triangle = np.asarray(index_triangle)
    hit = index_triangle >= 0
    corners = corner_values[np.where(hit, index_triangle, 0)] if len(corner_values) else \
        np.zeros((len(index_triangle), 3, corner_values.shape[-1]))
    u = np.asarray(u, dtype=np.float64)[:, None]
    v = np.asarray(v, dtype=np.float64)[:, None]
    values = (1.0 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]
    return np.where(hit[:, None], values, 0.0)
