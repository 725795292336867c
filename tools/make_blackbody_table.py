"""Regenerate ``lazyvis_addon/core/data/blackbody.npz``: Blender's blackbody colour, tabulated.

    .venv/bin/python tools/make_blackbody_table.py        # a second, through bpy

Cycles' Blackbody node and a light's Temperature colour are one function of the temperature (measured
with Cycles 5.0.1: an Emission fed by a Blackbody node, seen by the camera at 1 sample, equals
``Light.temperature_color`` at 800, 1500, 2700, 4000, 6500, 9000 and 15000 K to 5 digits): linear
Rec. 709 RGB normalised to luminance 1, constant above 12000 K and below 800 K. Bpy exposes it only as a
light's ``temperature_color``, which the exporter cannot write to while rendering, so it is tabulated here
on 1024 temperatures evenly spaced in log T over [800, 12000] K; ``core.blackbody`` interpolates linearly
in log T. Measured against Blender at 3000 random temperatures: 99 % within 1e-6 of the largest
channel, the rest within one table spacing of the function's own jumps (Blender's fit is piecewise and
steps at about 1903, 3316, 6365 and 11982 K), at most 8e-4 there.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUTPUT = ROOT / "lazyvis_addon" / "core" / "data" / "blackbody.npz"
LOW, HIGH, POINTS = 800.0, 12000.0, 1024


def blender_blackbody(temperatures: np.ndarray) -> np.ndarray:
    """(N, 3) float64 Blender's blackbody colour at ``temperatures`` (N,) kelvin, through a scratch light."""
    import bpy
    light = bpy.data.lights.new("lazyvis_blackbody", "AREA")
    try:
        light.use_temperature = True
        out = np.empty((len(temperatures), 3))
        for row, temperature in enumerate(temperatures):  # a thousand property reads
            light.temperature = float(temperature)
            out[row] = light.temperature_color[:3]
        return out
    finally:
        bpy.data.lights.remove(light)


def main() -> int:
    temperature = np.geomspace(LOW, HIGH, POINTS)
    rgb = blender_blackbody(temperature)
    np.savez_compressed(OUTPUT, temperature=temperature, rgb=rgb)
    print(f"wrote {OUTPUT.relative_to(ROOT)}: {POINTS} temperatures, {LOW:.0f}-{HIGH:.0f} K")
    return 0


if __name__ == "__main__":
    sys.exit(main())
