"""A stand-in for the ``blender`` executable of a Flamenco worker, through bpy: runs the arguments a
``blender-render`` command gives, in Blender's order of processing (each argument acts when it is read):

    python blender_shim.py -b FILE.blend [--scene NAME] [--python-expr CODE] [-E|--engine ENGINE]
                           [-o|--render-output PATTERN] [-f|--render-frame A|A..B]

Only these arguments, as the LazyVis Flamenco job uses them; -f renders each frame and writes it as
Blender's -f does: the output pattern's last run of '#' becomes the frame number (``cli.substitute_frame``,
Blender's rule), and the file format's extension is added."""

import sys

import bpy

import lazyvis_addon
from lazyvis_addon.cli import substitute_frame


def main(argv: list[str]) -> int:
    lazyvis_addon.register()  # as the extension enabled on a worker
    args = list(argv)
    pattern = "//"
    while args:  # a handful of arguments, in order
        flag = args.pop(0)
        if flag in ("-b", "--background", "-y"):
            continue
        if flag.endswith(".blend"):
            bpy.ops.wm.open_mainfile(filepath=flag, load_ui=False)
        elif flag in ("--scene", "-S"):
            bpy.context.window.scene = bpy.data.scenes[args.pop(0)] if bpy.context.window else None
        elif flag == "--python-expr":
            exec(args.pop(0), {"__name__": "__main__"})
        elif flag in ("-E", "--engine"):
            bpy.context.scene.render.engine = args.pop(0)
        elif flag in ("-o", "--render-output"):
            pattern = args.pop(0)
        elif flag in ("-f", "--render-frame"):
            first, _, last = args.pop(0).partition("..")
            for frame in range(int(first), int(last or first) + 1):
                bpy.context.scene.frame_set(frame)
                bpy.context.scene.render.filepath = substitute_frame(pattern, frame)
                bpy.ops.render.render(write_still=True)
        else:
            print(f"blender_shim: unsupported argument {flag}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
