"""``lazyvis``: render .blend files with the LazyVis engine through bpy (Blender as a Python module).

    lazyvis render scene.blend -f 1 -o out.exr            # frame 1 -> out.exr
    lazyvis render scene.blend -a -o out/frame_####.exr   # the file's frame range, out/frame_0001.exr, ...
    lazyvis render scene.blend -s 10 -e 20 -o out/f##.exr --png out/f##.png --resolution-percentage 25
    lazyvis compare scene.blend -o compare.png --json compare.json   # against Cycles (``compare``)
    lazyvis render scene.blend -f 1 --tiles 4x2 --tile 5 -o tiles/t5.exr  # one tile, for a farm
    lazyvis merge tiles/t*.exr -o frame.exr                          # stitch the tiles (``tiles``)
    lazyvis render scene.blend -a --tiles 2x2 --scheduler tcp://host:8786 -o out/f_####.exr  # Dask

does what ``blender -b scene.blend -E LAZYVIS -f 1 -o out.exr`` does with a Blender install: the add-on
is registered, the file opened, its scene's engine set to LAZYVIS, the frame set and rendered (compositor
and sequencer as the file has them), and the render result written. The output is always OpenEXR with
32-bit float channels, scene-linear:

- by default a single-part **RGBA** EXR of the final image (channels R, G, B, A; ZIP), as Blender writes
  with File Format OpenEXR, Color RGBA, Float (Full);
- with ``--multilayer`` a **multilayer** EXR with every pass of every view layer
  (``ViewLayer.Combined.R``, ``ViewLayer.Depth.Z``, ``ViewLayer.Blocker Count.X``, ...).

Output paths follow Blender: the last run of ``#`` becomes the frame number padded to its length
(``f_###.exr`` -> ``f_007.exr``), ``//`` is the .blend file's folder. A path without ``#`` is used as given
for a single frame; for several frames the four-digit frame number goes before its ``.exr`` extension
(``out.exr`` -> ``out0001.exr``, ...); a folder gets ``0001.exr``, ... in it. Without ``-o`` the file's
own output path is used exactly as Blender would (Output Properties > Output, with the ``.exr`` extension
added when File Extensions is on).

Frames (Blender's ``-f`` syntax): ``-f 3``, ``-f 1,4,9``, ``-f 1..5``, ``-f +2`` (frame start + 2),
``-f -1`` (frame end - 1). ``-a`` renders frame start to end by frame step; ``-s``/``-e``/``-j`` set start,
end and step (alone, they imply ``-a``). Neither ``-f`` nor ``-a``: the file's current frame.

A progress bar shows on the terminal (stderr); Blender's own messages (warnings of the engine) go to
stdout. Errors are one line on stderr and a non-zero exit status: 1 for a missing or unreadable file and
for render errors (the engine's report), 2 for bad arguments, 130 when interrupted (Ctrl-C cancels the
render; the frame being rendered is not written).

bpy is imported only inside the functions that render, so ``lazyvis --help`` is instant.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import sys
import time
from pathlib import Path

from .core.progress import Progress
from .tiles import TileError, apply_tile, merge_tiles, parse_tiles

PROG = "lazyvis"
ENGINE_ID = "LAZYVIS"  # lazyvis_addon.blender.engine.ENGINE_ID, without importing bpy for --help
# First bytes of .blend files: plain, gzip-compressed (before Blender 3.0) and zstd-compressed.
BLEND_MAGIC = (b"BLENDER", b"\x1f\x8b", b"\x28\xb5\x2f\xfd")
FRAME_LIMIT = 1048574  # Blender's MAXFRAME


class CliError(Exception):
    """A problem to report as one line and exit status 1 (missing file, render error, ...)."""


class Interrupted(Exception):
    """Ctrl-C during a render."""


# -- pure helpers (no bpy) ------------------------------------------------------------------------------------



def resident_memory_mb() -> float | None:
    """This process's resident memory now, in MB (Linux ``/proc/self/statm``), else the peak so far
    (``getrusage``), else None: printed per frame, as Blender prints ``Mem:``, so that a long animation
    shows whether memory creeps."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except (OSError, ValueError, IndexError, AttributeError):
        pass
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2 ** 20 if sys.platform == "darwin" else peak / 1024  # bytes on macOS, KB on Linux

def parse_frames(spec: str, start: int, end: int) -> list[int]:
    """Frames of Blender's ``-f`` argument: ``N``, ``+N`` (start + N), ``-N`` (end - N), ``A..B``, comma lists.

    Raises
    ------
    ValueError  an item that is not a frame or a range.
    """
    def frame(text: str) -> int:
        text = text.strip()
        if not re.fullmatch(r"[+-]?\d+", text):
            raise ValueError(f"'{text}' is not a frame number")
        value = start + int(text[1:]) if text.startswith("+") else end - int(text[1:]) if text.startswith("-") \
            else int(text)
        return max(-FRAME_LIMIT, min(FRAME_LIMIT, value))

    frames: list[int] = []
    for item in spec.split(","):
        if ".." in item:
            first, last = (frame(part) for part in item.split("..", 1))
            if last < first:
                raise ValueError(f"the range '{item}' ends before it starts")
            frames.extend(range(first, last + 1))
        else:
            frames.append(frame(item))
    return frames


def substitute_frame(pattern: str, frame: int) -> str:
    """Blender's rule: the last run of ``#`` becomes the frame number, zero-padded to the run's length."""
    runs = list(re.finditer(r"#+", pattern))
    if not runs:
        return pattern
    run = runs[-1]
    number = f"{frame:0{len(run.group())}d}" if frame >= 0 else f"-{-frame:0{len(run.group()) - 1}d}"
    return pattern[:run.start()] + number + pattern[run.end():]


def output_pattern(output: str, several_frames: bool, blend_dir: Path) -> str:
    """The ``#`` pattern for ``-o``: absolute (``//`` = the .blend's folder), with ``####`` added before
    the .exr extension when several frames would otherwise go to one file."""
    folder = output.endswith(("/", os.sep)) or os.path.isdir(output)
    if output.startswith("//"):
        path = str(blend_dir / output[2:])
    else:
        path = os.path.abspath(os.path.expanduser(output))
    if folder:  # a folder: frame-numbered files in it, as Blender names them
        return os.path.join(path, "####.exr")
    if several_frames and "#" not in os.path.basename(path):
        stem, extension = os.path.splitext(path)
        path = stem + "####" + extension if extension.lower() == ".exr" else path + "####"
    return path


def is_blend_file(path: Path) -> bool:
    with open(path, "rb") as handle:
        head = handle.read(8)
    return head.startswith(BLEND_MAGIC)


# -- terminal progress ---------------------------------------------------------------------------------------


class TerminalProgress(Progress):
    """A progress bar on a terminal, one line per stage otherwise (logs); Ctrl-C cancels.

    Warnings are printed by Blender itself (the engine reports them); the bar only makes room for them.
    """

    WIDTH = 30

    def __init__(self, stream=None, tty: bool | None = None) -> None:
        super().__init__()
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.columns = max(20, min(100, shutil.get_terminal_size((100, 24)).columns - 1))
        self.prefix = ""
        self.cancelled = False
        self._drawn = False
        self._last = 0.0
        self._logged: set[tuple[str, str]] = set()

    def on_stage(self, name: str, total: int) -> None:
        if self.tty:
            self._draw(f"{self.prefix}{name}")
            self._last = 0.0  # the stage's bar shows at its first advance
        elif (self.prefix, name) not in self._logged:  # a log names a stage once, not once per band of rows
            self._logged.add((self.prefix, name))
            self.stream.write(f"{self.prefix}{name}\n")
            self.stream.flush()

    def on_advance(self, name: str, done: int, total: int) -> None:
        now = time.monotonic()
        if not self.tty or not total or (now - self._last < 0.1 and done < total):
            return
        self._last = now
        filled = int(self.WIDTH * min(done / total, 1.0))
        self._draw(f"{self.prefix}{name:<20s} [{'#' * filled}{'.' * (self.WIDTH - filled)}] "
                   f"{100.0 * min(done / total, 1.0):5.1f}%")

    def on_warning(self, message: str) -> None:
        self.clear()

    def is_cancelled(self) -> bool:
        return self.cancelled

    def _draw(self, text: str) -> None:
        text = text[:self.columns]  # one terminal line, or \r cannot redraw it
        self.stream.write("\r" + text.ljust(self.columns if self._drawn else len(text)))
        self.stream.flush()
        self._drawn = True

    def clear(self) -> None:
        """Wipe the bar so that the next line starts clean."""
        if self._drawn:
            self.stream.write("\r" + " " * self.columns + "\r")
            self.stream.flush()
            self._drawn = False


# -- rendering (imports bpy) ---------------------------------------------------------------------------------


def configure_output(render, multilayer: bool) -> None:
    """``render.image_settings``: OpenEXR, 32-bit float, ZIP; RGBA single layer or every pass (multilayer)."""
    settings = render.image_settings
    if hasattr(settings, "media_type"):  # Blender 5.0
        settings.media_type = "MULTI_LAYER_IMAGE" if multilayer else "IMAGE"
        settings.file_format = "OPEN_EXR_MULTILAYER" if multilayer else "OPEN_EXR"
    else:
        settings.file_format = "OPEN_EXR_MULTILAYER" if multilayer else "OPEN_EXR"
    if not multilayer:
        settings.color_mode = "RGBA"
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"


def _register_addon():
    """Register the add-on unless it already is (an extension enabled in this bpy); returns the undo."""
    import lazyvis_addon
    from lazyvis_addon.blender.engine import LazyVisRenderEngine

    if LazyVisRenderEngine.is_registered:
        return lambda: None
    lazyvis_addon.register()
    return lazyvis_addon.unregister


def _error_text(error: BaseException) -> str:
    """Blender's operator errors read 'Error: message\\n'; keep the message."""
    text = str(error).strip()
    for prefix in ("Error: ", "error: "):
        if text.startswith(prefix):
            text = text[len(prefix):]
    return " ".join(text.split("\n")) or type(error).__name__


def apply_overrides(scene, args: argparse.Namespace) -> None:
    """The command line's overrides of ``scene`` (a bpy Scene), as Blender's own flags set them: the engine,
    --resolution, --resolution-percentage, -t (0: Blender's automatic thread count), -s, -e, -j."""
    render = scene.render
    render.engine = ENGINE_ID
    if args.resolution:
        render.resolution_x, render.resolution_y = args.resolution
    if args.resolution_percentage is not None:
        render.resolution_percentage = args.resolution_percentage
    if args.threads is not None:
        render.threads_mode = "AUTO" if args.threads == 0 else "FIXED"
        if args.threads > 0:
            render.threads = args.threads
    if args.frame_start is not None:
        scene.frame_start = args.frame_start
    if args.frame_end is not None:
        scene.frame_end = args.frame_end
    if args.frame_jump is not None:
        scene.frame_step = args.frame_jump


def checked_blend(file: str) -> Path:
    """The .blend ``file`` names, checked readable (else a CliError), with bpy importable."""
    blend = Path(file).expanduser()
    if not blend.exists():
        raise CliError(f"no such file: {file}")
    if blend.is_dir():
        raise CliError(f"{file} is a folder, not a .blend file")
    try:
        readable = is_blend_file(blend)
    except OSError as error:
        raise CliError(f"cannot read {file}: {error.strerror or error}") from None
    if not readable:
        raise CliError(f"{file} is not a .blend file")
    try:
        import bpy  # noqa: F401
    except ImportError as error:
        raise CliError(f"{PROG} needs Blender as a Python module (pip install bpy): {error}") from None
    return blend


def render_command(args: argparse.Namespace) -> int:
    client = None
    if args.scheduler:  # first: a local cluster's workers must not inherit bpy's sys.path
        client = _cluster_client(args)
    try:
        return _render_command(args, client)
    finally:
        if client is not None:
            from . import cluster
            cluster.close(client)


def _cluster_client(args: argparse.Namespace):
    """The Dask client of --scheduler (a LocalCluster of --workers processes for 'local'), or a CliError."""
    try:
        from . import cluster
        return cluster.connect(args.scheduler, args.workers or 2)
    except RuntimeError as error:
        raise CliError(str(error)) from None
    except (OSError, TimeoutError) as error:
        raise CliError(f"cannot reach the scheduler {args.scheduler}: {error}") from None


def _render_command(args: argparse.Namespace, client) -> int:
    blend = checked_blend(args.file)
    import bpy
    from .blender import engine as engine_module
    from .core.exr import read_exr
    from .core.png import linear_to_srgb8, write_png

    unregister = _register_addon()
    progress = TerminalProgress()
    engine_module.observers.append(progress)
    local_core = engine_module.core_render
    queue = None
    previous_handler = signal.getsignal(signal.SIGINT)

    def interrupt(signum, frame):  # first Ctrl-C: cancel the render cleanly; second: stop at once
        progress.cancelled = True
        signal.signal(signal.SIGINT, signal.default_int_handler)

    try:
        try:
            bpy.ops.wm.open_mainfile(filepath=str(blend.resolve()), load_ui=False)
        except RuntimeError as error:
            raise CliError(f"cannot open {args.file}: {_error_text(error)}") from None
        if args.scene:
            scene = bpy.data.scenes.get(args.scene)
            if scene is None:
                names = ", ".join(s.name for s in bpy.data.scenes)
                raise CliError(f"{args.file} has no scene '{args.scene}' (it has: {names})")
            if bpy.context.window is not None:
                bpy.context.window.scene = scene
        else:
            scene = bpy.context.scene
        render = scene.render
        apply_overrides(scene, args)

        if args.frames is not None:
            try:
                frames = parse_frames(args.frames, scene.frame_start, scene.frame_end)
            except ValueError as error:
                raise CliError(f"-f {args.frames}: {error}") from None
        elif args.animation or args.frame_start is not None or args.frame_end is not None:
            if scene.frame_end < scene.frame_start:
                raise CliError(f"the frame range {scene.frame_start}..{scene.frame_end} is empty")
            frames = list(range(scene.frame_start, scene.frame_end + 1, max(scene.frame_step, 1)))
        else:
            frames = [scene.frame_current]

        configure_output(render, args.multilayer)
        blend_dir = blend.resolve().parent
        several = len(frames) > 1
        if args.output:
            pattern = output_pattern(args.output, several, blend_dir)
        else:
            pattern = None  # the file's own output path, resolved by Blender per frame
        png_pattern = output_pattern(args.png, several, blend_dir) if args.png else None

        signal.signal(signal.SIGINT, interrupt)
        width = render.resolution_x * render.resolution_percentage // 100
        height = render.resolution_y * render.resolution_percentage // 100
        columns, rows = parse_tiles(args.tiles) if args.tiles else (1, 1)
        if client is not None:  # the engine's core render goes to the cluster, tiles and frames ahead
            from .cluster import FrameQueue
            queue = FrameQueue(client, columns, rows)
            engine_module.core_render = queue
            ahead, sent = queue.frames_ahead(), 0
        if args.tile is not None:  # one tile of the frame: a farm's task; 'lazyvis merge' stitches them
            try:
                window = apply_tile(render, args.tile, columns, rows)
            except ValueError as error:
                raise CliError(f"--tile {args.tile}: {error}") from None
            width, height = window[2] - window[0], window[3] - window[1]

        def render_now(frame: int) -> None:
            """Blender's render of the current frame (its report a CliError; Ctrl-C: Interrupted)."""
            try:
                bpy.ops.render.render(scene=scene.name)
            except RuntimeError as error:
                raise CliError(f"frame {frame}: {_error_text(error)}") from None
            finally:
                progress.clear()
            if progress.cancelled:
                raise Interrupted()

        def render_to(path: str, frame: int) -> None:
            render_now(frame)
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            result = bpy.data.images.get("Render Result")
            if result is None:
                raise CliError(f"frame {frame}: Blender produced no render result")
            try:
                result.save_render(filepath=path, scene=scene)
            except RuntimeError as error:
                raise CliError(f"frame {frame}: cannot write {path}: {_error_text(error)}") from None

        for index, frame in enumerate(frames):
            progress.prefix = f"Frame {frame} ({index + 1}/{len(frames)}) | " if several else f"Frame {frame} | "
            if queue is not None:
                while sent < len(frames) and sent <= index + ahead:  # frames ahead, exported and sent
                    scene.frame_set(frames[sent])
                    queue.begin(frames[sent], submitting=True)
                    render_now(frames[sent])  # its placeholder result is not saved
                    sent += 1
                queue.begin(frame, submitting=False)
            scene.frame_set(frame)
            path = substitute_frame(pattern, frame) if pattern else render.frame_path(frame=frame)
            started = time.perf_counter()
            if args.tiles and args.tile is None and queue is None:  # every tile in turn, merged: the frame
                render_tiles(render, columns, rows, path, frame, render_to, progress)
            else:
                render_to(path, frame)
            seconds = time.perf_counter() - started
            memory = resident_memory_mb()
            print(f"Saved: '{path}' (frame {frame}, {width} x {height}, {seconds:.2f} s"
                  + (f", Mem: {memory:.1f} MB)" if memory is not None else ")"), flush=True)
            if png_pattern:
                png = substitute_frame(png_pattern, frame)
                Path(png).parent.mkdir(parents=True, exist_ok=True)
                write_png(png, linear_to_srgb8(combined_rgb(read_exr(path))))
                print(f"Saved: '{png}' (preview, sRGB)", flush=True)
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        progress.clear()
        engine_module.observers.remove(progress)
        engine_module.core_render = local_core
        if queue is not None:
            queue.cancel_all()
        unregister()
    return 0


def render_tiles(render, columns: int, rows: int, path: str, frame: int, render_to, progress) -> None:
    """Render the frame as ``columns`` x ``rows`` tiles (``tiles.apply_tile``), each to a file beside
    ``path``, merge them into ``path`` (``tiles.merge_tiles``) and remove the tiles' files. The image is the
    whole frame's, bit for bit: a tile renders the margin its anti-aliasing reads."""
    folder = Path(path).parent / f".{Path(path).name}.tiles"
    folder.mkdir(parents=True, exist_ok=True)
    prefix = progress.prefix
    paths = []
    try:
        for tile in range(columns * rows):  # tiles: a handful
            apply_tile(render, tile, columns, rows)
            progress.prefix = f"{prefix}Tile {tile + 1}/{columns * rows} | "
            paths.append(str(folder / f"tile_{tile:04d}.exr"))
            render_to(paths[-1], frame)
        try:
            merge_tiles(paths, path)
        except TileError as error:
            raise CliError(f"frame {frame}: {error}") from None
    finally:
        progress.prefix = prefix
        render.use_border = False
        render.use_stamp_note = False
        shutil.rmtree(folder, ignore_errors=True)


def merge_command(args: argparse.Namespace) -> int:
    """``lazyvis merge TILE.exr ... -o FRAME.exr``: stitch tiles (``tiles.merge_tiles``)."""
    missing = [tile for tile in args.tiles if not Path(tile).is_file()]
    if missing:
        raise CliError(f"no such file: {missing[0]}")
    try:
        merged = merge_tiles(args.tiles, args.output)
    except TileError as error:
        raise CliError(str(error)) from None
    except OSError as error:
        raise CliError(f"cannot write {args.output}: {error.strerror or error}") from None
    print(f"Saved: '{args.output}' ({merged['tiles']} tiles, {merged['width']} x {merged['height']}, "
          f"{len(merged['channels'])} channels)", flush=True)
    return 0


def combined_rgb(channels: dict):
    """(H, W, 3) linear RGB of an EXR written by ``render``: R, G, B, or the first view layer's Combined."""
    import numpy as np

    for prefix in [""] + sorted({name[:-len("Combined.R")] for name in channels if name.endswith("Combined.R")}):
        names = [f"{prefix}R", f"{prefix}G", f"{prefix}B"] if not prefix else \
            [f"{prefix}Combined.{c}" for c in "RGB"]
        if all(name in channels for name in names):
            return np.stack([channels[name] for name in names], axis=2)
    raise CliError("the written EXR has no RGB channels to preview")


# -- arguments -----------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", metavar="COMMAND")
    commands.required = True
    render = commands.add_parser(
        "render", help="render frames of a .blend file with LazyVis to OpenEXR",
        description="Render frames of a .blend with the LazyVis engine, like blender -b FILE -E LAZYVIS -f N. "
                    "Writes 32-bit float OpenEXR: RGBA, or every pass with --multilayer.")
    render.add_argument("file", metavar="FILE.blend")
    frames = render.add_mutually_exclusive_group()
    frames.add_argument("-f", "--render-frame", dest="frames", metavar="FRAMES",
                        help="frame(s) to render: N, +N (start+N), -N (end-N), A..B, comma lists")
    frames.add_argument("-a", "--render-anim", dest="animation", action="store_true",
                        help="render the file's frame range (start to end by step)")
    render.add_argument("-s", "--frame-start", type=int, metavar="N", help="first frame of the range")
    render.add_argument("-e", "--frame-end", type=int, metavar="N", help="last frame of the range")
    render.add_argument("-j", "--frame-jump", type=int, metavar="N", help="frame step of the range")
    render.add_argument("-o", "--render-output", dest="output", metavar="PATH",
                        help="output EXR; '#' = frame number, '//' = the .blend's folder "
                             "(default: the file's output path)")
    render.add_argument("--png", metavar="PATH", help="also write an sRGB preview PNG of the image ('#' as for -o)")
    render.add_argument("--multilayer", action="store_true",
                        help="write a multilayer EXR with every pass of every view layer (default: RGBA)")
    render.add_argument("-S", "--scene", metavar="NAME", help="scene to render (default: the file's active scene)")
    render.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"), help="override the resolution")
    render.add_argument("--resolution-percentage", type=int, metavar="P",
                        help="override the resolution scale, 1-32767 %% (e.g. 10 for a quick look)")
    render.add_argument("-t", "--threads", type=int, metavar="N", help="render threads (0 = one per core)")
    render.add_argument("--tiles", metavar="CxR", help="render the frame as C x R tiles (render borders) and "
                                                       "merge them: the same image, less memory per tile")
    render.add_argument("--tile", type=int, metavar="I",
                        help="with --tiles: render only tile I (0 = top left, row by row), cropped, its place "
                             "in the frame in the file's Note; 'lazyvis merge' stitches the tiles")
    render.add_argument("--scheduler", metavar="ADDRESS",
                        help="render on a Dask cluster: tcp://HOST:PORT of its scheduler, or 'local' for worker "
                             "processes on this machine (needs pip install 'lazyvis[cluster]'); with --tiles each "
                             "frame's tiles, and frames ahead, spread over the workers")
    render.add_argument("--workers", type=int, metavar="N", help="with --scheduler local: worker processes (2)")
    render.set_defaults(handler=render_command)
    merge = commands.add_parser(
        "merge", help="stitch tile EXRs (lazyvis render --tile, the Flamenco job) into the frame's EXR",
        description="Stitch tiles rendered as render borders (cropped or not, RGBA or multilayer, every pass) "
                    "into the full frame's EXR. Each tile's place comes from its Note; the tiles must agree "
                    "on frame size, channels and frame, and cover the frame exactly once.")
    merge.add_argument("tiles", nargs="+", metavar="TILE.exr")
    merge.add_argument("-o", "--output", required=True, metavar="FRAME.exr", help="the merged EXR")
    merge.set_defaults(handler=merge_command)
    compare = commands.add_parser(
        "compare", help="LazyVis against Cycles on one frame: a side-by-side PNG with error maps, and figures",
        description="Render a .blend with LazyVis, then with Cycles (direct light only) as a reference, at "
                    "LazyVis' time and at LazyVis' error (or 1 %%); write the three images over their error "
                    "maps to a PNG and print the times and errors.")
    compare.add_argument("file", metavar="FILE.blend")
    compare.add_argument("-o", "--output", metavar="PATH", default="compare.png", help="the PNG (default compare.png)")
    compare.add_argument("--json", metavar="PATH", help="also write the figures as JSON")
    compare.add_argument("--reference-samples", type=int, default=1024, metavar="N",
                         help="Cycles samples of the reference the errors are measured against (default 1024)")
    compare.add_argument("-f", "--frame", type=int, metavar="N", help="frame (default: the file's current frame)")
    compare.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"), help="override the resolution")
    compare.add_argument("--resolution-percentage", type=int, metavar="P", help="override the resolution scale")
    compare.add_argument("-t", "--threads", type=int, metavar="N", help="render threads (0 = one per core)")

    def run_compare(args):
        from .compare import compare_command
        return compare_command(args, sys.modules[__name__])

    compare.set_defaults(handler=run_compare, frame_start=None, frame_end=None, frame_jump=None)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "resolution_percentage", None) is not None and not 1 <= args.resolution_percentage <= 32767:
        parser.error("--resolution-percentage must be between 1 and 32767")
    if getattr(args, "resolution", None) and min(args.resolution) < 4:
        parser.error("--resolution must be at least 4 x 4")
    if getattr(args, "threads", None) is not None and args.threads < 0:
        parser.error("--threads must be 0 or more")
    if getattr(args, "reference_samples", None) is not None and args.reference_samples < 64:
        parser.error("--reference-samples must be at least 64")
    if getattr(args, "tiles", None) is not None and args.command == "render":
        try:
            columns, rows = parse_tiles(args.tiles)
        except ValueError as error:
            parser.error(f"--tiles: {error}")
        if args.tile is not None and not 0 <= args.tile < columns * rows:
            parser.error(f"--tile must be 0 to {columns * rows - 1} for {columns} x {rows} tiles")
    if getattr(args, "tile", None) is not None and args.tiles is None:
        parser.error("--tile needs --tiles (the grid the tile is one of)")
    if getattr(args, "scheduler", None) and args.tile is not None:
        parser.error("--tile renders one tile here; --scheduler renders every tile on the cluster")
    if getattr(args, "workers", None) is not None and (args.workers < 1 or args.scheduler != "local"):
        parser.error("--workers (1 or more) goes with --scheduler local")
    try:
        return args.handler(args)
    except CliError as error:
        print(f"{PROG} {args.command}: error: {error}", file=sys.stderr)
        return 1
    except (Interrupted, KeyboardInterrupt):
        print(f"{PROG} {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
