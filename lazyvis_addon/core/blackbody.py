"""Blender's blackbody colour (the Blackbody node's and a light's Temperature), from a table.

Linear Rec. 709 RGB of luminance 1, as Cycles 5.0.1 renders it; tabulated from Blender by
``tools/make_blackbody_table.py`` (see ``data/README.md``), interpolated linearly in log T.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

TABLE = Path(__file__).with_name("data") / "blackbody.npz"


@lru_cache(maxsize=1)
def _table() -> tuple[np.ndarray, np.ndarray]:
    with np.load(TABLE) as data:
        return np.log(data["temperature"]), np.asarray(data["rgb"], np.float64)


def blackbody_rgb(temperature) -> np.ndarray:
    """RGB (..., 3) float64 of a blackbody at ``temperature`` (kelvin, any shape): Blender's colour, constant
    below 800 K and above 12000 K as Blender's is; NaN for a NaN temperature."""
    log_t, rgb = _table()
    t = np.asarray(temperature, np.float64)
    # np.interp holds the end values outside the table: Blender's function is flat there too.
    x = np.log(np.clip(t, np.exp(log_t[0]), np.exp(log_t[-1])))
    out = np.stack([np.interp(x, log_t, rgb[:, k]) for k in range(3)], axis=-1)
    return np.where(np.isnan(t)[..., None], np.nan, out)
