"""Panels draw only properties that exist (drawn into a recording layout: bpy cannot draw UI headless)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import add_area_light, node_material  # noqa: E402

from lazyvis_addon.blender import ui  # noqa: E402


class RecordingLayout:
    """Stands in for UILayout: every sub-layout is itself; ``prop`` checks the property exists."""

    def __init__(self):
        self.props, self.labels, self.node_views = [], [], []
        self.use_property_split = self.use_property_decorate = self.active = True

    def prop(self, data, name, **_kwargs):
        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property {name!r}"
        self.props.append(name)

    def label(self, text="", **_kwargs):
        self.labels.append(text)

    def template_node_view(self, tree, node, socket):
        self.node_views.append(socket.name)

    def _same(self, *_args, **_kwargs):
        return self

    row = column = split = box = _same


def draw(panel, context):
    layout = RecordingLayout()
    assert panel.poll(context), panel.__name__
    panel.draw(SimpleNamespace(layout=layout), context)
    return layout


def test_render_panels_draw_scene_properties(scene):
    context = SimpleNamespace(engine=scene.render.engine, scene=scene, view_layer=scene.view_layers[0])
    drawn = []
    for panel in (ui.LAZYVIS_RENDER_PT_integrator, ui.LAZYVIS_RENDER_PT_blocker_map, ui.LAZYVIS_RENDER_PT_lights,
                  ui.LAZYVIS_RENDER_PT_film, ui.LAZYVIS_RENDER_PT_performance, ui.LAZYVIS_VIEWLAYER_PT_passes):
        drawn += draw(panel, context).props
    for name in ("integrator", "glossy_integrator", "visibility",
                 "shadow_rays", "mc_samples", "seed", "connectivity", "umbra_detection",
                 "window_margin", "merge_quads", "disk_vertices", "film_transparent", "pixel_filter_type", "filter_width",
                 "aa_samples", "aa_coverage_rays", "aa_threshold", "aa_settle_tolerance", "memory_budget_mb", "pixel_batch", "threads_mode", "threads",
                 "use_pass_z", "use_pass_normal", "use_pass_blocker_count", "use_pass_sample_count"):
        assert name in drawn


def test_panels_hide_for_other_engines(scene):
    context = SimpleNamespace(engine="CYCLES", scene=scene)
    assert not ui.LAZYVIS_RENDER_PT_integrator.poll(context)


@pytest.mark.parametrize("shape", ["SQUARE", "RECTANGLE", "DISK", "ELLIPSE"])
def test_light_panel(scene, shape):
    light = add_area_light(shape=shape).data
    layout = draw(ui.LAZYVIS_LIGHT_PT_light, SimpleNamespace(engine=scene.render.engine, light=light))
    assert {"energy", "color", "shape", "size", "normalize", "exposure"} <= set(layout.props)
    assert ("size_y" in layout.props) == (shape in ("RECTANGLE", "ELLIPSE"))


@pytest.mark.parametrize("kind, shown", [("POINT", {"shadow_soft_size", "use_soft_falloff"}),
                                         ("SPOT", {"shadow_soft_size", "spot_size", "spot_blend"}),
                                         ("SUN", {"angle"})])
def test_light_panel_of_point_spot_and_sun(scene, kind, shown):
    bpy.ops.object.light_add(type=kind)
    layout = draw(ui.LAZYVIS_LIGHT_PT_light,
                  SimpleNamespace(engine=scene.render.engine, light=bpy.context.object.data))
    assert {"energy", "color", "exposure"} | shown <= set(layout.props)
    assert "normalize" not in layout.props and not any("ignored" in text for text in layout.labels)


def test_material_and_world_panels_show_the_surface_node(scene):
    material = node_material("Paint", Color=(0.5, 0.5, 0.5))
    layout = draw(ui.LAZYVIS_MATERIAL_PT_surface, SimpleNamespace(engine=scene.render.engine, material=material))
    assert layout.node_views == ["Surface"]
    world = bpy.data.worlds.new("Sky")
    layout = draw(ui.LAZYVIS_WORLD_PT_surface, SimpleNamespace(engine=scene.render.engine, world=world))
    assert layout.node_views == ["Surface"]
