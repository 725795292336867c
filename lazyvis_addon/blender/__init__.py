"""The Blender layer: export from the depsgraph, the render engine, its settings and panels.

Imports bpy; the core (``lazyvis_addon.core``) never imports this package.
"""

from __future__ import annotations

from . import engine, properties, ui

_modules = (properties, engine, ui)


def register() -> None:
    for module in _modules:
        module.register()


def unregister() -> None:
    for module in reversed(_modules):
        module.unregister()
