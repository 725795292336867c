import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# Without bpy the Blender tests (a third of the suite) would skip and the run still pass: CI and `make test`
# install it (the dev extras), so its absence is an error unless asked for by name.
ALLOW_NO_BPY = "LAZYVIS_ALLOW_NO_BPY"


def pytest_sessionstart(session):
    if importlib.util.find_spec("bpy") is None and not os.environ.get(ALLOW_NO_BPY):
        raise pytest.UsageError(
            "bpy (Blender as a Python module, bpy==5.0.1) is not installed, so the Blender tests would be skipped: "
            f"install the dev extras (`make test` does), or set {ALLOW_NO_BPY}=1 to run without them")


@pytest.fixture
def np_rng():
    return np.random.default_rng(12345)
