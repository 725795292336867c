"""Pass 2's kernels (``core.kernels``): a render compiles the groups its scene calls, a cold cache is filled by
worker processes under the module names an installed extension has, and a cancel stops them at once."""

import json
import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from lazyvis_addon.core import RenderCancelled
from lazyvis_addon.core.kernel_cache import STAMP_NAME
from lazyvis_addon.core.kernels import GROUPS, OPTIONAL_GROUPS, _compile_in_workers
from lazyvis_addon.core.rng import uniforms

ADDON = Path(__file__).resolve().parents[1] / "lazyvis_addon"

# Renders a scene in a fresh process, then prints the groups its scene needs and the modules of every
# Numba kernel that holds compiled code.
RENDER_AND_LIST = textwrap.dedent("""
    import json, sys
    import numpy as np
    from numba.core.registry import CPUDispatcher
    from lazyvis_addon.core import FacingLights, Settings, render
    from lazyvis_addon.core.demo_scenes import floating_boxes
    from lazyvis_addon.core.kernels import groups_for
    scene = floating_boxes(24, n_boxes=6)
    if sys.argv[1] == "lamp":
        scene.facing = FacingLights.point(np.array([0.0, 0.0, 3.0]), 0.3, 50.0, True)
    render(scene, Settings())
    compiled = sorted({name.split(".")[-1] for name, module in sys.modules.items()
                       if name.startswith("lazyvis_addon.core.")
                       for value in vars(module).values() if isinstance(value, CPUDispatcher) and value.signatures})
    print(json.dumps({"needed": sorted(groups_for(scene)), "compiled": compiled}))
""")


@pytest.mark.parametrize("lights", ["area", "lamp"])
def test_a_render_calls_no_optional_group_its_scene_does_not_need(lights):
    run = subprocess.run([sys.executable, "-c", RENDER_AND_LIST, lights], capture_output=True, text=True,
                         cwd=ADDON.parent, timeout=600)
    assert run.returncode == 0, run.stderr
    listed = json.loads(run.stdout.splitlines()[-1])
    needed, compiled = set(listed["needed"]), set(listed["compiled"])
    assert ("facing" in needed) == (lights == "lamp") and "emitters" not in needed
    for group in OPTIONAL_GROUPS:  # compiled only where needed; where needed, called
        assert (GROUPS[group][0] in compiled) == (group in needed), (group, compiled)


# Imports a copy of the add-on as Blender imports an installed extension (``bl_ext.user_default.lazyvis``),
# compiles the group ``rng`` through ``compile_kernels`` with the interpreter argv 2 ("-": the default), and
# prints whether it compiled, whether this process had to compile (cache misses), its kernel's values and the
# stamps written.
AS_EXTENSION = textwrap.dedent("""
    import importlib, json, sys, types
    import numpy as np
    extensions = sys.argv[1]
    for name, path in (("bl_ext", extensions), ("bl_ext.user_default", extensions + "/user_default")):
        stub = types.ModuleType(name)
        stub.__path__ = [path]
        sys.modules[name] = stub
    kernels = importlib.import_module("bl_ext.user_default.lazyvis.lazyvis_addon.core.kernels")
    rng = importlib.import_module("bl_ext.user_default.lazyvis.lazyvis_addon.core.rng")
    python = None if sys.argv[2] == "-" else sys.argv[2]
    compiled = kernels.compile_kernels(["rng"], workers=1, python=python)
    misses = sum(sum(kernel.stats.cache_misses.values()) for kernel in kernels.compile_groups(["rng"]))
    values = rng.uniforms(3, 1, 2, np.arange(5), np.arange(5), 2).tolist()
    print(json.dumps({"compiled": compiled, "misses": misses, "values": values,
                      "stamped": kernels._stamp_matches("rng")}))
""")


def run_as_extension(extensions: Path, python: str) -> dict:
    run = subprocess.run([sys.executable, "-c", AS_EXTENSION, str(extensions), python], capture_output=True,
                         text=True, timeout=600, env={**os.environ, "PYTHONPATH": ""})
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout.splitlines()[-1])


@pytest.fixture
def installed_copy(tmp_path):
    """A copy of the add-on laid out as an installed extension, with a cold kernel cache."""
    extension = tmp_path / "user_default" / "lazyvis"
    shutil.copytree(ADDON, extension / "lazyvis_addon", ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path, extension / "lazyvis_addon" / "core" / "__pycache__"


def test_a_cold_cache_is_filled_by_a_worker_under_the_extension_s_module_names(installed_copy):
    extensions, cache = installed_copy
    expected = uniforms(3, 1, 2, np.arange(5), np.arange(5), 2).tolist()
    first = run_as_extension(extensions, "-")
    # The worker compiled: this process only loaded (no miss), and its kernel computes what ours does.
    assert first == {"compiled": True, "misses": 0, "values": expected, "stamped": True}
    assert any(cache.glob("rng._uniforms-*.nbi")) and (cache / STAMP_NAME).is_file()
    # A stamped group starts no worker (an interpreter that cannot run would fail it) and loads from the cache.
    again = run_as_extension(extensions, "/nonexistent/python")
    assert again == {"compiled": False, "misses": 0, "values": expected, "stamped": True}


def test_a_worker_that_fails_leaves_its_groups_to_the_render_s_process(installed_copy):
    extensions, cache = installed_copy
    failed = run_as_extension(extensions, shutil.which("false") or "/bin/false")
    assert failed["compiled"] and failed["misses"] > 0  # compiled here, as without workers
    assert failed["values"] == uniforms(3, 1, 2, np.arange(5), np.arange(5), 2).tolist()
    assert failed["stamped"]  # Numba cached what this process compiled: no worker the next time


def _children() -> set[int]:
    pids = set()
    for task in Path(f"/proc/{os.getpid()}/task").iterdir():
        pids.update(int(pid) for pid in (task / "children").read_text().split())
    return pids


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="lists child processes through Linux's /proc")
def test_a_cancel_kills_the_workers_at_once():
    before = _children()
    start = time.perf_counter()

    def cancel_after_a_moment():
        if time.perf_counter() - start > 0.2:
            raise RenderCancelled("render cancelled")

    with pytest.raises(RenderCancelled):  # a worker takes seconds to start Numba and load a group
        _compile_in_workers(["arrangement", "detection"], 2, cancel_after_a_moment, sys.executable)
    assert time.perf_counter() - start < 0.5
    assert _children() == before  # killed and waited for
