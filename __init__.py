"""Blender extension entry point: the repository root is the extension (``bl_ext.<repo>.lazyvis``).

Everything lives in the ``lazyvis_addon`` package; this file only hands over to it (relative imports
only, so it works under whatever package name Blender gives the extension).
"""


def register() -> None:
    from .lazyvis_addon import register as register_addon
    register_addon()


def unregister() -> None:
    from .lazyvis_addon import unregister as unregister_addon
    unregister_addon()
