"""The Blender layer: export from the depsgraph, the render engine, its settings, panels and operators.

Imports bpy; the core (``lazyvis_addon.core``) never imports this package.
"""

from __future__ import annotations

from . import engine, operators, properties, ui

_modules = (properties, engine, operators, ui)


def register() -> None:
    for module in _modules:
        module.register()


def unregister() -> None:
    for module in reversed(_modules):
        module.unregister()
