"""Convert the published GGX LTC fit (Heitz, Dupuy, Hill, Neubelt 2016) into ``lazyvis_addon/core/data/ltc_ggx.npz``.

The fitted tables are the ones distributed with the paper's code (selfshadow/ltc_code,
``fit/results/ltc.js``) and redistributed verbatim by three.js in
``examples/jsm/lights/RectAreaLightTexturesLib.js``. Get that file from the npm registry and run:

    npm pack three@0.187.0 && tar -xzf three-0.187.0.tgz
    .venv/bin/python tools/import_ltc_tables.py package/examples/jsm/lights/RectAreaLightTexturesLib.js

Layout of the two 64 x 64 RGBA textures (row-major, 64 texels per row):

- texel (j, i): roughness r = i / 63 (α = r²), view parameter sqrt(1 - cos θ_o) = j / 63;
- ``LTC_MAT_1`` = (a, b, c, d): the inverse transform in the frame (T1, T2, N) is
  M⁻¹ = [[a, 0, c], [0, 1, 0], [b, 0, d]] (scaled so that its middle entry is 1);
- ``LTC_MAT_2`` = (norm, fresnel, 0, unused): norm = ∫ f cos θ_i dω_i (the lobe's albedo without Fresnel)
  and fresnel = ∫ f cos θ_i (1 - ω_o · h)^5 dω_i, so that ∫ f cos θ_i F_Schlick = f0 (norm - fresnel)
  + f90 fresnel.

The numbers are stored unchanged (float32 values held as float64); see ``core/data/README.md`` for the
licence notices that travel with them.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUTPUT = ROOT / "lazyvis_addon" / "core" / "data" / "ltc_ggx.npz"
SIZE = 64


def parse_array(source: str, name: str) -> np.ndarray:
    """The numbers of ``const NAME = [ ... ];`` in a JavaScript source, as float32 (what WebGL receives)."""
    match = re.search(rf"const\s+{name}\s*=\s*\[(.*?)\];", source, re.S)
    if match is None:
        raise ValueError(f"{name} not found")
    text = re.sub(r"-\s+", "-", match.group(1))  # the file writes some negatives as "- 4.4e-05"
    values = np.array([float(v) for v in text.split(",") if v.strip()], dtype=np.float32)
    if values.size != SIZE * SIZE * 4:
        raise ValueError(f"{name} has {values.size} numbers, expected {SIZE * SIZE * 4}")
    return values.reshape(SIZE, SIZE, 4)


def main(path: str) -> None:
    source = Path(path).read_text()
    inverse = parse_array(source, "LTC_MAT_1").astype(np.float64)
    magnitude = parse_array(source, "LTC_MAT_2").astype(np.float64)[..., :2]
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUTPUT, inverse_matrix=inverse, magnitude=magnitude)
    print(f"wrote {OUTPUT}: inverse_matrix {inverse.shape}, magnitude {magnitude.shape}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
