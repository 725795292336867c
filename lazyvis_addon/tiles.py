"""Tiles of a frame for render farms: which render border each tile is, the note that tells a tile's
place in its frame, and the merge of the tiles' EXR files into the frame's.

A tile is a Blender render border (Output Properties > Format > Render Region), rendered cropped or not.
Cropped, Blender's EXR is the border's size and says nothing of where it lies (its data window starts at
0, 0), so a tile render writes its place into the file's metadata: the render's stamp *Note*
(``use_stamp_note``), which Blender stores as the EXR header attribute ``Note`` whether or not the stamp
is burnt into the image, in single-layer and multilayer files alike. ``merge_tiles`` reads the notes back,
checks that the tiles agree and cover the frame exactly once, and writes the frame.

No bpy here: the command line (``lazyvis render --tiles``, ``lazyvis merge``) and the Blender operator that
a farm's ``--python-expr`` calls (``blender.operators``) share it. (The Dask backend, ``cluster``, tiles
the core's window in pixels and stitches arrays in memory: no files, no borders.)
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .core.exr import read_exr_parts, write_exr_parts

NOTE_PREFIX = "LazyVis tile"
_NOTE = re.compile(r"LazyVis tile (\d+) (\d+) (\d+) (\d+) of (\d+) x (\d+)")
_TILES = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


class TileError(ValueError):
    """Tiles that cannot be merged (the message names the file and what is wrong)."""


def parse_tiles(spec: str) -> tuple[int, int]:
    """``"4x3"`` -> (columns, rows), each 1 to 64; ValueError otherwise."""
    match = _TILES.match(spec or "")
    if not match:
        raise ValueError(f"tiles must be COLUMNSxROWS, such as 4x3, not {spec!r}")
    columns, rows = int(match.group(1)), int(match.group(2))
    if not (1 <= columns <= 64 and 1 <= rows <= 64):
        raise ValueError(f"tiles must be 1 to 64 each way, not {columns} x {rows}")
    return columns, rows


def tile_border(index: int, columns: int, rows: int) -> tuple[float, float, float, float]:
    """Blender's render border (min_x, max_x, min_y, max_y; fractions, y up) of tile ``index`` of a
    ``columns`` x ``rows`` grid, tiles numbered row by row from the top left. Neighbouring tiles share the
    fraction of their common edge, so ``border_window`` gives them one pixel edge: no gap, no overlap."""
    if not (0 <= index < columns * rows):
        raise ValueError(f"tile {index} is not one of the {columns} x {rows} = {columns * rows} tiles (0 to "
                         f"{columns * rows - 1})")
    row, column = divmod(index, columns)
    return (column / columns, (column + 1) / columns, 1.0 - (row + 1) / rows, 1.0 - row / rows)


def border_window(width: int, height: int, border: tuple[float, float, float, float] | None
                  ) -> tuple[int, int, int, int]:
    """Core pixel window (x0, y0, x1, y1), rows counted from the top, of Blender's render border.

    ``border`` = (min_x, max_x, min_y, max_y) as fractions with y up (Blender's), or None. Blender
    truncates ``fraction * size`` computed in float32 to whole pixels (measured: the render result has
    exactly this size; in float64, 7/96 * 96 truncates to 6 where Blender's float32 product gives 7).
    """
    if border is None:
        return (0, 0, width, height)
    min_x, max_x, min_y, max_y = (np.float32(v) for v in border)
    x0, x1 = int(min_x * np.float32(width)), int(max_x * np.float32(width))
    bottom, top = int(min_y * np.float32(height)), int(max_y * np.float32(height))
    if x1 <= x0 or top <= bottom:
        raise ValueError(f"the render border selects no pixels of the {width} x {height} image; "
                         "make it larger or turn Render Region off")
    return (x0, height - top, x1, height - bottom)


def apply_tile(render, index: int, columns: int, rows: int) -> tuple[int, int, int, int]:
    """Make Blender's render settings ``render`` (``scene.render``) render tile ``index`` of ``columns`` x
    ``rows``: the render border, cropped, and the stamp note that tells the tile's place
    (``tile_note``). Returns the tile's window at the settings' resolution."""
    border = tile_border(index, columns, rows)
    render.use_border = True
    render.use_crop_to_border = True
    render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y = border
    # Blender's own rounding of the scaled resolution (integer percent of whole pixels).
    width = render.resolution_x * render.resolution_percentage // 100
    height = render.resolution_y * render.resolution_percentage // 100
    window = border_window(width, height, border)
    render.use_stamp_note = True
    render.stamp_note_text = tile_note(window, width, height)
    return window


def tile_note(window: tuple[int, int, int, int], width: int, height: int) -> str:
    """The stamp note of a tile: its window (x0 y0 x1 y1, rows from the top, ends exclusive) in a frame
    of ``width`` x ``height`` pixels."""
    return f"{NOTE_PREFIX} {window[0]} {window[1]} {window[2]} {window[3]} of {width} x {height}"


def parse_note(note: str | None) -> tuple[tuple[int, int, int, int], tuple[int, int]] | None:
    """(window, (width, height)) of a ``tile_note``, or None if ``note`` is not one."""
    match = _NOTE.search(note or "")
    if not match:
        return None
    x0, y0, x1, y1, width, height = (int(v) for v in match.groups())
    return (x0, y0, x1, y1), (width, height)


def _tile(path: Path):
    """A tile file's parts (``read_exr_parts``), window and frame size, checked against each other, and
    whether it is cropped to its window."""
    try:
        parts = read_exr_parts(path)
    except (OSError, RuntimeError, ValueError) as error:
        raise TileError(f"{path}: not a readable OpenEXR file ({error})") from None
    notes = [attributes["Note"] for _, attributes, _ in parts if "Note" in attributes]
    place = parse_note(notes[0] if notes else None)
    if place is None:
        raise TileError(f"{path}: the file does not say where it lies in the frame (no '{NOTE_PREFIX} ...' "
                        "note): render tiles with 'lazyvis render --tiles', the LazyVis Flamenco job or "
                        "bpy.ops.lazyvis.set_tile")
    (x0, y0, x1, y1), (width, height) = place
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        raise TileError(f"{path}: its note places it at {x0} {y0} {x1} {y1}, outside its {width} x {height} frame")
    shapes = {values.shape for _, _, channels in parts for values in channels.values()}
    if shapes == {(y1 - y0, x1 - x0)}:
        cropped = True
    elif shapes == {(height, width)}:
        cropped = False
    else:
        listed = ", ".join(f"{shape[1]} x {shape[0]}" for shape in sorted(shapes))
        raise TileError(f"{path}: {listed} pixels, neither its window ({x1 - x0} x {y1 - y0}) nor its frame "
                        f"({width} x {height})")
    return parts, (x0, y0, x1, y1), (width, height), cropped


def _layout(parts) -> list[tuple[str, list[str]]]:
    """(part name, sorted channel names) of each part: what tiles of one frame share."""
    return [(name, sorted(channels)) for name, _, channels in parts]


def _frame_number(parts) -> str | None:
    return next((attributes["Frame"] for _, attributes, _ in parts if "Frame" in attributes), None)


def merge_tiles(paths, output) -> dict:
    """Stitch tile EXRs (cropped or not, single-layer or Blender's multi-part multilayer, any passes) into
    the frame's EXR.

    Every tile must carry a ``tile_note``; all must name one frame size, the same parts and channels and the
    same frame number (the header's ``Frame``, where Blender wrote one), and their windows must cover the
    frame exactly once. Writes 32-bit float channels with ZIP compression, in the tiles' parts with the
    first tile's metadata (its Note replaced by what was merged). Returns {"tiles", "width", "height",
    "channels"}.

    Raises
    ------
    TileError   no tiles, an unreadable or unplaced tile, tiles that disagree, a gap or an overlap.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise TileError("no tiles to merge")
    merged = counts = first_path = layout = size = number = None
    for path in paths:  # tiles: a handful to a few hundred, each read once
        parts, (x0, y0, x1, y1), tile_size, cropped = _tile(path)
        if merged is None:
            first_path, layout, size, number = path, _layout(parts), tile_size, _frame_number(parts)
            merged = [(name, dict(attributes), {channel: np.zeros((size[1], size[0]), np.float32)
                                                for channel in channels}) for name, attributes, channels in parts]
            counts = np.zeros((size[1], size[0]), np.int32)
        if tile_size != size:
            raise TileError(f"{path}: a tile of a {tile_size[0]} x {tile_size[1]} frame, but {first_path} is of "
                            f"a {size[0]} x {size[1]} one")
        if _layout(parts) != layout:
            have = {channel for _, names in layout for channel in names}  # multilayer names carry their part
            got = {channel for _, names in _layout(parts) for channel in names}
            raise TileError(f"{path}: other passes or channels than {first_path} (missing "
                            f"{sorted(have - got) or 'none'}, extra {sorted(got - have) or 'none'}): render every "
                            "tile with the same passes")
        if _frame_number(parts) != number:
            raise TileError(f"{path}: frame {_frame_number(parts)}, but {first_path} is frame {number}")
        for (_, _, channels), (_, _, target) in zip(parts, merged):  # parts: a handful
            for name, values in channels.items():
                target[name][y0:y1, x0:x1] = values if cropped else values[y0:y1, x0:x1]
        counts[y0:y1, x0:x1] += 1
    if (counts != 1).any():
        over, gap = int((counts > 1).sum()), int((counts == 0).sum())
        where = np.argwhere(counts != 1)[0]
        raise TileError(f"the tiles do not cover the {size[0]} x {size[1]} frame exactly once: {gap} pixels "
                        f"uncovered, {over} covered twice or more (first at x {where[1]}, y {where[0]} from "
                        "the top)")
    for _, attributes, _ in merged:
        if "Note" in attributes:
            attributes["Note"] = f"LazyVis: {len(paths)} tiles merged"
    write_exr_parts(os.fspath(output), merged)
    return {"tiles": len(paths), "width": size[0], "height": size[1],
            "channels": [channel for _, names in layout for channel in names]}
