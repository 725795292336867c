"""Lights' Ray Visibility (issue 14): a light reaching only the diffuse or only the glossy lobes, as Cycles
renders Blender's Object > Visibility > Ray Visibility > Diffuse / Glossy of a light or an emitting mesh.
The two parts add up to the light that reaches both, each part is what its lobe alone reflects, and the
flags survive validation, emitter grouping and the .npz file."""

import dataclasses

import numpy as np
import pytest

from lazyvis_addon.core import Materials, Scene, Settings, render
from lazyvis_addon.core.demo_scenes import box_triangles, plane_under_light
from lazyvis_addon.core.emitters import group_mesh_emitters
from lazyvis_addon.core.scene import LOBE_DIFFUSE, LOBE_GLOSSY, LOBES_ALL, FacingLights, Lights

CENTRES = Settings(aa_samples=1)
# A Principled floor: a diffuse base under a dielectric GGX layer (both lobes).
PRINCIPLED = Materials(np.array([(0.6, 0.5, 0.4)]), principled=np.array([True]), roughness=np.array([0.35]))


def _scene(lobes=None, facing=False, materials=PRINCIPLED, blocker=True):
    scene = plane_under_light(resolution=20, height=1.2,
                              blocker=box_triangles((0.3, 0.1, 0.5), (0.3, 0.3, 0.2)) if blocker else None)
    scene = dataclasses.replace(scene, materials=materials)
    if facing:
        lamp = FacingLights.point((0.2, -0.3, 1.4), 0.2, (3.0, 3.0, 3.0))
        lamp = lamp if lobes is None else lamp.reaching(lobes)
        return dataclasses.replace(scene, lights=Lights.empty(), facing=lamp)
    lights = scene.lights
    return dataclasses.replace(scene, lights=Lights(lights.vertices, lights.vertex_count, lights.radiance,
                                                    lights.two_sided, lobes=None if lobes is None else [lobes]))


@pytest.mark.parametrize("facing", [False, True])
def test_diffuse_and_glossy_parts_add_up_to_the_whole_light(facing):
    whole = render(_scene(facing=facing), CENTRES).combined[..., :3]
    diffuse = render(_scene(LOBE_DIFFUSE, facing), CENTRES).combined[..., :3]
    glossy = render(_scene(LOBE_GLOSSY, facing), CENTRES).combined[..., :3]
    lit = whole > 1e-3 * whole.max()
    assert lit.mean() > 0.5
    assert (diffuse[lit] > 0).all() and (glossy[lit] > 0).all() and (glossy[lit] < whole[lit]).all()
    np.testing.assert_allclose(diffuse + glossy, whole, rtol=1e-6, atol=1e-9 * whole.max())  # float32 images
    np.testing.assert_array_equal(render(_scene(LOBES_ALL, facing), CENTRES).combined, render(_scene(facing=facing),
                                                                                              CENTRES).combined)


def test_each_part_is_what_its_lobe_alone_reflects():
    """A diffuse-only light on a pure Glossy BSDF is dark, a glossy-only one on a Diffuse BSDF too; each
    reaching its own lobe renders as the light reaching both."""
    glossy_material = Materials(np.zeros((1, 3)), diffuse_weight=np.zeros(1), glossy_colour=np.ones((1, 3)),
                                roughness=np.array([0.3]))
    diffuse_material = Materials.diffuse([(0.5, 0.5, 0.5)])
    assert render(_scene(LOBE_DIFFUSE, materials=glossy_material), CENTRES).combined[..., :3].max() == 0.0
    assert render(_scene(LOBE_GLOSSY, materials=diffuse_material), CENTRES).combined[..., :3].max() == 0.0
    for lobe, material in ((LOBE_GLOSSY, glossy_material), (LOBE_DIFFUSE, diffuse_material)):
        np.testing.assert_array_equal(render(_scene(lobe, materials=material), CENTRES).combined,
                                      render(_scene(materials=material), CENTRES).combined)


def test_lobes_survive_validation_grouping_and_npz(tmp_path):
    quad = np.array([[(-0.3, -0.3, 1.0), (0.3, -0.3, 1.0), (0.3, 0.3, 1.0)],
                     [(-0.3, -0.3, 1.0), (0.3, 0.3, 1.0), (-0.3, 0.3, 1.0)]])
    cube = box_triangles((1.0, 1.0, 1.0), (0.2, 0.2, 0.2))
    triangles = np.concatenate([quad, cube])
    emitters = Lights(triangles, np.full(len(triangles), 3), np.ones((len(triangles), 3)), np.ones(len(triangles), bool),
                      lobes=[LOBE_GLOSSY] * 2 + [LOBE_DIFFUSE] * 12)
    grouped, hulls, _, _ = group_mesh_emitters(emitters, np.repeat([0, 1], [2, 12]))
    assert list(grouped.lobes) == [LOBE_GLOSSY] and list(hulls.lobes) == [LOBE_DIFFUSE]
    scene = _scene(LOBE_GLOSSY)
    scene = dataclasses.replace(scene, facing=FacingLights.point((0.5, 0.5, 2.0), 0.1, (1.0,) * 3).reaching(LOBE_DIFFUSE),
                                hulls=hulls)
    scene.save_npz(tmp_path / "scene.npz")
    loaded = Scene.load_npz(tmp_path / "scene.npz")
    assert list(loaded.lights.lobes) == [LOBE_GLOSSY] and list(loaded.facing.lobes) == [LOBE_DIFFUSE]
    assert list(loaded.hulls.lobes) == [LOBE_DIFFUSE]
    assert list(loaded.validated().lights.lobes) == [LOBE_GLOSSY]
    with pytest.raises(ValueError, match="lobes must be bits"):
        Lights(scene.lights.vertices, scene.lights.vertex_count, scene.lights.radiance, scene.lights.two_sided,
               lobes=[4])


def test_monte_carlo_integrators_warn_that_they_light_every_lobe():
    out = render(_scene(LOBE_DIFFUSE), Settings(aa_samples=1, integrator="standard_mc", mc_samples=2))
    assert any("Ray Visibility" in w for w in out.warnings)
    assert not any("Ray Visibility" in w for w in render(_scene(LOBE_DIFFUSE), CENTRES).warnings)
