"""The C heap a render's arrays come from, kept between its batches and given back at its end (glibc).

A render allocates and frees arrays of a few hundred kilobytes to a few tens of megabytes batch after batch
(pass 2's couples, arcs, pieces and their integrals). glibc's malloc gives such blocks back to the system
when they are freed (``munmap``, or trimming the heap's top past M_TRIM_THRESHOLD), so the next batch's
arrays are fresh pages that the kernel must zero on first touch: ``perf`` put 21-29 % of a one-thread render
of suzanne at 512 px in the kernel's page-fault and page-zeroing paths. While a render runs, blocks up to
glibc's largest mmap threshold (32 MiB) come from the heap and up to ``RETAINED_BYTES`` of free heap stay
mapped for the next batch; when the last overlapping render ends, the heap keeps no more free memory at its
top than glibc's own adjustment would (IDLE_RETAINED_BYTES, from its next free on). Measured in
fresh bpy processes on this 2-core machine, with and without it alternating: suzanne at 512 px on one thread
12.9-13.8 -> 10.9-11.6 s (page faults per render 94-259 k -> 35-43 k).

Elsewhere (macOS, Windows, musl) this does nothing. Blender's Linux executable is built with jemalloc
(WITH_MEM_JEMALLOC; the bpy module is not), which keeps freed pages a while by itself: there glibc's
settings go unused and do no harm (not measured here: this machine has the bpy module only).
"""

from __future__ import annotations

import ctypes
import sys
import threading
from contextlib import contextmanager
from typing import Iterator

# mallopt's parameters (malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
# Blocks up to this size come from the heap during a render: glibc's largest mmap threshold on 64-bit.
HEAP_BLOCK_BYTES = 32 * 1024 * 1024
# Free memory at the heap's top kept between renders: what glibc's own adjustment reaches (twice the mmap
# threshold, which it raises to the size of the largest block freed, up to HEAP_BLOCK_BYTES). Setting a
# threshold turns that adjustment off, so the render leaves the thresholds where glibc would have taken them.
IDLE_RETAINED_BYTES = 2 * HEAP_BLOCK_BYTES
# Free memory at the heap's top kept for the next batch: 64 MiB kept most of the faults (suzanne at 512 px,
# one thread, 12.4 s), 256 MiB removed them (11.0 s, as with 4 GiB). At most this share of the render's
# memory budget, which it counts against (the default 2 GB budget keeps 256 MiB).
RETAINED_BYTES = 256 * 1024 * 1024
RETAINED_BUDGET_SHARE = 1 / 8

_lock = threading.Lock()
_users = 0
_libc = None


def _glibc():
    """The process's glibc (its ``mallopt``), or None where malloc is not glibc's."""
    global _libc
    if _libc is None:
        _libc = False
        if sys.platform.startswith("linux"):
            try:
                libc = ctypes.CDLL(None)
                libc.gnu_get_libc_version  # glibc only (musl has mallopt as a stub)
                libc.mallopt.argtypes, libc.mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
                _libc = libc
            except (OSError, AttributeError):
                pass
    return _libc or None


@contextmanager
def retained_heap(memory_budget_mb: float | None = None) -> Iterator[bool]:
    """A context in which freed C-heap memory stays mapped for the next allocation (see the module
    docstring), at most RETAINED_BUDGET_SHARE of ``memory_budget_mb`` (MB; None: RETAINED_BYTES); yields
    whether glibc's malloc was found and set. Renders that overlap share it: the first
    to begin sets it, the last to end lowers the heap's free top to what glibc's own adjustment reaches
    (which any ``mallopt`` turns off for good)."""
    global _users
    libc = _glibc()
    with _lock:
        if libc is not None and _users == 0:
            libc.mallopt(M_MMAP_THRESHOLD, HEAP_BLOCK_BYTES)
            retained = RETAINED_BYTES if memory_budget_mb is None else \
                min(RETAINED_BYTES, int(memory_budget_mb * 2 ** 20 * RETAINED_BUDGET_SHARE))
            libc.mallopt(M_TRIM_THRESHOLD, max(retained, IDLE_RETAINED_BYTES))
        _users += 1
    try:
        yield libc is not None
    finally:
        with _lock:
            _users -= 1
            if libc is not None and _users == 0:
                # No ``malloc_trim`` here: it gave back the pages the next render needs again (the viewport's
                # steps, one after another: boxes at 64 px 20 k page faults a render instead of 3.5 k without
                # this context, 8 % slower); glibc trims the top past the lowered threshold at its next free.
                libc.mallopt(M_TRIM_THRESHOLD, IDLE_RETAINED_BYTES)


def heap_retained() -> bool:
    """Whether a render holds ``retained_heap`` now (for tests)."""
    return _users > 0
