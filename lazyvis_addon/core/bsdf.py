"""The BSDF of each visible point, split the way pass 2 integrates it.

A material row (``scene.Materials``) stands for Cycles' closures

    f(ω_i, ω_o) = diffuse · [cos θ_i > 0] / π  +  Σ_closures weight · F(ω_o·h) · D G2 / (4 cos θ_i cos θ_o) · ms

where every GGX closure of a row shares one roughness, so one lobe *shape* D G2 / (4 cos θ_i cos θ_o)
serves them all and they differ only in constant factors and Fresnel. Pass 2 therefore needs per point:

- ``diffuse`` (N, 3): the Lambertian coefficient (the BRDF is diffuse / π). For a Principled row it is
  (1 - metallic) · base colour · the layering weight of the specular coat, which depends on ω_o
  (``ggx.principled_diffuse_weight``), so it is computed here once per point.
- ``glossy_scale`` (N, 3): the hemispherical integral of every GGX closure's f cos θ_i with its Fresnel
  (``ltc.material_magnitude``) times the closure weight and the Multiscatter GGX factor. The Phong
  integrator multiplies it by the *share* of its lobe that falls in the visible pieces.
- ``glossy_magnitude(rows, wi)``: the same with every Fresnel evaluated at one direction ω_i; the LTC
  integrator multiplies it by each piece's share of the lobe, with ω_i the piece's lobe-weighted direction.
- ``value(rows, wi)``: f itself, for the Monte Carlo integrators (unbiased for any row).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .ggx import (FRESNEL_BASIS_SIZE, GlossyMaterial, PrincipledMetal, PrincipledSpecular, energy_factor, ggx_brdf,
                  principled_diffuse_weight)
from .ltc import lobe_magnitudes, material_magnitude
from .scene import Materials


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...k,...k->...", a, b)


@dataclass
class SurfaceBsdf:
    """The BSDF at N visible points (a batch), facing the camera.

    Attributes
    ----------
    normal : (N, 3) float64      unit shading normal.
    view : (N, 3) float64        unit direction towards the camera ω_o.
    diffuse : (N, 3) float64     Lambertian coefficient: the diffuse BRDF is diffuse / π (0 on misses).
    glossy_scale : (N, 3)        ∫ f_glossy cos θ_i over the hemisphere (see the module docstring).
    roughness : (N,) float64     of the GGX lobes (α = roughness²).
    glossy : (N,) bool           the point has a GGX lobe that reflects (glossy_scale > 0).
    row : (N,) int64             material row (0 on misses, where nothing is shaded).
    base : (N, 3) float64        base colour (texture already applied): the metal's F0.
    """

    normal: np.ndarray
    view: np.ndarray
    diffuse: np.ndarray
    glossy_scale: np.ndarray
    roughness: np.ndarray
    glossy: np.ndarray
    row: np.ndarray
    base: np.ndarray
    materials: Materials

    @classmethod
    def of(cls, surface, materials: Materials) -> "SurfaceBsdf":
        """The BSDF of a batch of ``surface.SurfacePoints``."""
        n = len(surface)
        row = np.where(surface.material >= 0, surface.material, 0)
        normal, view, base = surface.shading_normal, surface.view, surface.albedo
        cos_view = np.clip(_dot(normal, view), 0.0, 1.0)
        roughness = materials.roughness[row]
        diffuse = base * materials.diffuse_weight[row, None]
        glossy_scale = np.zeros((n, 3))
        for p, closures in _closures(materials, row, base, surface.hit):  # (distribution, closure kind) groups
            for closure, weight in closures:
                magnitude = material_magnitude(closure, roughness[p], cos_view[p])
                glossy_scale[p] += weight * magnitude * energy_factor(closure, roughness[p], cos_view[p])
                if isinstance(closure, PrincipledSpecular):
                    # The specular coat takes its albedo from the diffuse base under it; metals have none.
                    layer = principled_diffuse_weight(roughness[p], cos_view[p], closure)
                    diffuse[p] *= weight * layer[:, None]
        diffuse = np.where(surface.hit[:, None], diffuse, 0.0)
        glossy = (glossy_scale.max(axis=1) > 0.0) & (cos_view > 0.0) & surface.hit
        return cls(normal, view, diffuse, glossy_scale, roughness, glossy, row, base, materials)

    def glossy_value(self, rows: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """f_glossy(ω_i, ω_o) (S, 3) in 1/sr at points ``rows`` (S,) towards unit directions wi (S, 3)."""
        value = np.zeros((len(rows), 3))
        normal, view, roughness = self.normal[rows], self.view[rows], self.roughness[rows]
        for p, closures in _closures(self.materials, self.row[rows], self.base[rows], np.ones(len(rows), bool)):
            for closure, weight in closures:
                value[p] += weight * ggx_brdf(wi[p], view[p], normal[p], roughness[p], closure)
        return value

    def glossy_magnitude(self, rows: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """The white lobe's hemispherical albedo times every closure's weight, Fresnel and multiscatter
        factor, the Fresnel taken at the half vector of ω_i (S, 3): the analytic integrators' estimate of
        ∫_P f_glossy cos θ_i / ∫_P D_lobe for a polygon P whose lobe-weighted mean direction is ω_i.
        Unlike ``glossy_scale`` (the Fresnel averaged over the whole lobe) it follows the Fresnel across
        the lobe, which at oblique views varies several-fold between the mirror direction and grazing."""
        normal, view, roughness = self.normal[rows], self.view[rows], self.roughness[rows]
        cos_view = np.clip(_dot(normal, view), 0.0, 1.0)
        half = wi + view
        half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-300)
        cos_hv = np.clip(_dot(half, view), 0.0, 1.0)
        norm = lobe_magnitudes(roughness, cos_view)[0][:, None]
        value = np.zeros((len(rows), 3))
        for p, closures in _closures(self.materials, self.row[rows], self.base[rows], np.ones(len(rows), bool)):
            for closure, weight in closures:
                fresnel = closure.reflectance(cos_hv[p])
                value[p] += weight * fresnel * energy_factor(closure, roughness[p], cos_view[p])
        return norm * value

    def fresnel_terms(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every closure's weight, multiscatter factor and Fresnel as coefficients of ``ggx.fresnel_basis``
        (S, 4, 3), and the η of its dielectric blend (S,) (1.5 where the row has no dielectric closure, whose
        coefficient is then 0): Σ_k coefficients_k basis_k(ω_o·h) · norm equals ``glossy_magnitude`` at any
        ω_i, but for the metal's clamp to [0, 1]. An integral over a piece carries the Fresnel point by point
        with it (``illumination.ltc_residual``)."""
        normal, view, roughness = self.normal[rows], self.view[rows], self.roughness[rows]
        cos_view = np.clip(_dot(normal, view), 0.0, 1.0)
        terms = np.zeros((len(rows), FRESNEL_BASIS_SIZE, 3))
        eta = np.full(len(rows), 1.5)
        for p, closures in _closures(self.materials, self.row[rows], self.base[rows], np.ones(len(rows), bool)):
            for closure, weight in closures:
                coefficients, closure_eta = closure.fresnel_terms(len(p))
                factor = weight * energy_factor(closure, roughness[p], cos_view[p])
                terms[p] += coefficients * factor[:, None, :]
                if closure_eta is not None:
                    eta[p] = closure_eta
        return terms, eta

    def value(self, rows: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """The whole BSDF f(ω_i, ω_o) (S, 3) in 1/sr: diffuse / π above the horizon plus the GGX lobes."""
        above = (_dot(self.normal[rows], wi) > 0.0)[:, None]
        value = np.where(above, self.diffuse[rows] / np.pi, 0.0)
        lobed = np.flatnonzero(self.glossy[rows])
        if len(lobed):
            value[lobed] += self.glossy_value(rows[lobed], wi[lobed])
        return value


def glossy_materials(materials: Materials) -> np.ndarray:
    """(M,) bool: the materials with a GGX lobe (``_closures``' rule: Principled, or a Glossy BSDF's colour)."""
    return np.asarray(materials.principled, bool) | (np.asarray(materials.glossy_colour).max(axis=1) > 0.0)


def _closures(materials: Materials, row: np.ndarray, base: np.ndarray, shaded: np.ndarray):
    """The GGX closures of points with material rows ``row`` (N,), grouped as Cycles' closure objects want
    them: yields (points (P,) int64, [(closure, weight (P, 1)), ...]) per group. Groups: Principled rows
    (dielectric specular, then metal) and Glossy BSDF rows, each split by distribution (one multiscatter
    flag per closure object); a handful of groups, whatever the number of points."""
    principled = materials.principled[row] & shaded
    colour = materials.glossy_colour[row]
    glossy = (colour.max(axis=1) > 0.0) & shaded
    multiscatter = materials.multiscatter[row]
    for flag in (True, False):  # the two GGX distributions
        p = np.flatnonzero(principled & (multiscatter == flag))
        if len(p):
            r = row[p]
            metallic = materials.metallic[r][:, None]
            specular = PrincipledSpecular(materials.ior[r], materials.specular_level[r], materials.specular_tint[r],
                                          flag)
            metal = PrincipledMetal(base[p], materials.specular_tint[r], flag)
            yield p, [(specular, 1.0 - metallic), (metal, metallic)]
        g = np.flatnonzero(glossy & (multiscatter == flag))
        if len(g):
            yield g, [(GlossyMaterial(colour[g], flag), np.ones((len(g), 1)))]
