"""Operators: ``bpy.ops.lazyvis.set_tile``, which a render farm's ``--python-expr`` calls to render one tile
of a frame (``lazyvis_addon.tiles``)."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, IntProperty

from ..tiles import apply_tile


class LAZYVIS_OT_set_tile(bpy.types.Operator):
    """Set the render border to one tile of a grid over the frame, cropped, and write the tile's place into
    the render's stamp note, so that 'lazyvis merge' can stitch the tiles' files"""

    bl_idname = "lazyvis.set_tile"
    bl_label = "Set Render Tile"
    bl_options = {'REGISTER', 'UNDO'}

    tile: IntProperty(name="Tile", min=0, default=0, description="Tile number, row by row from the top left")
    columns: IntProperty(name="Columns", min=1, max=64, default=2)
    rows: IntProperty(name="Rows", min=1, max=64, default=2)
    output: EnumProperty(name="Output", default='MULTILAYER', description="File format of the tile",
                         items=[('KEEP', "Keep", "The file's own output format"),
                                ('RGBA', "OpenEXR RGBA", "32-bit float RGBA, as 'lazyvis merge' stitches losslessly"),
                                ('MULTILAYER', "OpenEXR Multilayer", "32-bit float, every pass")])

    def execute(self, context):
        from ..cli import configure_output
        try:
            window = apply_tile(context.scene.render, self.tile, self.columns, self.rows)
        except ValueError as error:
            self.report({'ERROR'}, str(error))
            return {'CANCELLED'}
        if self.output != 'KEEP':
            configure_output(context.scene.render, self.output == 'MULTILAYER')
            context.scene.render.use_file_extension = True  # the merge names the tiles '....exr'
        self.report({'INFO'}, f"LazyVis: tile {self.tile} of {self.columns} x {self.rows}: pixels {window}")
        return {'FINISHED'}


classes = (LAZYVIS_OT_set_tile,)
register, unregister = bpy.utils.register_classes_factory(classes)
