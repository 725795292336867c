"""Numba's on-disk kernel cache, dropped when any source of the core changes.

Numba keys a cached kernel on its own file's time stamp and size only, but our kernels inline helpers from
other modules (``detection._detect`` inlines ``arcs.arc_test``, ``regions._region_arcs`` inlines
``arcs._cone_range``): after an edit of ``arcs.py`` alone, ``_detect`` was loaded from the cache with the
old helper inside, and renders were silently wrong (measured here: a developer's experiment left 4,162
inconsistent couples in suzanne_dense3 at 512 px until the cache was deleted). Installed add-ons never change
their sources; a working copy does. So at import, a digest of every ``core/*.py`` is compared with the one
the cache was built from, and the cache files are deleted when they differ.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

STAMP_NAME = "lazyvis_sources.sha1"
GROUP_STAMPS = "lazyvis_kernels_*.ok"  # ``kernels``' marks of groups compiled into this cache


def sources_digest(package: Path) -> str:
    """SHA-1 (hex) of the names and bytes of every ``*.py`` in ``package``, in name order."""
    digest = hashlib.sha1()
    for source in sorted(package.glob("*.py")):
        digest.update(source.name.encode())
        digest.update(source.read_bytes())
    return digest.hexdigest()


def drop_stale_kernels(package: Path) -> bool:
    """Delete Numba's cache files (``*.nbi``, ``*.nbc``) and ``kernels``' group stamps in
    ``package/__pycache__`` when the sources' digest differs from the one stored there, and store the new
    one. Returns whether files were dropped. A cache folder that cannot be read or written is left alone
    (Numba then caches elsewhere or not at all)."""
    cache = package / "__pycache__"
    stamp = cache / STAMP_NAME
    try:
        current = sources_digest(package)
        if stamp.is_file() and stamp.read_text().strip() == current:
            return False
        stale = [*cache.glob("*.nbi"), *cache.glob("*.nbc"), *cache.glob(GROUP_STAMPS)] if cache.is_dir() else []
        for path in stale:
            path.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        stamp.write_text(current + "\n")
        return bool(stale)
    except OSError:
        return False
