"""Blender properties: ``scene.lazyvis`` (the core's ``Settings``) and ``view_layer.lazyvis`` (passes).

Defaults come from ``Settings`` itself, and ``settings_from_scene`` is the one place where the
properties become a ``Settings``. (No ``from __future__ import annotations`` here: Blender reads the
property annotations as objects.)
"""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

from ..core.settings import Settings
from .export import DISK_VERTICES_DEFAULT

_DEFAULTS = Settings()

INTEGRATOR_ITEMS = (
    ("analytic", "Analytic", "Blocker map, then Lambert's polygon formula over the visible parts of each "
     "light: noise-free, exact unless a blocker was missed"),
    ("reduced_mc", "Reduced Monte Carlo", "Blocker map, then Monte Carlo over the visible parts of each light "
     "(paper section 3.3)"),
    ("standard_mc", "Standard Monte Carlo", "Shadow rays over the whole light, the paper's baseline"),
    ("reference", "Reference", "Every triangle is a candidate blocker: exact and slow, for comparisons"),
)

# Explicit numbers: a .blend stores an enum's number, so the items keep theirs as new ones are added.
GLOSSY_INTEGRATOR_ITEMS = (
    ("ltc_cv", "LTC + Correction", "LTC with its shape error integrated by a Gauss rule over the visible parts "
     "(roughness 0.05 and up): noise-free, within Cycles' noise in the tests, about 1.5x LTC's time", 3),
    ("ltc", "LTC", "Linearly transformed cosines over the visible parts of each light: noise-free, a few "
     "percent off at grazing views", 0),
    ("phong", "Phong", "Phong lobes matched to the GGX peak, integrated in closed form (the paper's choice): "
     "noise-free, a cruder highlight shape", 1),
    ("mc", "Monte Carlo", "Samples directions over the visible parts of each light: unbiased, noisy at low "
     "sample counts", 2),
)

VISIBILITY_ITEMS = (
    ("silhouettes", "Silhouettes", "Every edge that can cross a light is found, however small; the visible part "
     "comes out exactly from the silhouette arcs crossing the light (no missed blockers)"),
    ("blocker_map", "Blocker Map", "The paper's method: shadow rays seed a blocker map that is flood-filled "
     "through the image (fast on big blockers; misses blockers no shadow ray hits)"),
)


class LazyVisSceneSettings(bpy.types.PropertyGroup):
    """Render settings of the Lazy Visibility engine (``scene.lazyvis``)."""

    integrator: EnumProperty(name="Integrator", items=INTEGRATOR_ITEMS, default=_DEFAULTS.integrator,
                             description="How the visible part of each light is integrated")
    glossy_integrator: EnumProperty(name="Glossy", items=GLOSSY_INTEGRATOR_ITEMS,
                                    default=_DEFAULTS.glossy_integrator,
                                    description="How glossy reflection (Principled and Glossy BSDFs) is "
                                                "integrated over the visible part of each light by the Analytic "
                                                "and Reference integrators")
    visibility: EnumProperty(name="Visibility", items=VISIBILITY_ITEMS, default=_DEFAULTS.visibility,
                             description="How the Analytic integrator finds what each pixel sees of a light")
    shadow_rays: IntProperty(name="Shadow Rays", default=_DEFAULTS.shadow_rays, min=1, soft_max=64,
                             description="Shadow rays per pixel and light that look for blockers (pass 1), "
                                         "stratified over the light")
    aa_samples: IntProperty(name="Edge Samples", default=_DEFAULTS.aa_samples, min=1, soft_max=256,
                            description="Anti-aliasing: samples for pixels at edges (another object, material "
                                        "or a sharp shadow nearby) on average, more at stronger edges, placed "
                                        "by the pixel filter (with Coverage Rays the pixel's centre counts as "
                                        "one); 1 shades pixel centres only")
    aa_coverage_rays: IntProperty(name="Coverage Rays", default=_DEFAULTS.aa_coverage_rays, min=0, soft_max=64,
                                  description="Camera rays per edge pixel that only see which object and "
                                              "material the pixel covers, and how much of it: the jump at an "
                                              "object's outline comes from them, so few shaded samples are "
                                              "needed (0: off, the plain mean of the samples)")
    aa_settle_tolerance: FloatProperty(name="Settle Tolerance", default=_DEFAULTS.aa_settle_tolerance, min=0.0,
                                       soft_max=0.05, precision=4,
                                       description="An edge pixel first shades 3 samples; when they agree with "
                                                   "its centre within this fraction of its brightness and its "
                                                   "filter covers one object, it stops there (0: always shade "
                                                   "every Edge Sample)")
    aa_threshold: FloatProperty(name="Edge Threshold", default=_DEFAULTS.aa_threshold, min=0.0, soft_max=1.0,
                                description="Relative brightness step between neighbouring pixels that "
                                            "marks an edge for anti-aliasing")
    verify_rays: IntProperty(name="Verification Rays", default=_DEFAULTS.verify_rays, min=0, soft_max=64,
                             description="Rays per pixel and light into what pass 1 left visible; each hit is a "
                                         "missed blocker, added and re-shaded (0: off)")
    refine_rounds: IntProperty(name="Refinement Rounds", default=_DEFAULTS.refine_rounds, min=0, soft_max=8,
                               description="How many times verification may add blockers and re-shade")
    mc_samples: IntProperty(name="Samples", default=_DEFAULTS.mc_samples, min=1, soft_max=1024,
                            description="Samples per pixel and light for the Monte Carlo integrators")
    connectivity: EnumProperty(name="Connectivity", default=str(_DEFAULTS.connectivity),
                               items=(("8", "8 Neighbours", "Flood fill over the 8 neighbouring pixels "
                                                            "(the paper's text)"),
                                      ("4", "4 Neighbours", "Flood fill over the 4 edge neighbours "
                                                            "(the paper's Fig. 3)")),
                               description="Pixels a blocker found at one pixel is propagated to")
    umbra_detection: BoolProperty(name="Umbra Detection", default=_DEFAULTS.umbra_detection,
                                  description="Mark a light hidden where one blocker covers it entirely "
                                              "(paper section 5)")
    extend_fill: BoolProperty(name="Extended Fill", default=_DEFAULTS.extend_fill,
                              description="Also keep a blocker in the pixels just outside its shadow, so every "
                                          "point seen through a pixel has its blockers (paper section 4.4)")
    merge_quads: BoolProperty(name="Merge Quads", default=_DEFAULTS.merge_quads,
                              description="Treat coplanar triangle pairs that form convex quads as one blocker "
                                          "polygon, and clip by the silhouettes of closed convex parts (boxes, "
                                          "posts) instead of by their faces (faster; the same image up to "
                                          "rounding)")
    seed: IntProperty(name="Seed", default=_DEFAULTS.seed, min=0,
                      description="Random seed; with the frame number it fixes every random number")
    disk_vertices: IntProperty(name="Disk Vertices", default=DISK_VERTICES_DEFAULT, min=3, soft_max=128,
                               description="Polygon vertices for disk and ellipse area lights (the polygon "
                                           "has the ellipse's area)")
    memory_budget_mb: FloatProperty(name="Memory Budget", default=_DEFAULTS.memory_budget_mb, min=16.0,
                                    soft_max=65536.0, step=1000, precision=0,
                                    description="Working memory in MB the passes may use for their batches")
    pixel_batch: IntProperty(name="Pixel Batch", default=_DEFAULTS.pixel_batch, min=256, soft_max=1 << 20,
                             description="Pixels per batch: how often progress is shown and a cancel is seen")
    window_margin: IntProperty(name="Region Margin", default=_DEFAULTS.window_margin, min=0, soft_max=256,
                               subtype='PIXEL',
                               description="Blocker Map: when rendering a region (render border), blockers "
                                           "are also looked for this many pixels around it, so that the region "
                                           "matches the full frame (Silhouettes needs none: a region is always "
                                           "the full frame's pixels)")


class LazyVisViewLayerSettings(bpy.types.PropertyGroup):
    """Passes of the Lazy Visibility engine beyond Blender's own (``view_layer.lazyvis``)."""

    use_pass_blocker_count: BoolProperty(name="Blocker Count", default=True,
                                         description="Silhouette arcs crossing the pixel's lights (Silhouettes), "
                                                     "or blocker-light pairs found by pass 1 (Blocker Map)",
                                         update=lambda self, context: context.view_layer.update_render_passes())
    use_pass_sample_count: BoolProperty(name="Sample Count", default=False,
                                        description="Shaded camera samples per pixel: Edge Samples on "
                                                    "average where anti-aliased (the centre included), 1 "
                                                    "where the centre was shaded alone",
                                        update=lambda self, context: context.view_layer.update_render_passes())


def settings_from_scene(scene) -> Settings:
    """The core ``Settings`` for a Blender scene: every ``scene.lazyvis`` property named like a Settings
    field, plus frame, film transparency, the pixel filter and threads from Blender's own render settings."""
    props = scene.lazyvis
    values = {name: getattr(props, name) for name in Settings.field_names()
              if name in LazyVisSceneSettings.__annotations__}
    values["connectivity"] = int(values["connectivity"])  # an enum of "4" / "8"
    # Blender keeps float properties in float32: 0.1 comes back as 0.10000000149. Six digits are the UI's.
    values = {name: float(f"{value:.6g}") if isinstance(value, float) else value for name, value in values.items()}
    values.update(frame=scene.frame_current, transparent_background=scene.render.film_transparent,
                  **pixel_filter(scene),
                  threads=0 if scene.render.threads_mode == 'AUTO' else scene.render.threads)
    return Settings(**values)


def pixel_filter(scene) -> dict:
    """``filter_width`` and ``filter_type`` as Cycles reads them (Film > Pixel Filter), so that both engines
    filter a .blend alike. ``render.filter_size`` is EEVEE's and independent: a .blend may carry 1.5 in
    one and 0.01 in the other. Without the Cycles add-on, the core's defaults (Cycles' own) apply."""
    cycles = getattr(scene, "cycles", None)
    if cycles is None:
        return {}
    return {"filter_width": float(f"{cycles.filter_width:.6g}"), "filter_type": str(cycles.pixel_filter_type)}


classes = (LazyVisSceneSettings, LazyVisViewLayerSettings)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.lazyvis = PointerProperty(type=LazyVisSceneSettings, name="Lazy Visibility")
    bpy.types.ViewLayer.lazyvis = PointerProperty(type=LazyVisViewLayerSettings, name="Lazy Visibility")


def unregister() -> None:
    del bpy.types.ViewLayer.lazyvis
    del bpy.types.Scene.lazyvis
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
