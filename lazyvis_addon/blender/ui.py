"""Panels, laid out like Cycles': our own for what LazyVis adds, Blender's own for the rest.

Blender's built-in panels (Output, Format, Frame Range, Colour Management, Camera, View Layer, ...) are
adopted by adding the engine id to their ``COMPAT_ENGINES``, as Cycles does; our Light, Film, Passes,
Material and World panels replace the ones that do not fit.
"""

from __future__ import annotations


import bpy

from .engine import ENGINE_ID

# Built-in panels that list 'BLENDER_RENDER' but that LazyVis replaces or cannot honour.
EXCLUDED_PANELS = {
    "DATA_PT_light", "DATA_PT_preview", "DATA_PT_spot", "DATA_PT_cone", "DATA_PT_falloff_curve",
    "DATA_PT_camera_dof", "NODE_DATA_PT_light", "NODE_DATA_PT_spot", "MATERIAL_PT_preview",
    "MATERIAL_PT_context_material", "VIEWLAYER_PT_filter", "VIEWLAYER_PT_layer_passes",
    "RENDER_PT_freestyle", "RENDER_PT_gpencil", "RENDER_PT_grease_pencil_render",
    "RENDER_PT_grease_pencil_viewport", "EEVEE_MATERIAL_PT_viewport_settings",
}
# Panels of other engines that fit LazyVis as they are.
EXTRA_PANELS = {"EEVEE_MATERIAL_PT_context_material"}


def adopted_panels() -> list[type]:
    panels = []
    for panel in bpy.types.Panel.__subclasses__():
        compat = getattr(panel, "COMPAT_ENGINES", None)
        if compat is None or "freestyle" in panel.__name__.lower():
            continue
        if ("BLENDER_RENDER" in compat and panel.__name__ not in EXCLUDED_PANELS) or panel.__name__ in EXTRA_PANELS:
            panels.append(panel)
    return panels


class LazyVisPanel:
    """Mixin: shown only when LazyVis is the render engine."""

    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    COMPAT_ENGINES = {ENGINE_ID}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


# -- Render properties ---------------------------------------------------------------------------------


class LAZYVIS_RENDER_PT_integrator(LazyVisPanel, bpy.types.Panel):
    bl_label = "Integrator"
    bl_context = "render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.lazyvis
        layout.prop(props, "integrator")
        sub = layout.column()
        sub.active = props.integrator in ("analytic", "reference")
        sub.prop(props, "glossy_integrator")
        sub = layout.column()
        sub.active = props.integrator == "analytic"
        sub.prop(props, "visibility")
        col = layout.column(align=True)
        col.active = props.integrator == "reduced_mc" or (props.integrator == "analytic" and (
            props.visibility == "blocker_map" or props.glossy_integrator == "mc"))
        col.prop(props, "shadow_rays")
        col = layout.column(align=True)
        col.active = props.integrator in ("reduced_mc", "standard_mc") or props.glossy_integrator == "mc"
        col.prop(props, "mc_samples")
        col = layout.column(align=True)
        col.prop(props, "aa_samples")
        sub = col.column(align=True)
        sub.active = props.aa_samples > 1
        sub.prop(props, "aa_coverage_rays")
        sub.prop(props, "aa_threshold")
        sub.prop(props, "aa_settle_tolerance")
        layout.prop(props, "seed")


class LAZYVIS_RENDER_PT_blocker_map(LazyVisPanel, bpy.types.Panel):
    bl_label = "Blocker Map"
    bl_context = "render"
    bl_parent_id = "LAZYVIS_RENDER_PT_integrator"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.scene.lazyvis.integrator in ("analytic", "reduced_mc")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.lazyvis
        layout.prop(props, "connectivity")
        layout.prop(props, "umbra_detection")
        layout.prop(props, "merge_quads")
        layout.prop(props, "extend_fill")
        layout.prop(props, "verify_rays")
        sub = layout.column()
        sub.active = props.verify_rays > 0
        sub.prop(props, "refine_rounds")
        layout.prop(props, "window_margin")


class LAZYVIS_RENDER_PT_lights(LazyVisPanel, bpy.types.Panel):
    bl_label = "Lights"
    bl_context = "render"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(context.scene.lazyvis, "disk_vertices")


class LAZYVIS_RENDER_PT_film(LazyVisPanel, bpy.types.Panel):
    bl_label = "Film"
    bl_context = "render"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        cycles = getattr(context.scene, "cycles", None)
        if cycles is not None:  # Cycles' pixel filter, shared with Cycles (see properties.pixel_filter)
            layout.prop(cycles, "pixel_filter_type", text="Pixel Filter")
            row = layout.row()
            row.active = cycles.pixel_filter_type != 'BOX'
            row.prop(cycles, "filter_width", text="Width")
        layout.prop(context.scene.render, "film_transparent", text="Transparent")


class LAZYVIS_RENDER_PT_performance(LazyVisPanel, bpy.types.Panel):
    bl_label = "Performance"
    bl_context = "render"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.lazyvis
        render = context.scene.render
        col = layout.column(align=True)
        col.prop(render, "threads_mode")
        sub = col.column(align=True)
        sub.enabled = render.threads_mode == 'FIXED'
        sub.prop(render, "threads")
        col = layout.column(align=True)
        col.prop(props, "memory_budget_mb", text="Memory Budget (MB)")
        col.prop(props, "pixel_batch")


# -- View layer ------------------------------------------------------------------------------------------


class LAZYVIS_VIEWLAYER_PT_passes(LazyVisPanel, bpy.types.Panel):
    bl_label = "Passes"
    bl_context = "view_layer"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        view_layer = context.view_layer
        col = layout.column(heading="Data", align=True)
        col.prop(view_layer, "use_pass_combined")
        col.prop(view_layer, "use_pass_z")
        col.prop(view_layer, "use_pass_normal")
        col = layout.column(heading="LazyVis", align=True)
        col.prop(view_layer.lazyvis, "use_pass_blocker_count")
        col.prop(view_layer.lazyvis, "use_pass_sample_count")


# -- Light ---------------------------------------------------------------------------------------------


class LAZYVIS_LIGHT_PT_light(LazyVisPanel, bpy.types.Panel):
    bl_label = "Light"
    bl_context = "data"

    @classmethod
    def poll(cls, context):
        return context.light is not None and super().poll(context)

    def draw(self, context):
        layout = self.layout
        light = context.light
        layout.row().prop(light, "type", expand=True)
        layout.use_property_split = True
        layout.use_property_decorate = False
        if light.type not in {'AREA', 'POINT', 'SPOT', 'SUN'}:
            layout.label(text="LazyVis does not render this type of light; it is ignored", icon='ERROR')
            return
        col = layout.column()
        row = col.row(align=True, heading="Temperature")
        row.prop(light, "use_temperature", text="")
        sub = row.row()
        sub.active = light.use_temperature
        sub.prop(light, "temperature", text="")
        col.prop(light, "color", text="Tint" if light.use_temperature else "Color")
        col = layout.column()
        col.prop(light, "energy", text="Strength" if light.type == 'SUN' else "Power")
        col.prop(light, "exposure")
        if light.type == 'SUN':
            layout.column().prop(light, "angle")
            return
        if light.type in {'POINT', 'SPOT'}:
            col = layout.column()
            col.prop(light, "use_soft_falloff")
            col.prop(light, "shadow_soft_size", text="Radius")
            if light.type == 'SPOT':
                col = layout.column()
                col.prop(light, "spot_size", text="Spot Size")
                col.prop(light, "spot_blend", text="Blend")
            return
        col.prop(light, "normalize")
        col = layout.column()
        col.prop(light, "shape")
        sub = col.column(align=True)
        if light.shape in {'SQUARE', 'DISK'}:
            sub.prop(light, "size")
        else:
            sub.prop(light, "size", text="Size X")
            sub.prop(light, "size_y", text="Y")
        col.prop(light, "spread")


# -- Material and world ----------------------------------------------------------------------------------


def _draw_node_input(layout, tree, input_name: str) -> None:
    """Blender's node view of the socket feeding the Cycles output, as Cycles' own panels draw it."""
    output = tree.get_output_node('CYCLES') if tree is not None else None
    if output is None:
        layout.label(text="No output node")
        return
    socket = output.inputs.get(input_name)
    if socket is None:
        layout.label(text="Incompatible output node")
        return
    layout.template_node_view(tree, output, socket)


class LAZYVIS_MATERIAL_PT_surface(LazyVisPanel, bpy.types.Panel):
    bl_label = "Surface"
    bl_context = "material"

    @classmethod
    def poll(cls, context):
        return context.material is not None and super().poll(context)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        material = context.material
        layout.label(text="Read: Diffuse, Principled, Glossy, Mix (Diffuse + Glossy) and Emission shaders; "
                          "Image Texture on the base colour", icon='INFO')
        _draw_node_input(layout, material.node_tree, "Surface")
        layout.prop(material, "diffuse_color", text="Viewport Color (fallback)")


class LAZYVIS_WORLD_PT_surface(LazyVisPanel, bpy.types.Panel):
    bl_label = "Surface"
    bl_context = "world"

    @classmethod
    def poll(cls, context):
        return context.world is not None and super().poll(context)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        world = context.world
        layout.label(text="Shown behind the scene only; it does not light it", icon='INFO')
        if world.node_tree is None:
            layout.prop(world, "color")
        else:
            _draw_node_input(layout, world.node_tree, "Surface")


classes = (
    LAZYVIS_RENDER_PT_integrator,
    LAZYVIS_RENDER_PT_blocker_map,
    LAZYVIS_RENDER_PT_lights,
    LAZYVIS_RENDER_PT_film,
    LAZYVIS_RENDER_PT_performance,
    LAZYVIS_VIEWLAYER_PT_passes,
    LAZYVIS_LIGHT_PT_light,
    LAZYVIS_MATERIAL_PT_surface,
    LAZYVIS_WORLD_PT_surface,
)


def register() -> None:
    for panel in adopted_panels():
        panel.COMPAT_ENGINES.add(ENGINE_ID)
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    for panel in adopted_panels():
        panel.COMPAT_ENGINES.discard(ENGINE_ID)
