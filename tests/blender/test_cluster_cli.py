"""``lazyvis render --scheduler`` (issue 18): frames and tiles rendered on a Dask cluster write the same files
as a local render, bit for bit: with a LocalCluster of worker processes, and with a scheduler and two worker
processes started as a farm would (``dask scheduler`` / ``dask worker`` on 127.0.0.1), one of them killed
while it renders a tile (Dask gives its tiles to the other). Every server binds to loopback and is stopped
by the test."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
distributed = pytest.importorskip("distributed", reason="Dask's distributed is the cluster extra (lazyvis[cluster])")

from blender_helpers import ROOT, read_exr  # noqa: E402
from test_cli import interrupted_render, lazyvis, save_tiled_scene  # noqa: E402

BOXES = ROOT / "sample_blends" / "floating_boxes.blend"


def assert_same_files(first: Path, second: Path) -> None:
    a, b = read_exr(first), read_exr(second)
    assert sorted(a) == sorted(b)
    for name, values in a.items():
        np.testing.assert_array_equal(b[name], values, err_msg=f"{name}: {first.name} vs {second.name}")


def test_local_cluster_renders_the_local_files(scene, tmp_path):
    blend = save_tiled_scene(scene, tmp_path / "tiled.blend")
    local = lazyvis("render", blend, "-f", "1", "--multilayer", "-o", tmp_path / "local.exr")
    assert local.returncode == 0, local.stderr
    remote = lazyvis("render", blend, "-f", "1", "--multilayer", "-o", tmp_path / "remote.exr", "--tiles", "3x2",
                     "--scheduler", "local", "--workers", "2")
    assert remote.returncode == 0, remote.stdout + remote.stderr
    assert "Cluster tiles" in remote.stderr  # the progress counts the tiles
    assert_same_files(tmp_path / "local.exr", tmp_path / "remote.exr")


def start(argv, log: Path) -> subprocess.Popen:
    return subprocess.Popen(argv, cwd=ROOT, stdout=log.open("w"), stderr=subprocess.STDOUT,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)), start_new_session=True)


@pytest.fixture
def farm(tmp_path):
    """A scheduler and two single-threaded workers, separate processes on 127.0.0.1: (address, workers)."""
    scheduler_file = tmp_path / "scheduler.json"
    processes = [start([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
                        "--no-dashboard", "--scheduler-file", str(scheduler_file)], tmp_path / "scheduler.log")]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        workers = [start([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads", "1",
                          "--nworkers", "1", "--no-dashboard", "--host", "127.0.0.1", "--no-nanny"],
                         tmp_path / f"worker{i}.log") for i in range(2)]
        processes += workers
        with distributed.Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address, workers
    finally:
        for process in processes:  # stop every server the test started
            if process.poll() is None:
                os.killpg(process.pid, signal.SIGTERM)
        for process in processes:
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)


def test_a_farm_of_worker_processes_and_a_killed_worker(farm, tmp_path):
    """Frames 1-2 of the boxes at 128 px as 3 x 3 tiles on two workers, one killed while it renders a tile:
    the files are the local render's."""
    address, workers = farm
    common = ("-f", "1..2", "--resolution-percentage", "25", "--multilayer")
    local = lazyvis("render", BOXES, *common, "-o", tmp_path / "local_#.exr")
    assert local.returncode == 0, local.stderr
    command = subprocess.Popen([sys.executable, "-m", "lazyvis_addon.cli", "render", str(BOXES), *common, "-o",
                                str(tmp_path / "farm_#.exr"), "--tiles", "3x3", "--scheduler", address],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed_with_tasks = False
    with distributed.Client(address, timeout="30s") as watcher:
        pids = watcher.run(os.getpid)  # worker address -> its process (no nanny: the worker itself)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and command.poll() is None and not killed_with_tasks:
            busy = [worker for worker, tasks in watcher.processing().items()
                    if any(str(task).startswith("lazyvis-tile") for task in tasks)]
            if busy:
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed_with_tasks = True
            time.sleep(0.02)
    stdout, stderr = command.communicate(timeout=300)
    assert killed_with_tasks, "no worker was seen rendering a tile"
    assert command.returncode == 0, stdout + stderr
    assert sum(process.poll() is not None for process in workers) == 1  # one worker gone, one did the rest
    for frame in (1, 2):
        assert_same_files(tmp_path / f"local_{frame}.exr", tmp_path / f"farm_{frame}.exr")


def test_cluster_arguments_and_an_unreachable_scheduler(scene, tmp_path):
    blend = save_tiled_scene(scene, tmp_path / "tiled.blend")
    for args, message in ((("--scheduler", "local", "--tiles", "2x2", "--tile", "1"), "--tile renders one tile"),
                          (("--workers", "2"), "--workers (1 or more) goes with --scheduler local")):
        result = lazyvis("render", blend, *args)
        assert result.returncode == 2 and message in result.stderr, result.stderr
    result = lazyvis("render", blend, "--scheduler", "tcp://127.0.0.1:9", timeout=120)
    assert result.returncode == 1 and "cannot reach the scheduler tcp://127.0.0.1:9" in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


def test_ctrl_c_cancels_the_clusters_tasks(farm, tmp_path):
    """SIGINT while the workers render a frame's tiles: status 130, nothing written, and the scheduler left
    with no LazyVis task (the frame's and the frames sent ahead cancelled)."""
    address, _ = farm
    output = tmp_path / "f_#.exr"
    interrupted_render([BOXES, "-f", "1..3", "--resolution-percentage", "25", "--tiles", "3x3",
                                 "--scheduler", address, "-o", output],
                                lambda line: "Cluster tiles" in line, seconds=180)
    assert not list(tmp_path.glob("f_*.exr"))
    with distributed.Client(address, timeout="30s") as watcher:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and watcher.run_on_scheduler(
                lambda dask_scheduler: len(dask_scheduler.tasks)):
            time.sleep(0.1)
        assert watcher.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) == 0
