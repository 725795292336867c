"""The Flamenco 3 job type ``farm/flamenco/lazyvis_tiled.js`` (issue 18): compiled under Node with a stand-in
for Flamenco's job compiler (``tests/farm/flamenco_harness.js``), its tasks, commands, arguments and
dependencies asserted; then run as a worker would (the blender-render commands through a bpy stand-in for the
``blender`` executable, the merge through the ``lazyvis`` command) and the merged frames compared with whole
frames, bit for bit. Node is on the machines (and ``make test`` installs Debian's nodejs where it is not)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import ROOT, add_area_light, add_camera, read_exr  # noqa: E402

JOB_TYPE = ROOT / "farm" / "flamenco" / "lazyvis_tiled.js"
HARNESS = ROOT / "tests" / "farm" / "flamenco_harness.js"
SHIM = ROOT / "tests" / "farm" / "blender_shim.py"


def compile_job(settings: dict, tmp_path: Path) -> dict:
    node = shutil.which("node") or shutil.which("nodejs")
    assert node, "Node.js is needed to compile Flamenco job types (make test installs Debian's nodejs)"
    settings_file = tmp_path / "settings.json"
    settings_file.write_text(json.dumps(settings))
    result = subprocess.run([node, str(HARNESS), str(JOB_TYPE), str(settings_file)], capture_output=True,
                            text=True, timeout=60)
    compiled = json.loads(result.stdout)
    if result.returncode == 3:
        return compiled
    assert result.returncode == 0, result.stderr
    return compiled


def job_settings(tmp_path: Path, **changes) -> dict:
    settings = {"frames": "1-3, 7", "chunk_size": 2, "tiles_x": 3, "tiles_y": 2, "multilayer": True,
                "render_output_root": str(tmp_path / "render"), "add_path_components": 0,
                "render_output_path": str(tmp_path / "render" / "shot" / "{timestamp}" / "######"),
                "lazyvis_cmd": "lazyvis", "blendfile": str(tmp_path / "shot.blend"), "scene": "Scene"}
    settings.update(changes)
    return settings


def test_the_job_compiles_to_tile_tasks_and_merges(tmp_path):
    compiled = compile_job(job_settings(tmp_path), tmp_path)
    tasks = {task["name"]: task for task in compiled["tasks"]}
    chunks = ("1-2", "3", "7")
    renders = [f"render-{chunk}-tile-{tile}" for chunk in chunks for tile in range(6)]
    assert list(tasks) == [name for chunk in chunks for name in
                           [f"render-{chunk}-tile-{tile}" for tile in range(6)] + [f"merge-{chunk}"]]
    out = tmp_path / "render" / "shot" / "20261206-030405"
    for name in renders:
        task = tasks[name]
        chunk, tile = name.split("-tile-")[0][len("render-"):], int(name.split("-tile-")[1])
        assert task["type"] == "blender" and task["dependencies"] == [] and len(task["commands"]) == 1
        command = task["commands"][0]
        assert command["name"] == "blender-render" and command["totalFrames"] == (2 if chunk == "1-2" else 1)
        parameters = command["parameters"]
        assert parameters["exe"] == "{blender}" and parameters["exeArgs"] == "{blenderArgs}"
        assert parameters["blendfile"] == str(tmp_path / "shot.blend")
        assert parameters["args"] == [
            "--scene", "Scene",
            "--python-expr", f"import bpy; bpy.ops.lazyvis.set_tile(tile={tile}, columns=3, rows=2, "
                             "output='MULTILAYER')",
            "--engine", "LAZYVIS", "--render-output", str(out / "tiles" / f"tile_{tile:04d}_######"),
            "--render-frame", chunk.replace("-", "..")]
    merge = tasks["merge-1-2"]
    assert merge["type"] == "misc" and merge["dependencies"] == [f"render-1-2-tile-{t}" for t in range(6)]
    assert [c["name"] for c in merge["commands"]] == ["exec", "exec"]  # frames 1 and 2
    assert merge["commands"][1]["parameters"] == {
        "exe": "lazyvis", "args": ["merge"] + [str(out / "tiles" / f"tile_{t:04d}_000002.exr") for t in range(6)]
        + ["-o", str(out / "000002.exr")]}
    assert tasks["merge-7"]["dependencies"] == [f"render-7-tile-{t}" for t in range(6)]
    rgba = compile_job(job_settings(tmp_path, multilayer=False, tiles_x=1, tiles_y=1, frames="4"), tmp_path)
    assert [t["name"] for t in rgba["tasks"]] == ["render-4-tile-0", "merge-4"]
    assert "output='RGBA'" in rgba["tasks"][0]["commands"][0]["parameters"]["args"][3]
    for bad in ({"tiles_x": 0}, {"tiles_y": 65}, {"tiles_x": 1.5}):
        assert "must be a whole number from 1 to 64" in compile_job(job_settings(tmp_path, **bad), tmp_path)["error"]


def test_the_settings_evaluate_in_blender(scene):
    """The settings Flamenco's add-on evaluates in Blender (``eval``) give the scene's frame range and name."""
    source = JOB_TYPE.read_text()
    scene.frame_start, scene.frame_end = 3, 42
    context = {"C": bpy.context}
    assert eval("f'{C.scene.frame_start}-{C.scene.frame_end}'", context) == "3-42"
    assert eval("C.scene.name", context) == scene.name
    for expression in ("f'{C.scene.frame_start}-{C.scene.frame_end}'", "C.scene.name"):
        assert f'eval: "{expression}"' in source


def run_like_a_worker(compiled: dict, tmp_path: Path) -> None:
    """Every task's commands in order (tile tasks before the merge that depends on them): blender-render
    through the bpy stand-in, exec of 'lazyvis' through this Python's ``lazyvis_addon.cli``."""
    environment = dict(os.environ, PYTHONPATH=str(ROOT))
    for task in compiled["tasks"]:  # tasks: tiles first, each chunk's merge after them
        for command in task["commands"]:
            parameters = command["parameters"]
            if command["name"] == "blender-render":
                argv = [sys.executable, str(SHIM), "-b", parameters["blendfile"], *parameters["args"]]
            else:
                assert command["name"] == "exec" and parameters["exe"] == "lazyvis"
                argv = [sys.executable, "-m", "lazyvis_addon.cli", *parameters["args"]]
            result = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, env=environment, timeout=300)
            assert result.returncode == 0, f"{task['name']}: {result.stdout}\n{result.stderr}"


def test_tiles_rendered_by_the_job_merge_into_whole_frames(scene, tmp_path):
    """The compiled job, run task by task, writes frames equal to whole-frame renders, every pass."""
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.2, -0.1, 0.3))
    light = add_area_light(location=(0.0, 0.0, 2.0), size=1.0, energy=20.0)
    for frame in (1, 2):  # the light moves: two different frames
        light.location.x = 0.3 * frame
        light.keyframe_insert("location", frame=frame)
    scene.view_layers[0].use_pass_z = True
    scene.render.resolution_x, scene.render.resolution_y = 40, 30
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"), copy=True)
    compiled = compile_job(job_settings(tmp_path, frames="1-2", chunk_size=2), tmp_path)
    run_like_a_worker(compiled, tmp_path)
    out = tmp_path / "render" / "shot" / "20261206-030405"
    whole = subprocess.run([sys.executable, "-m", "lazyvis_addon.cli", "render", str(tmp_path / "shot.blend"),
                            "-f", "1..2", "--multilayer", "-o", str(tmp_path / "whole" / "f_######.exr")],
                           capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert whole.returncode == 0, whole.stderr
    frames = [read_exr(tmp_path / "whole" / f"f_{frame:06d}.exr") for frame in (1, 2)]
    assert not np.array_equal(frames[0]["ViewLayer.Combined"], frames[1]["ViewLayer.Combined"])
    for frame, expected in zip((1, 2), frames):
        merged = read_exr(out / f"{frame:06d}.exr")
        assert {"ViewLayer.Combined", "ViewLayer.Depth.Z"} <= set(merged) and sorted(merged) == sorted(expected)
        for name, values in expected.items():
            np.testing.assert_array_equal(merged[name], values, err_msg=f"{name}, frame {frame}")
