"""Tiles of a frame for render farms (issue 18): borders that tile the frame exactly, the note that places a
tile, and ``merge_tiles``' stitching and refusals (no bpy: synthetic tile files)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lazyvis_addon.core.exr import read_exr, read_exr_parts, write_exr
from lazyvis_addon.tiles import (TileError, border_window, merge_tiles, parse_note, parse_tiles, tile_border,
                                 tile_note)


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(st.integers(1, 4000), st.integers(1, 3000), st.integers(1, 16), st.integers(1, 16))
def test_tile_borders_cover_the_frame_exactly_once(width, height, columns, rows):
    """Through Blender's own float32 rounding of border fractions (``border_window``), the tiles of any grid
    cover every pixel of any frame once: shared edges, no gap, no overlap."""
    if columns > width or rows > height:
        return
    count = np.zeros((height, width), np.int32)
    for tile in range(columns * rows):
        x0, y0, x1, y1 = border_window(width, height, tile_border(tile, columns, rows))
        count[y0:y1, x0:x1] += 1
    assert (count == 1).all()


def test_tiles_are_numbered_row_by_row_from_the_top_left():
    assert border_window(100, 60, tile_border(0, 4, 3)) == (0, 0, 25, 20)
    assert border_window(100, 60, tile_border(3, 4, 3)) == (75, 0, 100, 20)
    assert border_window(100, 60, tile_border(11, 4, 3)) == (75, 40, 100, 60)
    with pytest.raises(ValueError, match="tile 12 is not one of the 4 x 3"):
        tile_border(12, 4, 3)


def test_tile_grid_and_note_round_trip():
    assert parse_tiles("4x3") == (4, 3) and parse_tiles(" 2 X 5 ") == (2, 5)
    for bad in ("4", "0x2", "4x3x2", "ax3", "65x1"):
        with pytest.raises(ValueError):
            parse_tiles(bad)
    note = tile_note((16, 5, 48, 29), 64, 48)
    assert parse_note(note) == ((16, 5, 48, 29), (64, 48))
    assert parse_note("a note of the user's, no tile") is None and parse_note(None) is None


def frame_channels(width=12, height=8, names=("R", "G", "B", "A")):
    rng = np.random.default_rng(3)
    return {name: rng.random((height, width)).astype(np.float32) for name in names}


def write_tile(path, frame, window, cropped=True, frame_number="1", note=True):
    x0, y0, x1, y1 = window
    height, width = next(iter(frame.values())).shape
    if cropped:
        channels = {name: values[y0:y1, x0:x1] for name, values in frame.items()}
    else:  # an uncropped border render: the frame's size, zero outside the border
        channels = {}
        for name, values in frame.items():
            full = np.zeros_like(values)
            full[y0:y1, x0:x1] = values[y0:y1, x0:x1]
            channels[name] = full
    attributes = {"Frame": frame_number}
    if note:
        attributes["Note"] = tile_note(window, width, height)
    write_exr(path, channels, attributes=attributes)
    return path


def test_merge_stitches_cropped_and_uncropped_tiles_of_any_channels(tmp_path):
    frame = frame_channels(names=("ViewLayer.Combined.R", "ViewLayer.Combined.A", "ViewLayer.Depth.Z"))
    paths = [write_tile(tmp_path / f"t{i}.exr", frame, border_window(12, 8, tile_border(i, 3, 2)), cropped=i % 2 == 0)
             for i in range(6)]
    summary = merge_tiles(paths[::-1], tmp_path / "frame.exr")  # any order
    assert summary == {"tiles": 6, "width": 12, "height": 8, "channels": sorted(frame)}
    merged = read_exr(tmp_path / "frame.exr")
    for name, values in frame.items():
        np.testing.assert_array_equal(merged[name], values)
    [(_, attributes, _)] = read_exr_parts(tmp_path / "frame.exr")
    assert attributes["Frame"] == "1" and attributes["Note"] == "LazyVis: 6 tiles merged"


def test_merge_refuses_tiles_that_do_not_fit(tmp_path):
    frame = frame_channels()
    windows = [border_window(12, 8, tile_border(i, 2, 2)) for i in range(4)]
    good = [write_tile(tmp_path / f"t{i}.exr", frame, w) for i, w in enumerate(windows)]

    def refused(paths, message):
        with pytest.raises(TileError, match=message):
            merge_tiles(paths, tmp_path / "out.exr")
        assert not (tmp_path / "out.exr").exists()

    refused([], "no tiles")
    refused(good[:3], "12 x 8 frame exactly once: 24 pixels uncovered")
    refused(good + [good[0]], "24 covered twice")
    refused(good[:3] + [write_tile(tmp_path / "late.exr", frame, windows[3], frame_number="2")], "frame 2, but")
    refused(good[:3] + [write_tile(tmp_path / "bare.exr", frame, windows[3], note=False)], "does not say where")
    other = frame_channels(names=("R", "G", "B"))
    refused(good[:3] + [write_tile(tmp_path / "rgb.exr", other, windows[3])], r"missing \['A'\]")
    bigger = frame_channels(width=14)
    refused(good[:3] + [write_tile(tmp_path / "wide.exr", bigger, windows[3])], "of a 14 x 8 frame")
    (tmp_path / "junk.exr").write_bytes(b"not an exr")
    refused(good[:3] + [tmp_path / "junk.exr"], "not a readable OpenEXR")
    wrong = tmp_path / "wrong.exr"
    write_exr(wrong, {name: values[:3, :3] for name, values in frame.items()},
              attributes={"Frame": "1", "Note": tile_note(windows[3], 12, 8)})
    refused(good[:3] + [wrong], "3 x 3 pixels, neither its window")
    outside = tmp_path / "outside.exr"
    write_exr(outside, frame, attributes={"Frame": "1", "Note": tile_note((0, 0, 20, 8), 12, 8)})
    refused([outside], "outside its 12 x 8 frame")
