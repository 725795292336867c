"""LazyVis core: direct illumination with lazy visibility evaluation, in numpy + Embree. Never imports bpy.

    from lazyvis_addon.core import Scene, Settings, render
    output = render(scene, Settings(integrator="analytic"))
"""

from pathlib import Path

from .kernel_cache import drop_stale_kernels

drop_stale_kernels(Path(__file__).resolve().parent)  # before any kernel is loaded from the cache

from .progress import Progress, RenderCancelled  # noqa: E402
from .frame import BACKGROUND_DEPTH, RenderOutput  # noqa: E402
from .render import render  # noqa: E402
from .scene import Camera, FacingLights, Lights, Materials, Scene, SeenLights  # noqa: E402
from .settings import INTEGRATORS, Settings  # noqa: E402

__all__ = ["BACKGROUND_DEPTH", "Camera", "FacingLights", "INTEGRATORS", "Lights", "Materials", "Progress", "RenderCancelled",
           "RenderOutput", "Scene", "SeenLights", "Settings", "render"]
