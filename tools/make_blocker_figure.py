"""The blocker map as a picture (issue 19): a sample render, its Blocker Count in false colour (the paper's
Fig. 4) and where its lights are partly or wholly hidden, side by side in one PNG.

    .venv/bin/python tools/make_blocker_figure.py                     # -> docs/blocker_map.png, 320 px panels
    .venv/bin/python tools/make_blocker_figure.py --blend sample_blends/tree.blend --width 256 --out tree.png

The .blend is rendered by the core at its own LazyVis settings (the engine's ``settings_from_scene``), once
with the default Silhouettes visibility and once with Blocker Map (``--no-blocker-map`` skips it). Panels,
left to right, each titled, with a legend below:
1. Combined: the image, linear to sRGB, clipped (Blender's "Standard" view).
2. Blocker Count with Silhouettes: the silhouette arcs crossing the pixel's lights.
3. Blocker Count with Blocker Map: the blocker-light pairs stored per pixel (the paper's Fig. 4).
   Both counts in false colour: black where 0, otherwise a viridis ramp over log(count) from 1 to the
   panel's largest count (each panel has its own scale, printed under it).
4. Detection, from the Silhouettes render (exact: no missed blockers): per pixel, whether some light is
   wholly hidden (umbra: the render's ``umbra`` pass), else whether some light is partly hidden (penumbra:
   silhouette arcs cross a light that is not wholly hidden), else every light it faces is seen whole.
   A pixel in one light's umbra and another's penumbra shows as umbra. Nothing seen: black.
Blocker Count and umbra are taken at the pixel centres; only the Combined image is anti-aliased.

The labels are drawn with Blender's font module (``blf`` into an ``imbuf``, no display needed) and laid
over the picture in numpy; without bpy the picture is written without them. The PNG is written by the
core's own writer (``lazyvis_addon.core.png``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from lazyvis_addon.core import BACKGROUND_DEPTH, RenderOutput, render  # noqa: E402
from lazyvis_addon.core.png import linear_to_srgb8, write_png  # noqa: E402

DEFAULT_BLEND = ROOT / "sample_blends" / "floating_boxes.blend"
DEFAULT_OUT = ROOT / "docs" / "blocker_map.png"

# Viridis (matplotlib's perceptual map) at nine evenly spaced points, 0..255 sRGB; interpolated linearly
# between them, which stays within a unit or two of the full table.
VIRIDIS = np.array([[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
                    [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]], np.float64)

# Detection classes and their colours: distinct in luminance as well as hue (grey ~110, amber ~190, red
# ~80), so they stay apart for colour-blind readers; red for umbra as in the paper's Fig. 4.
NOTHING, VISIBLE, PENUMBRA, UMBRA = 0, 1, 2, 3
DETECTION_COLOURS = np.array([[0, 0, 0], [110, 110, 120], [240, 190, 40], [200, 40, 40]], np.uint8)
DETECTION_NAMES = ("nothing seen", "unoccluded", "penumbra", "umbra")

BACKDROP = np.array([48, 48, 48], np.uint8)   # between and around the panels (lighter than the 0 swatch)
TEXT_COLOUR = np.array([235, 235, 235], np.float64)
GAP = 4                                       # pixels between panels


def false_colour(count: np.ndarray) -> tuple[np.ndarray, int]:
    """Blocker Count (H, W) int -> ((H, W, 3) uint8, top): black where 0, else viridis over
    log(count) / log(top), top the largest count (at least 2, so that one count still has a scale)."""
    top = max(int(count.max()), 2)
    t = np.log(np.maximum(count, 1)) / np.log(top)
    colour = viridis(t)
    colour[count <= 0] = 0
    return colour, top


def viridis(t: np.ndarray) -> np.ndarray:
    """(...) float in [0, 1] -> (..., 3) uint8 from the VIRIDIS table, linearly interpolated."""
    position = np.clip(t, 0.0, 1.0) * (len(VIRIDIS) - 1)
    low = np.minimum(position.astype(np.int64), len(VIRIDIS) - 2)
    weight = (position - low)[..., None]
    return np.round(VIRIDIS[low] * (1.0 - weight) + VIRIDIS[low + 1] * weight).astype(np.uint8)


def detection_classes(output: RenderOutput) -> np.ndarray:
    """(H, W) uint8 class per pixel of a Silhouettes render: UMBRA where some light is wholly hidden,
    PENUMBRA where silhouette arcs cross a light (Blocker Count > 0) and none is wholly hidden, VISIBLE
    elsewhere on a surface, NOTHING where no surface is seen.

    Why arcs mean "partly hidden": an arc is the outline of a blocker as seen from the point, crossing the
    light, so some of the light is behind the blocker and some is not, unless other blockers hide the rest,
    and then the light is wholly hidden and the ``umbra`` pass has it. With the Blocker Map visibility the
    count is pairs whose blocker may overlap the light (flooded a pixel beyond the penumbra), so this
    reading holds for Silhouettes only."""
    seen = output.depth < BACKGROUND_DEPTH
    umbra = output.umbra.any(axis=2)
    return np.select([~seen, umbra, output.blocker_count > 0], [NOTHING, UMBRA, PENUMBRA], VISIBLE).astype(np.uint8)


@dataclass
class Panel:
    """One panel: its title, picture (H, W, 3) uint8 and legend (``kind``: "text", "scale" or "classes";
    ``value``: the text, the scale's top count, or None)."""

    title: str
    picture: np.ndarray
    kind: str
    value: object = None


@dataclass
class Figure:
    """The composed picture (FH, FW, 3) uint8, the labels to lay over it (x, baseline y from the top, font
    size, text, alignment: x is the text's "left" end, "centre" or "right" end) and where each panel's
    picture is: (row, column) of its top-left corner."""

    picture: np.ndarray
    labels: list
    corners: list


def panels(silhouettes: RenderOutput, blocker_map: RenderOutput | None, caption: str) -> list[Panel]:
    """The figure's panels from a Silhouettes render and, optionally, a Blocker Map render of one scene."""
    result = [Panel("Combined", linear_to_srgb8(silhouettes.combined[..., :3]), "text", caption)]
    picture, top = false_colour(silhouettes.blocker_count)
    result.append(Panel("Blocker Count: silhouette arcs", picture, "scale", top))
    if blocker_map is not None:
        picture, top = false_colour(blocker_map.blocker_count)
        result.append(Panel("Blocker Map pairs (Fig. 4)", picture, "scale", top))
    result.append(Panel("Detection", DETECTION_COLOURS[detection_classes(silhouettes)], "classes"))
    return result


def compose(parts: list[Panel]) -> Figure:
    """Panels side by side on the backdrop, a title strip above each and a legend strip below."""
    height, width = parts[0].picture.shape[:2]
    size = max(6, round(width / 27))          # font size: 12 px at 320 px panels
    title_h, legend_h = round(1.8 * size), round(3.2 * size)
    total_w = len(parts) * width + (len(parts) + 1) * GAP
    picture = np.empty((title_h + height + legend_h, total_w, 3), np.uint8)
    picture[:] = BACKDROP
    labels, corners = [], []
    bar_h = max(2, round(0.9 * size))
    bar_top = title_h + height + max(1, round(0.4 * size))
    text_base = bar_top + bar_h + round(1.2 * size)
    for index, part in enumerate(parts):
        x0 = GAP + index * (width + GAP)
        picture[title_h:title_h + height, x0:x0 + width] = part.picture
        corners.append((title_h, x0))
        labels.append((x0 + 2, title_h - round(0.5 * size), size, part.title, "left"))
        if part.kind == "text":
            labels.append((x0 + 2, bar_top + round(0.9 * size), size - 1, part.value, "left"))
        elif part.kind == "scale":
            # A black swatch for 0, then the ramp from 1 to the top count, ticks at 1, ~sqrt(top) and top.
            swatch = max(2, width // 12)
            ramp = width - 2 * swatch
            picture[bar_top:bar_top + bar_h, x0:x0 + swatch] = 0
            picture[bar_top:bar_top + bar_h, x0 + 2 * swatch:x0 + width] = viridis(np.linspace(0.0, 1.0, ramp))[None]
            top = int(part.value)
            middle = int(round(np.sqrt(top)))
            labels.append((x0 + swatch // 2, text_base, size - 1, "0", "centre"))
            labels.append((x0 + 2 * swatch, text_base, size - 1, "1", "left"))
            if 1 < middle < top:
                offset = int(round(np.log(middle) / np.log(top) * (ramp - 1)))
                labels.append((x0 + 2 * swatch + offset, text_base, size - 1, str(middle), "centre"))
            labels.append((x0 + width, text_base, size - 1, str(top), "right"))
        else:
            step = width // 3
            swatch = max(2, size)
            for slot, kind in enumerate((VISIBLE, PENUMBRA, UMBRA)):
                sx = x0 + slot * step
                picture[bar_top:bar_top + bar_h, sx:sx + swatch] = DETECTION_COLOURS[kind]
                labels.append((sx + swatch + 3, bar_top + bar_h, size - 1, DETECTION_NAMES[kind], "left"))
    return Figure(picture, labels, corners)


def text_layer(shape: tuple[int, int], labels: list) -> np.ndarray | None:
    """(H, W) float32 coverage 0..1 of ``labels`` (``Figure.labels``) drawn with Blender's bundled Inter
    font, or None without bpy. Left-aligned text longer than the space to the next label on its row (or
    the picture's edge) is cut short."""
    try:
        import blf
        import bpy
        import imbuf
    except ImportError:
        return None
    height, width = shape
    font_path = str(Path(bpy.utils.system_resource("DATAFILES")) / "fonts" / "Inter.woff2")
    font = blf.load(font_path)
    if font < 0:
        return None
    buffer = imbuf.new((width, height))
    # Each label's room: up to the next label starting on the same row, or the edge.
    rooms = []
    for x, y, _, _, _ in labels:
        after = [other[0] for other in labels if other[1] == y and other[0] > x]
        rooms.append(min(after, default=width) - x - 2)
    # ``draw_buffer``: plain ``draw`` into a bound ImBuf crashed bpy 5.0.1 headless (no GPU context).
    with blf.bind_imbuf(font, buffer):
        blf.color(font, 1.0, 1.0, 1.0, 1.0)
        for (x, y, size, text, align), room in zip(labels, rooms):
            blf.size(font, size)
            while align == "left" and text and blf.dimensions(font, text)[0] > room:
                text = text[:-1]
            shift = {"left": 0.0, "centre": 0.5, "right": 1.0}[align] * blf.dimensions(font, text)[0]
            blf.position(font, round(x - shift), height - y, 0)   # an ImBuf's rows go up from the bottom
            blf.draw_buffer(font, text)
    with tempfile.TemporaryDirectory() as folder:
        path = str(Path(folder) / "labels.png")
        imbuf.write(buffer, filepath=path)
        image = bpy.data.images.load(path)
        try:
            pixels = np.array(image.pixels[:], np.float32).reshape(height, width, image.channels)
        finally:
            bpy.data.images.remove(image)
    blf.unload(font_path)
    return np.ascontiguousarray(pixels[::-1, :, 0])   # white text: red is its coverage; rows top first


def labelled(figure: Figure) -> np.ndarray:
    """The figure's picture with its labels blended over it (unchanged without bpy)."""
    coverage = text_layer(figure.picture.shape[:2], figure.labels)
    if coverage is None:
        return figure.picture
    mixed = figure.picture * (1.0 - coverage[..., None]) + TEXT_COLOUR * coverage[..., None]
    return np.round(mixed).astype(np.uint8)


def load_blend(path: Path, width: int):
    """(core Scene, Settings) of a .blend at ``width`` pixels, the height from its aspect, through bpy
    (bench_geometry's loader: the engine's exporter and ``settings_from_scene``)."""
    sys.path[:0] = [str(ROOT / "bench"), str(ROOT / "tools")]
    from bench_geometry import load_blend as bench_load_blend
    return bench_load_blend(Path(path), width, None)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blend", type=Path, default=DEFAULT_BLEND, help="the .blend (default floating_boxes)")
    parser.add_argument("--width", type=int, default=320, help="each panel's width in pixels (default 320)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the PNG (default docs/blocker_map.png)")
    parser.add_argument("--no-blocker-map", action="store_true", help="skip the Blocker Map render and panel")
    args = parser.parse_args(argv)
    scene, settings = load_blend(args.blend, args.width)
    height, width = scene.camera.window_shape
    started = time.perf_counter()
    silhouettes = render(scene, settings.replace(visibility="silhouettes"))
    blocker_map = None if args.no_blocker_map else render(scene, settings.replace(visibility="blocker_map"))
    seconds = time.perf_counter() - started
    caption = f"{args.blend.stem}, {width} x {height}, {scene.light_count} lights"
    figure = compose(panels(silhouettes, blocker_map, caption))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_png(args.out, labelled(figure))
    classes = np.bincount(detection_classes(silhouettes).ravel(), minlength=4) / (height * width)
    shares = ", ".join(f"{name} {100 * share:.1f} %" for name, share in zip(DETECTION_NAMES, classes))
    counts = f"most arcs {silhouettes.blocker_count.max()}"
    if blocker_map is not None:
        counts += f", most pairs {blocker_map.blocker_count.max()}"
    print(f"{caption}: rendered in {seconds:.1f} s; {counts}; {shares}")
    print(f"Saved: '{args.out}' ({args.out.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
