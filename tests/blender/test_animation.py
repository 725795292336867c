"""Long animations through ``lazyvis render FILE -a`` (issue 17): 50 frames of a scene whose camera, an object
and the light move, rendered in one process as a farm worker would. Resident memory must not creep (frame 50
within 5 % of frame 5, from the ``Mem:`` the command prints per frame, as Blender does), and every frame
must equal the same frame rendered alone: nothing of one frame leaks into the next."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import ROOT, add_area_light, add_camera, read_exr  # noqa: E402

FRAMES = 50


def lazyvis(*args, timeout=900) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lazyvis_addon.cli", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def save_animated_scene(scene, path):
    """A floor, a box and an area light, 40 x 30 px; over FRAMES frames the camera circles, the box slides
    across the floor and the light swings over it (keys at both ends, Blender's default easing between)."""
    camera = add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=6.0)
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(-1.0, 0.0, 0.6))
    box = bpy.context.active_object
    light = add_area_light(location=(-1.0, 0.5, 2.5), size=1.2, energy=60.0)
    for frame, (box_x, light_x, camera_y) in ((1, (-1.0, -1.0, -6.0)), (FRAMES, (1.0, 1.2, -4.5))):
        box.location.x, light.location.x = box_x, light_x
        camera.location.y = camera_y
        for thing in (box, light, camera):
            thing.keyframe_insert("location", frame=frame)
    render = scene.render
    render.resolution_x, render.resolution_y, render.resolution_percentage = 40, 30, 100
    scene.frame_start, scene.frame_end = 1, FRAMES
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    return path


def test_fifty_frames_keep_their_memory_and_equal_single_frame_renders(scene, tmp_path):
    blend = save_animated_scene(scene, tmp_path / "moving.blend")
    result = lazyvis("render", blend, "-a", "-o", tmp_path / "anim" / "f_####.exr")
    assert result.returncode == 0, result.stdout + result.stderr
    memory = {int(frame): float(mb) for frame, mb in
              re.findall(r"\(frame (\d+), .*? Mem: ([\d.]+) MB\)", result.stdout)}
    assert sorted(memory) == list(range(1, FRAMES + 1)), result.stdout
    print(f"resident memory: frame 5 {memory[5]:.0f} MB, frame {FRAMES} {memory[FRAMES]:.0f} MB, "
          f"most {max(memory.values()):.0f} MB; every fifth frame: {[round(memory[f]) for f in range(5, FRAMES + 1, 5)]}")
    assert memory[FRAMES] <= 1.05 * memory[5]
    frames = [read_exr(tmp_path / "anim" / f"f_{frame:04d}.exr")["RGBA"] for frame in (1, 25, FRAMES)]
    assert not np.array_equal(frames[0], frames[2])  # the scene moves
    for frame, animated in zip((1, 25, FRAMES), frames):
        single = lazyvis("render", blend, "-f", frame, "-o", tmp_path / "single" / f"s_{frame}.exr")
        assert single.returncode == 0, single.stdout + single.stderr
        np.testing.assert_array_equal(read_exr(tmp_path / "single" / f"s_{frame}.exr")["RGBA"], animated,
                                      err_msg=f"frame {frame}")
