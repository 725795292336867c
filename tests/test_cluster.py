"""Rendering on a Dask cluster (issue 18, ``lazyvis_addon.cluster``): a frame's tiles rendered by workers and
stitched equal the local render bit for bit; a worker's exception reaches the client; a cancel stops the
tasks. In-process workers here (threads, no network); ``tests/blender/test_cluster.py`` runs the command
line against worker processes on 127.0.0.1 and kills one."""

from __future__ import annotations

import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed", reason="Dask's distributed is the cluster extra (lazyvis[cluster])")

from lazyvis_addon import cluster  # noqa: E402
from lazyvis_addon.core import Progress, RenderCancelled, Settings, demo_scenes, render  # noqa: E402
from tests.test_render import PASSES  # noqa: E402


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as local, \
            distributed.Client(local) as connected:
        yield connected


def test_tile_windows_cover_the_window_once():
    for window, columns, rows in (((0, 0, 96, 72), 3, 2), ((5, 7, 19, 30), 4, 5), ((0, 0, 3, 2), 8, 8)):
        x0, y0, x1, y1 = window
        count = np.zeros((y1, x1), np.int32)
        tiles = cluster.tile_windows(window, columns, rows)
        for tx0, ty0, tx1, ty1 in tiles:
            assert tx1 > tx0 and ty1 > ty0
            count[ty0:ty1, tx0:tx1] += 1
        assert (count[y0:y1, x0:x1] == 1).all() and count.sum() == (x1 - x0) * (y1 - y0)
    assert len(cluster.tile_windows((0, 0, 3, 2), 8, 8)) == 6  # no empty tiles


def test_tiles_on_workers_equal_the_local_render(client):
    scene = demo_scenes.floating_boxes(resolution=72, n_boxes=9)
    settings = Settings(threads=1)
    local = render(scene, settings)
    progress = Progress()
    remote = cluster.render_on(client, scene, settings, 3, 2, progress)
    for name in PASSES:
        np.testing.assert_array_equal(getattr(remote, name), getattr(local, name), err_msg=name)
    assert remote.stats["cluster_tiles"] == 6 and remote.stats["triangles"] == local.stats["triangles"]
    assert remote.stats["aa_pixels"] >= local.stats["aa_pixels"]  # each tile counts its margin's too
    assert progress.stage_seconds["Cluster tiles"] > 0.0


def test_a_worker_error_reaches_the_client(client):
    scene = demo_scenes.floating_boxes(resolution=16, n_boxes=1)
    with pytest.raises(MemoryError, match="budget"):
        cluster.render_on(client, scene, Settings(memory_budget_mb=1.0), 2, 1)


class CancelAfterStart(Progress):
    def __init__(self):
        super().__init__()
        self.asked = 0

    def is_cancelled(self) -> bool:
        self.asked += 1
        return self.asked > 2


def test_a_cancel_cancels_the_tasks(client):
    scene = demo_scenes.floating_boxes(resolution=96, n_boxes=16)
    submitted = cluster.submit(client, scene.validated(), Settings(threads=1), 4, 4)
    with pytest.raises(RenderCancelled):
        cluster.gather(client, submitted, CancelAfterStart())
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and {f.status for f in submitted.futures} - {"cancelled", "finished"}:
        time.sleep(0.05)
    assert {future.status for future in submitted.futures} <= {"cancelled", "finished"}
    assert sum(future.status == "cancelled" for future in submitted.futures) > 8  # most had not started
