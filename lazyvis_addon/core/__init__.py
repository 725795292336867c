"""LazyVis core: direct illumination with lazy visibility evaluation, in numpy + Embree. Never imports bpy.

    from lazyvis_addon.core import Scene, Settings, render
    output = render(scene, Settings(integrator="analytic"))
"""

from .progress import Progress, RenderCancelled
from .render import BACKGROUND_DEPTH, RenderOutput, render
from .scene import Camera, FacingLights, Lights, Materials, Scene, SeenLights
from .settings import INTEGRATORS, Settings

__all__ = ["BACKGROUND_DEPTH", "Camera", "FacingLights", "INTEGRATORS", "Lights", "Materials", "Progress", "RenderCancelled",
           "RenderOutput", "Scene", "SeenLights", "Settings", "render"]
