"""The kernel cache is dropped when a source of the core changes (``core.kernel_cache``)."""

from lazyvis_addon.core.kernel_cache import STAMP_NAME, drop_stale_kernels


def test_cached_kernels_are_dropped_when_any_source_changes_and_kept_otherwise(tmp_path):
    (tmp_path / "detection.py").write_text("def f(): pass\n")
    helper = tmp_path / "arcs.py"
    helper.write_text("def g(): return 1\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    kernel = [cache / "detection._detect-1.py311.nbi", cache / "detection._detect-1.py311.1.nbc",
              cache / "lazyvis_kernels_detection.ok"]  # and ``kernels``' mark of the group
    for path in kernel:
        path.write_bytes(b"compiled")
    assert drop_stale_kernels(tmp_path)                      # no stamp yet: built from unknown sources
    assert not any(path.exists() for path in kernel) and (cache / STAMP_NAME).is_file()
    for path in kernel:                                     # compiled again from these sources
        path.write_bytes(b"compiled")
    assert not drop_stale_kernels(tmp_path)                  # same sources: kept
    assert all(path.exists() for path in kernel)
    helper.write_text("def g(): return 2\n")                # an inlined helper's module changes
    assert drop_stale_kernels(tmp_path)
    assert not any(path.exists() for path in kernel)
    assert (tmp_path / "detection.py").exists() and helper.exists()
