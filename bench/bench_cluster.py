"""Cluster benchmark (issue 18): one frame on a Dask cluster of 1 and of 2 single-threaded workers.

    .venv/bin/python bench/bench_cluster.py [--blend sample_blends/floating_boxes.blend] [--size 1920 1080]
                                            [--tiles 4x4]

The scene is exported once through Blender's Python module (the engine's own export), then rendered by the
core: locally on one thread (the reference image and time), and on a LocalCluster of 1 and of 2 worker
processes with one thread each, as ``--tiles`` tiles (``cluster.render_on``). Prints each time, the
speed-up of 2 workers over 1, and the overhead of the cluster and the merge (1 worker's time over the local
one-thread time); checks that every image equals the local one bit for bit.

The cluster is started before bpy is imported (its workers are spawned processes that inherit sys.path).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blend", default=str(ROOT / "sample_blends" / "floating_boxes.blend"))
    parser.add_argument("--size", type=int, nargs=2, default=(1920, 1080), metavar=("W", "H"))
    parser.add_argument("--tiles", default="4x4")
    args = parser.parse_args()
    import numpy as np
    from distributed import Client, LocalCluster

    from lazyvis_addon import cluster
    from lazyvis_addon.tiles import parse_tiles
    columns, rows = parse_tiles(args.tiles)
    clusters = {workers: LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                                      dashboard_address=None) for workers in (1, 2)}
    try:
        sys.path.insert(0, str(ROOT / "bench"))
        from bench_geometry import load_blend  # imports bpy: after the clusters
        scene, settings = load_blend(Path(args.blend), args.size[0], None, height=args.size[1])
        settings = replace(settings, threads=1)
        from lazyvis_addon.core import render
        started = time.perf_counter()
        local = render(scene, settings)
        local_seconds = time.perf_counter() - started
        print(f"{Path(args.blend).name} {scene.camera.width} x {scene.camera.height}, {len(scene.triangles)} "
              f"triangles; local, 1 thread: {local_seconds:.1f} s", flush=True)
        seconds = {}
        for workers, local_cluster in clusters.items():
            with Client(local_cluster) as client:
                cluster.render_on(client, scene, settings, 1, 1)  # warm: workers import the core, load kernels
                started = time.perf_counter()
                remote = cluster.render_on(client, scene, settings, columns, rows)
                seconds[workers] = time.perf_counter() - started
            same = all(np.array_equal(getattr(remote, name), getattr(local, name))
                       for name in ("combined", "depth", "normal", "sample_count", "blocker_count", "umbra"))
            print(f"{workers} worker(s) x 1 thread, {columns} x {rows} tiles: {seconds[workers]:.1f} s, "
                  f"image {'equal to the local one' if same else 'DIFFERENT'}", flush=True)
            if not same:
                return 1
        print(f"speed-up 2 workers over 1: {seconds[1] / seconds[2]:.2f}x; cluster + tiles + merge overhead "
              f"(1 worker over local): {seconds[1] / local_seconds:.2f}x", flush=True)
    finally:
        for local_cluster in clusters.values():
            local_cluster.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
