"""``lazyvis render`` (lazyvis_addon/cli.py): the command line that does with bpy what
``blender -b FILE.blend -E LAZYVIS -f N`` does with a Blender install. Run as subprocesses, the way it is
used; the pure helpers (frame lists, '#' paths, the progress bar) are tested in-process."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
import tomllib

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import ROOT, add_area_light, add_camera, read_exr, render_to_exr  # noqa: E402

from lazyvis_addon import cli  # noqa: E402


def lazyvis(*args, timeout=300) -> subprocess.CompletedProcess:
    """``lazyvis ARGS`` as installed (``python -m lazyvis_addon.cli`` is the same entry point)."""
    return subprocess.run([sys.executable, "-m", "lazyvis_addon.cli", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def save_small_scene(scene, path, frames=(1, 1), animate=False):
    """A plane under an area light seen from above, 32 x 24 px, saved to ``path``; with ``animate`` the
    light's power is keyed to grow with the frame number."""
    add_camera(scene)
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    light = add_area_light(location=(0.0, 0.0, 2.0), size=1.0, energy=20.0)
    if animate:
        for frame in range(frames[0], frames[1] + 1):
            light.data.energy = 10.0 * frame
            light.data.keyframe_insert("energy", frame=frame)
    scene.frame_start, scene.frame_end = frames
    scene.frame_current = frames[0]
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    return path


def assert_clean_failure(result, message):
    assert result.returncode == 1, result.stdout + result.stderr
    assert message in result.stderr, result.stderr
    assert "Traceback" not in result.stdout + result.stderr


# -- end to end ----------------------------------------------------------------------------------------------


def test_render_writes_what_the_engine_renders(scene, tmp_path):
    """The command's RGBA float EXR is the engine's own render, value for value, and the PNG its preview."""
    blend = save_small_scene(scene, tmp_path / "small.blend")
    result = lazyvis("render", blend, "-f", "1", "-o", tmp_path / "out" / "frame_###.exr",
                     "--png", tmp_path / "out" / "frame_###.png")
    assert result.returncode == 0, result.stdout + result.stderr
    exr, png = tmp_path / "out" / "frame_001.exr", tmp_path / "out" / "frame_001.png"
    assert f"Saved: '{exr}'" in result.stdout and png.read_bytes().startswith(b"\x89PNG")
    assert "Illumination" in result.stderr  # the progress, one line per stage when not on a terminal
    written = read_exr(exr)
    assert sorted(written) == ["RGBA"] and written["RGBA"].shape == (24, 32, 4)
    expected = render_to_exr(scene, tmp_path / "in_process.exr")["RGBA"]
    np.testing.assert_array_equal(written["RGBA"], expected)
    assert written["RGBA"][..., :3].max() > 0.0


def test_sample_blend_at_ten_percent(tmp_path):
    result = lazyvis("render", ROOT / "sample_blends" / "floating_boxes.blend", "-f", "1", "-o",
                     tmp_path / "boxes.exr", "--resolution-percentage", "10")
    assert result.returncode == 0, result.stdout + result.stderr
    rgba = read_exr(tmp_path / "boxes.exr")["RGBA"]
    assert rgba.shape == (51, 51, 4) and rgba.dtype == np.float32
    assert 0.02 < rgba[..., :3].mean() < 2.0 and np.isfinite(rgba).all()


def test_animation_range_and_frame_lists(scene, tmp_path):
    """-a renders start..end, -s/-e narrow it, -f takes Blender's lists; each frame is evaluated (the
    keyed light power grows with the frame) and '#' becomes the padded frame number."""
    blend = save_small_scene(scene, tmp_path / "anim.blend", frames=(1, 3), animate=True)
    result = lazyvis("render", blend, "-a", "-o", tmp_path / "a" / "f_##.exr")
    assert result.returncode == 0, result.stdout + result.stderr
    means = [read_exr(tmp_path / "a" / f"f_0{frame}.exr")["RGBA"][..., :3].mean() for frame in (1, 2, 3)]
    # (not exactly: edge pixels' anti-aliasing samples are placed at random per frame)
    np.testing.assert_allclose(np.array(means) / means[0], [1.0, 2.0, 3.0], rtol=2e-3)

    result = lazyvis("render", blend, "-s", "2", "-e", "3", "-o", tmp_path / "s" / "g.exr")
    assert result.returncode == 0, result.stdout + result.stderr
    assert sorted(os.listdir(tmp_path / "s")) == ["g0002.exr", "g0003.exr"]  # no '#': numbered like Blender

    result = lazyvis("render", blend, "-f", "1,+2", "-o", tmp_path / "l" / "h#.exr")
    assert result.returncode == 0, result.stdout + result.stderr
    assert sorted(os.listdir(tmp_path / "l")) == ["h1.exr", "h3.exr"]


def test_frame_jump_scene_resolution_and_threads_flags(scene, tmp_path):
    """-j steps the range as Blender's frame_step; -S renders the named scene (another size than
    the active one); --resolution sets the frame's size; -t 1 and -t 2 give the same image bit for bit."""
    blend = save_small_scene(scene, tmp_path / "flags.blend", frames=(1, 5), animate=True)
    result = lazyvis("render", blend, "-a", "-j", "2", "-o", tmp_path / "j" / "f_#.exr")
    assert result.returncode == 0, result.stdout + result.stderr
    assert sorted(os.listdir(tmp_path / "j")) == ["f_1.exr", "f_3.exr", "f_5.exr"]
    means = [read_exr(tmp_path / "j" / f"f_{frame}.exr")["RGBA"][..., :3].mean() for frame in (1, 3, 5)]
    np.testing.assert_allclose(np.array(means) / means[0], [1.0, 3.0, 5.0], rtol=2e-3)  # each frame evaluated

    second = bpy.data.scenes.new("Dim")  # the same objects, 16 x 12
    second.render.engine = scene.render.engine
    second.camera = scene.camera
    for obj in scene.collection.objects:
        second.collection.objects.link(obj)
    second.render.resolution_x, second.render.resolution_y = 16, 12
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "two.blend"), copy=True)
    for name, shape in ((scene.name, (24, 32)), ("Dim", (12, 16))):
        result = lazyvis("render", tmp_path / "two.blend", "-S", name, "-f", "1", "-o", tmp_path / f"{name}.exr")
        assert result.returncode == 0, result.stdout + result.stderr
        assert read_exr(tmp_path / f"{name}.exr")["RGBA"].shape[:2] == shape
    assert_clean_failure(lazyvis("render", tmp_path / "two.blend", "-S", "Nope", "-f", "1"), "has no scene 'Nope'")

    images = []
    for threads in (1, 2):
        out = tmp_path / f"t{threads}.exr"
        result = lazyvis("render", blend, "-f", "2", "--resolution", "40", "20", "-t", threads, "-o", out)
        assert result.returncode == 0, result.stdout + result.stderr
        assert "40 x 20" in result.stdout
        images.append(read_exr(out)["RGBA"])
    assert images[0].shape == (20, 40, 4)
    np.testing.assert_array_equal(images[0], images[1])


@pytest.mark.parametrize("threads, mode, count", [(0, "AUTO", 0), (3, "FIXED", 3)])
def test_overrides_reach_the_settings(scene, threads, mode, count):
    """What the flags set is what the engine's Settings read (threads: Blender's Performance > Threads)."""
    from lazyvis_addon.blender.properties import settings_from_scene

    args = cli.build_parser().parse_args(["render", "x.blend", "--resolution", "64", "48", "--resolution-percentage",
                                          "50", "-t", str(threads), "-s", "2", "-e", "9", "-j", "3"])
    cli.apply_overrides(scene, args)
    render = scene.render
    assert (render.resolution_x, render.resolution_y, render.resolution_percentage) == (64, 48, 50)
    assert render.threads_mode == mode and settings_from_scene(scene).threads == count
    assert (scene.frame_start, scene.frame_end, scene.frame_step) == (2, 9, 3)


def test_default_output_is_the_files_own_path(scene, tmp_path):
    scene.render.filepath = "//frames/shot_"
    blend = save_small_scene(scene, tmp_path / "own.blend")
    result = lazyvis("render", blend, "-f", "1")
    assert result.returncode == 0, result.stdout + result.stderr
    assert (tmp_path / "frames" / "shot_0001.exr").is_file()  # Blender's own rule: digits and extension


def test_multilayer_has_every_pass(scene, tmp_path):
    layer = scene.view_layers[0]
    layer.use_pass_z = True
    blend = save_small_scene(scene, tmp_path / "passes.blend")
    result = lazyvis("render", blend, "-o", tmp_path / "layers.exr", "--multilayer", "--png", tmp_path / "p.png")
    assert result.returncode == 0, result.stdout + result.stderr
    channels = read_exr(tmp_path / "layers.exr")
    prefix = layer.name + "."
    assert {prefix + "Combined", prefix + "Depth.Z", prefix + "Blocker Count.X"} <= set(channels)
    assert (tmp_path / "p.png").is_file()


def test_png_preview_is_the_exr_in_srgb(scene, tmp_path):
    """The --png preview, decoded by Blender's own PNG reader, is the EXR's colour through the sRGB transfer
    (Blender's Standard view), row for row; and the transfer is the closed form at known values."""
    from lazyvis_addon.core.png import linear_to_srgb8

    blend = save_small_scene(scene, tmp_path / "png.blend")
    result = lazyvis("render", blend, "-f", "1", "-o", tmp_path / "f.exr", "--png", tmp_path / "f.png")
    assert result.returncode == 0, result.stdout + result.stderr
    exr = read_exr(tmp_path / "f.exr")["RGBA"][..., :3]
    image = bpy.data.images.load(str(tmp_path / "f.png"))
    assert tuple(image.size) == (32, 24) and image.depth in (24, 32)
    pixels = np.array(image.pixels[:], np.float32).reshape(24, 32, image.channels)[::-1, :, :3]  # bottom row first
    np.testing.assert_array_equal(np.round(pixels * 255.0).astype(np.uint8), linear_to_srgb8(exr))
    assert 0.05 < pixels.mean() < 0.95  # a lit image, not black or clipped
    linear = np.array([[[0.0, 0.0031308, 0.5], [1.0, 2.0, np.nan]]])
    assert linear_to_srgb8(linear).tolist() == [[[0, 10, 188], [255, 255, 0]]]  # 12.92 x 0.0031308 x 255 = 10.3


# -- errors: one line, non-zero status, no traceback ---------------------------------------------------------


def test_missing_file(tmp_path):
    assert_clean_failure(lazyvis("render", tmp_path / "nothing.blend", "-f", "1"), "no such file")


def test_not_a_blend_file(tmp_path):
    fake = tmp_path / "fake.blend"
    fake.write_text("not a blend file\n")
    assert_clean_failure(lazyvis("render", fake, "-f", "1"), "is not a .blend file")


def test_render_error_is_the_engines_report(scene, tmp_path):
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.object
    cube.name = "Corrupt"
    cube.data.vertices[3].co = (0.0, float("inf"), float("nan"))
    blend = save_small_scene(scene, tmp_path / "nan.blend")
    result = lazyvis("render", blend, "-f", "1", "-o", tmp_path / "x.exr")
    assert_clean_failure(result, "frame 1: LazyVis: object 'Corrupt' has NaN or infinite vertex coordinates")
    assert not (tmp_path / "x.exr").exists()


def test_blenders_own_refusal_is_reported_too(scene, tmp_path):
    blend = save_small_scene(scene, tmp_path / "nocam.blend")
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    bpy.context.scene.camera = None
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    assert_clean_failure(lazyvis("render", blend, "-f", "1"), "frame 1: Cannot render, no camera")


def test_bad_frame_list_and_bad_arguments(scene, tmp_path):
    blend = save_small_scene(scene, tmp_path / "small.blend")
    assert_clean_failure(lazyvis("render", blend, "-f", "1..x"), "is not a frame number")
    usage = lazyvis("render", blend, "-f", "1", "-a")
    assert usage.returncode == 2 and "not allowed with" in usage.stderr


def interrupted_render(args, ready, seconds=120) -> str:
    """``lazyvis render ARGS`` sent SIGINT once a stage line of stderr satisfies ``ready``: asserts the clean
    interrupt (status 130, 'interrupted', no traceback) and returns stderr."""
    process = subprocess.Popen([sys.executable, "-m", "lazyvis_addon.cli", "render", *map(str, args)],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + seconds
        for line in process.stderr:  # stage lines: wait until the core is at work
            if ready(line) or time.monotonic() > deadline:
                break
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    return stderr


def test_ctrl_c_cancels_without_writing(tmp_path):
    """SIGINT during the render: exit status 130, 'interrupted', and no image for the frame."""
    output = tmp_path / "cancelled.exr"
    interrupted_render([ROOT / "sample_blends" / "suzanne.blend", "-f", "1", "-o", output],
                       lambda line: "Illumination" in line)
    assert not output.exists()


def test_ctrl_c_in_a_multi_frame_run_keeps_the_finished_frames(tmp_path):
    """SIGINT while frame 2 of 3 renders: status 130, frame 1 written whole, frames 2 and 3 not at all."""
    interrupted_render([ROOT / "sample_blends" / "suzanne.blend", "-s", "1", "-e", "3", "-o", tmp_path / "f_#.exr"],
                       lambda line: "Frame 2" in line and "Illumination" in line, seconds=180)
    assert sorted(os.listdir(tmp_path)) == ["f_1.exr"]
    assert read_exr(tmp_path / "f_1.exr")["RGBA"].shape == (512, 512, 4)


# -- in-process: the pure helpers ------------------------------------------------------------------------


def test_frame_lists_follow_blenders_syntax():
    assert cli.parse_frames("7", 1, 250) == [7]
    assert cli.parse_frames("1,3,5..7", 1, 250) == [1, 3, 5, 6, 7]
    assert cli.parse_frames("+2", 10, 20) == [12]
    assert cli.parse_frames("-1", 10, 20) == [19]
    with pytest.raises(ValueError):
        cli.parse_frames("5..3", 1, 250)


@pytest.mark.parametrize("pattern", ["out_#.exr", "out_####.exr", "a##/b###.exr", "plain.exr"])
def test_frame_numbers_replace_hashes_as_blender_does(scene, pattern, tmp_path):
    render = scene.render
    render.filepath = str(tmp_path / pattern)
    render.use_file_extension = False
    blender = render.frame_path(frame=7)
    ours = cli.substitute_frame(str(tmp_path / pattern), 7)
    if "#" in pattern:
        assert ours == blender
    else:
        assert ours == str(tmp_path / pattern)  # one frame to a plain path: the path as given


def test_output_pattern_numbers_several_frames(tmp_path):
    assert cli.output_pattern("//r/x.exr", False, tmp_path) == str(tmp_path / "r" / "x.exr")
    assert cli.output_pattern(str(tmp_path / "x.exr"), True, tmp_path) == str(tmp_path / "x####.exr")
    assert cli.output_pattern(str(tmp_path / "x_##.exr"), True, tmp_path) == str(tmp_path / "x_##.exr")
    assert cli.output_pattern(str(tmp_path) + os.sep, False, tmp_path) == str(tmp_path / "####.exr")


def test_progress_bar_on_a_terminal():
    stream = io.StringIO()
    progress = cli.TerminalProgress(stream, tty=True)
    progress.prefix = "Frame 1 | "
    progress.begin_stage("Illumination", 4)
    progress.advance(4)
    progress.warn("something")  # makes room for Blender's warning line
    text = stream.getvalue()
    assert "\rFrame 1 | Illumination" in text and "[" + "#" * 30 + "] 100.0%" in text
    assert text.endswith("\r")


def test_bands_of_rows_resume_their_stages():
    """A frame in bands takes its stages up again band after band: a terminal's bar goes on where the stage
    stopped (it does not drop to 0 %), and a log names each stage once per frame, not once per band."""
    stream = io.StringIO()
    progress = cli.TerminalProgress(stream, tty=True)
    progress.begin_stage("Illumination", 8)
    progress.advance(4)
    progress.begin_stage("Camera rays", 8, 4)
    progress.begin_stage("Illumination", 8, 4)
    assert stream.getvalue().rstrip().endswith("Illumination         [" + "#" * 15 + "." * 15 + "]  50.0%")
    log = io.StringIO()
    progress = cli.TerminalProgress(log, tty=False)
    progress.prefix = "Frame 1 | "
    for done in (0, 4):  # two bands
        progress.begin_stage("Camera rays", 8, done)
        progress.begin_stage("Illumination", 8, done)
    progress.prefix = "Frame 2 | "
    progress.begin_stage("Camera rays", 8)
    assert log.getvalue().splitlines() == ["Frame 1 | Camera rays", "Frame 1 | Illumination", "Frame 2 | Camera rays"]


def test_the_command_is_installed_with_the_package():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["lazyvis"] == "lazyvis_addon.cli:main"
    code = "import sys; from lazyvis_addon import cli; assert 'bpy' not in sys.modules; print('ok')"
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.stdout.strip() == "ok", result.stderr


# -- tiles (issue 18) ----------------------------------------------------------------------------------------


def save_tiled_scene(scene, path):
    """``save_small_scene`` with a box on the plane (outlines and penumbrae to anti-alias) and the Depth pass,
    at 40 x 30 px."""
    scene.view_layers[0].use_pass_z = True
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.2, -0.1, 0.3))
    scene.render.resolution_x, scene.render.resolution_y = 40, 30
    return save_small_scene(scene, path)


def test_tiles_merge_into_the_frame_bit_for_bit(scene, tmp_path):
    """At the default settings: the frame rendered whole, as 3 x 2 tiles merged in one run, and as 2 x 2
    tiles rendered one per command (a farm's tasks) then stitched by 'lazyvis merge' -- every pass of the
    multilayer EXR the same, bit for bit."""
    blend = save_tiled_scene(scene, tmp_path / "tiled.blend")
    whole = lazyvis("render", blend, "-o", tmp_path / "whole.exr", "--multilayer")
    assert whole.returncode == 0, whole.stdout + whole.stderr
    tiled = lazyvis("render", blend, "-o", tmp_path / "tiled.exr", "--multilayer", "--tiles", "3x2")
    assert tiled.returncode == 0, tiled.stdout + tiled.stderr
    assert "Tile 6/6" in tiled.stderr and not list(tmp_path.glob(".*tiles"))  # progress; tiles' files removed
    for tile in range(4):
        one = lazyvis("render", blend, "-o", tmp_path / "parts" / f"t{tile}.exr", "--multilayer", "--tiles", "2x2",
                      "--tile", tile)
        assert one.returncode == 0, one.stdout + one.stderr
        assert read_exr(tmp_path / "parts" / f"t{tile}.exr")["ViewLayer.Combined"].shape == (15, 20, 4)
    merged = lazyvis("merge", *sorted((tmp_path / "parts").glob("t*.exr")), "-o", tmp_path / "merged.exr")
    assert merged.returncode == 0 and "4 tiles, 40 x 30" in merged.stdout, merged.stdout + merged.stderr
    expected = read_exr(tmp_path / "whole.exr")
    assert {"ViewLayer.Combined", "ViewLayer.Depth.Z"} <= set(expected)
    assert len(np.unique(expected["ViewLayer.Combined"][..., 0])) > 50  # edges and shadows, not a flat image
    for name in ("tiled.exr", "merged.exr"):
        channels = read_exr(tmp_path / name)
        assert sorted(channels) == sorted(expected)
        for key, values in expected.items():
            np.testing.assert_array_equal(channels[key], values, err_msg=f"{key} of {name}")


def test_tile_arguments_and_merge_errors(scene, tmp_path):
    blend = save_small_scene(scene, tmp_path / "small.blend")
    for args, message in ((("--tile", "1"), "--tile needs --tiles"), (("--tiles", "0x2"), "tiles must be 1 to 64"),
                          (("--tiles", "2x2", "--tile", "4"), "--tile must be 0 to 3")):
        result = lazyvis("render", blend, *args)
        assert result.returncode == 2 and message in result.stderr, result.stderr
    assert_clean_failure(lazyvis("merge", tmp_path / "none.exr", "-o", tmp_path / "m.exr"), "no such file")
    plain = lazyvis("render", blend, "-o", tmp_path / "plain.exr")
    assert plain.returncode == 0, plain.stderr
    assert_clean_failure(lazyvis("merge", tmp_path / "plain.exr", "-o", tmp_path / "m.exr"),
                         "does not say where it lies in the frame")


def test_set_tile_operator_sets_the_border_and_the_note(scene):
    """What a farm's --python-expr calls before rendering a tile."""
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 200, 100, 50
    assert bpy.ops.lazyvis.set_tile(tile=5, columns=3, rows=2) == {'FINISHED'}
    render = scene.render
    assert render.use_border and render.use_crop_to_border and render.use_stamp_note
    assert (render.border_min_x, render.border_max_x) == pytest.approx((2 / 3, 1.0))
    assert (render.border_min_y, render.border_max_y) == pytest.approx((0.0, 0.5))
    assert render.stamp_note_text == "LazyVis tile 66 25 100 50 of 100 x 50"
    with pytest.raises(RuntimeError, match="tile 6 is not one of"):
        bpy.ops.lazyvis.set_tile(tile=6, columns=3, rows=2)
