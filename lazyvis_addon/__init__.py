"""LazyVis: direct illumination with lazy visibility evaluation (Hart, Dutre, Greenberg 1999).

``lazyvis_addon.core`` is the renderer (numpy + Embree, no Blender); ``lazyvis_addon.blender`` is the
Blender add-on on top of it. Blender is imported only inside ``register`` / ``unregister``, so importing
this package or its core never imports bpy.
"""


def register() -> None:
    from . import blender
    blender.register()


def unregister() -> None:
    from . import blender
    blender.unregister()
