"""Pass 2's compiled kernels: their groups, the groups a scene needs, and their first compile.

Numba compiles a kernel on its first call and keeps it in its on-disk cache (``kernel_cache`` drops that
cache when a source changes); later renders load it in milliseconds. Compiling every group took 73 s on
this 2-core machine (2026-12-07, one process: the arrangement 15.0 s, detection 12.7, emitters 10.4, regions
9.8, ...), all of it at a user's first render. Two things shorten that wait:

- a render compiles only the groups its scene needs (``groups_for``): mesh emitters' and lamps' kernels only
  when the scene has them (the rest would still compile on a first call, just unannounced);
- on a cold cache the groups are compiled by worker processes, one per core (up to four), each writing
  Numba's cache, which this process then reads. Numba compiles under one global lock, so threads cannot
  share the work; processes can. A worker that cannot start or fails leaves its groups to this process
  (as before: slower, never wrong), and a cancel kills the workers at once.

A group compiled into the cache (by a worker or by this process) is marked by a stamp file beside Numba's
cache (``__pycache__``) naming Numba's version, Python's and the CPU (``kernel_cache`` deletes the stamps
with the cache when a source changes): a stamp that matches means the cache holds the group, so no worker
is started. Measured on this 2-core machine, a first
render of the floating boxes: 74.6 s before (every group, one process), 27-31 s after (two workers); on
more cores the wait is bounded by the largest group (the arrangement's ``_fans``, 15 s here).
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import time
from functools import lru_cache
from pathlib import Path
from typing import Callable, Iterable

from .kernel_cache import GROUP_STAMPS as STAMP_PATTERN

# Group name -> (module of the core, its compile function, seconds it took to compile on this machine's cold
# cache, 2026-12-07: the weights that share groups out among workers).
GROUPS: dict[str, tuple[str, str, float]] = {
    "arrangement": ("arrangement", "compile_arrangement", 15.0),
    "detection": ("detection", "compile_detection", 12.7),
    "regions": ("regions", "compile_regions", 9.8),
    "illumination": ("illumination", "compile_illumination", 5.9),
    "silhouettes": ("silhouettes", "compile_silhouettes", 4.3),
    "edge_tree": ("edge_tree", "compile_edge_tree", 3.7),
    "terminator": ("terminator", "compile_terminator", 3.7),
    "geometry": ("geometry", "compile_geometry", 2.3),
    "rng": ("rng", "compile_rng", 1.3),
    "antialias": ("antialias", "compile_antialias", 0.6),
    "ggx": ("ggx", "compile_ggx", 0.3),
    "facing": ("facing", "compile_facing", 3.0),
    "emitters": ("emitters", "compile_emitters", 10.4),
}
# Groups only some scenes need (``groups_for``): point / spot / sun lamps, mesh emitters.
OPTIONAL_GROUPS = frozenset({"facing", "emitters"})
_PACKAGE = Path(__file__).resolve().parent
# A worker: import this module under this process's own name (argv 1; an installed extension's is
# ``bl_ext.<repository>.lazyvis.lazyvis_addon.core.kernels``), its packages above ``lazyvis_addon`` stubs
# over the folders above argv 2 (the folder holding ``lazyvis_addon``), then compile the groups it is given.
# Numba's cached code records its module's name (for the kernel's globals): under the same name, what a
# worker caches is what this process would have compiled.
_WORKER_CODE = """
import importlib, pathlib, sys, types
name, folder = sys.argv[1], pathlib.Path(sys.argv[2])
above = name.split(".")[:-3]
for depth in range(len(above), 0, -1):
    stub = types.ModuleType(".".join(above[:depth]))
    stub.__path__ = [str(folder)]
    sys.modules[stub.__name__] = stub
    folder = folder.parent
importlib.import_module(name).compile_groups(sys.argv[3:])
"""
_POLL_SECONDS = 0.05
# At most this many workers: with four the largest group (the arrangement, a quarter of the work) already
# bounds the wait, and each worker holds its own Numba and LLVM (about 200 MB).
MAX_WORKERS = 4


def groups_for(scene=None) -> frozenset[str]:
    """The groups a render of ``scene`` (a ``Scene``; None: every group) calls."""
    if scene is None:
        return frozenset(GROUPS)
    needed = set(GROUPS) - OPTIONAL_GROUPS
    if len(scene.facing):
        needed.add("facing")
    if len(scene.hulls):
        needed.add("emitters")
    return frozenset(needed)


def compile_groups(names: Iterable[str]) -> list:
    """Compile the named groups in this process (or load them from Numba's cache); returns their kernels
    (Numba dispatchers), flattened."""
    kernels = []
    for name in names:
        module, function, _ = GROUPS[name]
        made = getattr(importlib.import_module(f"{__package__}.{module}"), function)()
        kernels.extend(made)
    return kernels


def compile_kernels(groups: Iterable[str] | None = None, check_cancel: Callable[[], None] | None = None,
                    workers: int | None = None, python: str | None = None) -> bool:
    """Make the ``groups`` (default: all) ready, the door the render's stage *Compiling kernels* goes
    through. Groups whose stamp does not match are first compiled by up to ``workers`` processes (default:
    one per core, at most MAX_WORKERS; 0: none, this process compiles) run by ``python`` (default: this
    interpreter), while
    ``check_cancel`` is called every 50 ms (what it raises kills the workers and is raised here). Then
    this process loads every group. Returns whether any kernel had to be compiled, here or by a worker."""
    names = sorted(set(GROUPS) if groups is None else set(groups), key=lambda name: -GROUPS[name][2])
    cold = [name for name in names if not _stamp_matches(name)]
    compiled_by_workers = False
    if cold:
        count = min(os.cpu_count() or 1, MAX_WORKERS) if workers is None else workers
        if count > 0 and _cache_writable():
            compiled_by_workers = _compile_in_workers(cold, count, check_cancel, python or _interpreter())
    kernels = compile_groups(names)
    compiled_here = any(kernel.stats.cache_misses for kernel in kernels)
    if cold and _cache_writable():  # Numba's cache beside the sources holds them now
        for name in cold:
            _write_stamp(name)
    return compiled_by_workers or compiled_here


def _compile_in_workers(names: list[str], count: int, check_cancel, python: str | None) -> bool:
    """Share ``names`` out among ``count`` worker processes, longest first to the least loaded; wait for
    them. Returns whether any finished (its groups then stamped); a failed one is left to this process."""
    if python is None:
        return False
    shares: list[list[str]] = [[] for _ in range(min(count, len(names)))]
    loads = [0.0] * len(shares)
    for name in names:  # sorted longest first
        least = loads.index(min(loads))
        shares[least].append(name)
        loads[least] += GROUPS[name][2]
    root = _PACKAGE.parents[1]  # the folder holding lazyvis_addon
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(root), *[path for path in sys.path if path]])
    env["NUMBA_NUM_THREADS"] = "1"
    running = []
    try:
        for share in shares:
            try:
                process = subprocess.Popen([python, "-c", _WORKER_CODE, __name__, str(root), *share], env=env,
                                           cwd=str(root), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                           stderr=subprocess.DEVNULL)
            except OSError:
                continue
            running.append((process, share))
        finished = False
        while running:
            for process, share in list(running):
                code = process.poll()
                if code is None:
                    continue
                running.remove((process, share))
                if code == 0:
                    for name in share:
                        _write_stamp(name)
                    finished = True
            if check_cancel is not None:
                check_cancel()
            if running:
                time.sleep(_POLL_SECONDS)
        return finished
    finally:
        for process, _ in running:  # a cancel, or anything raised while waiting
            process.kill()
            process.wait()


def _interpreter() -> str | None:
    """A Python interpreter to run workers: this one's, where it is one (Blender's ``sys.executable`` is its
    bundled Python; anything else, such as an embedding program, gets no workers)."""
    executable = sys.executable
    if executable and Path(executable).name.lower().startswith("python") and Path(executable).is_file():
        return executable
    return None


def _cache_dir() -> Path:
    return _PACKAGE / "__pycache__"


def _cache_writable() -> bool:
    """Numba caches beside the sources only where it may write (else in a per-user folder, whose
    stamps this module does not keep: it then compiles in-process, as before)."""
    cache = _cache_dir()
    if os.environ.get("NUMBA_CACHE_DIR"):
        return False
    try:
        cache.mkdir(exist_ok=True)
    except OSError:
        return False
    return os.access(cache, os.W_OK)


@lru_cache(maxsize=1)
def _stamp_key() -> str:
    """What a group's compiled code depends on besides its name and the sources (a change of those deletes the
    stamps with the cache: ``kernel_cache``): Numba, Python and the CPU."""
    import llvmlite.binding
    import numba

    return "\n".join([numba.__version__, sys.version.split()[0],
                      os.environ.get("NUMBA_CPU_NAME") or llvmlite.binding.get_host_cpu_name(),
                      os.environ.get("NUMBA_CPU_FEATURES", "")]) + "\n"


def _stamp_path(name: str) -> Path:
    return _cache_dir() / STAMP_PATTERN.replace("*", name)


def _stamp_matches(name: str) -> bool:
    try:
        return _stamp_path(name).read_text() == _stamp_key()
    except OSError:
        return False


def _write_stamp(name: str) -> None:
    try:
        _stamp_path(name).write_text(_stamp_key())
    except OSError:
        pass
