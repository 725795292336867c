"""Every sample .blend split into 2 x 2 and 3 x 5 tiles (issue 18): each tile rendered in Blender at the
default settings as a farm renders it (``bpy.ops.lazyvis.set_tile``: border, crop, note, multilayer EXR),
stitched by ``tiles.merge_tiles``, equals the whole frame bit for bit in every pass (Combined, Depth, Normal,
Blocker Count, Sample Count)."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import ROOT, read_exr  # noqa: E402

from lazyvis_addon.cli import configure_output  # noqa: E402
from lazyvis_addon.tiles import merge_tiles  # noqa: E402

SAMPLES = sorted(path.stem for path in (ROOT / "sample_blends").glob("*.blend"))
# 10 % of the samples' 512 px: 51 px across, so that 3 x 5 tiles are 17 x 7-8 px (edges everywhere).
PERCENTAGE = 10


def open_sample(name: str):
    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "sample_blends" / f"{name}.blend"), load_ui=False)
    scene = bpy.context.scene
    scene.render.resolution_percentage = PERCENTAGE
    scene.render.use_file_extension = False
    for layer in scene.view_layers:
        layer.use_pass_z = layer.use_pass_normal = True
        layer.lazyvis.use_pass_blocker_count = layer.lazyvis.use_pass_sample_count = True
    return scene


def write(scene, path) -> None:
    configure_output(scene.render, multilayer=True)
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)


@pytest.mark.parametrize("name", SAMPLES)
def test_sample_tiles_merge_into_the_whole_frame(addon, name, tmp_path):
    scene = open_sample(name)
    assert scene.render.engine == "LAZYVIS" and scene.lazyvis.aa_samples > 1  # the defaults, anti-aliased
    write(scene, tmp_path / "whole.exr")
    whole = read_exr(tmp_path / "whole.exr")
    assert len(whole) >= 5, sorted(whole)
    for columns, rows in ((2, 2), (3, 5)):
        paths = []
        for tile in range(columns * rows):  # tiles: a handful
            assert bpy.ops.lazyvis.set_tile(tile=tile, columns=columns, rows=rows, output='MULTILAYER') == {'FINISHED'}
            paths.append(tmp_path / f"tile_{columns}x{rows}_{tile}.exr")
            write(scene, paths[-1])
        merge_tiles(paths, tmp_path / f"merged_{columns}x{rows}.exr")
        scene.render.use_border = False
        merged = read_exr(tmp_path / f"merged_{columns}x{rows}.exr")
        assert sorted(merged) == sorted(whole)
        for channel, values in whole.items():
            np.testing.assert_array_equal(merged[channel], values, err_msg=f"{channel}, {columns} x {rows} tiles")
