"""GGX over polygons with linearly transformed cosines (Heitz, Dupuy, Hill, Neubelt, SIGGRAPH 2016).

For one view direction and roughness, the GGX lobe f cos θ_i (as a function of ω_i) is approximated by a
clamped cosine D_o(ω) = max(0, ω_z)/π under a 3 x 3 linear transform M,
D(ω) = D_o(M⁻¹ω/|M⁻¹ω|) |det M⁻¹| / |M⁻¹ω|³, scaled by the lobe's hemispherical magnitude. Linear maps
take polygons to polygons and the clamped cosine integrates in closed form over a polygon (Lambert's
formula), so

    ∫_P f cos θ_i dω_i ≈ magnitude · ∫_(M⁻¹ P) D_o = magnitude · E(M⁻¹ P) / π,

where E is the projected solid angle of the transformed polygon clipped to z > 0.

Per receiver: frame (T1, T2, N) with T1 = normalize(V - N (V·N)), T2 = N × T1; vertices p -> M⁻¹ (T1·p,
T2·p, N·p); clip to z > 0; ``geometry.projected_solid_angle``. M⁻¹ comes from the published fit
(``data/ltc_ggx.npz``, 64 x 64 over roughness and sqrt(1 - cos θ_o), bilinear as on the GPU), fitted to the
same lobe as Cycles' GGX (α = roughness², height-correlated G2).

Magnitudes: the fit ships norm and Schlick-Fresnel terms estimated with 2,500 samples per cell; against
exact quadrature its norm is off by 0.3% rms (1.2% at most) up to 80° views and by up to 5% closer to
grazing, so the magnitudes used here are exact hemispherical integrals of Cycles' lobe on the same grid
(``data/ggx_albedo.npz``, keys ``ltc_*``, ``tools/make_ggx_tables.py``). Every error left is the LTC *shape*
error, including the share of the fitted lobe that falls below the horizon at oblique views (0.3-1.3% at 30°,
2-6% at 60°, up to 11% at 80°), which no polygon above the horizon can receive.

Accuracy (tests/test_ltc.py, against brute-force 2-D quadrature of Cycles' lobe over the polygon): the
error, as a fraction of the lobe's hemispherical albedo, is below 1.6% at view angles up to 30°, up to
8.5% at 60° and 17% at 80° for mid roughness (0.3-0.5), where the GGX lobe becomes a crescent along the
horizon that an LTC cannot follow (roughness 0.1 and 0.8 stay below 1.3%). Mirror-like lobes
(α² <= 2e-10) give 0, as in Cycles.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from .geometry import clip_convex, irradiance_vector
from .ggx import (ROUGHNESS_SQ_THRESHOLD, GGXMaterial, GlossyMaterial, PrincipledMetal, PrincipledSpecular,
                  albedo_tables, alpha_from_roughness, energy_factor, lookup_table)
from .phong import clip_to_half_spaces, vertex_count_from_padding

LTC_TABLE_PATH = Path(__file__).resolve().parent / "data" / "ltc_ggx.npz"


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...k,...k->...", a, b)


@functools.lru_cache(maxsize=1)
def ltc_tables() -> dict[str, np.ndarray]:
    """The published fit (read once).

    inverse_matrix : (64, 64, 4) float64, [j, i, (a, b, c, d)] with M⁻¹ = [[a, 0, c], [0, 1, 0], [b, 0, d]] at
        roughness i / 63 and sqrt(1 - cos θ_o) = j / 63, in the frame (T1, T2, N).
    magnitude : (64, 64, 2) float64, the fit's own (norm, Schlick) estimates (kept for reference, unused).
    """
    with np.load(LTC_TABLE_PATH) as data:
        return {key: np.asarray(data[key], dtype=np.float64) for key in data.files}


def view_parameter(cos_view: np.ndarray) -> np.ndarray:
    """The tables' second coordinate sqrt(1 - cos θ_o), (M,)."""
    return np.sqrt(np.clip(1.0 - np.asarray(cos_view, dtype=np.float64), 0.0, 1.0))


def ltc_frame(normal: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Rows (T1, T2, N) of each receiver's frame, (M, 3, 3): T1 = normalize(V - N (V·N)), T2 = N × T1.

    At normal incidence (V ∥ N) the lobe is isotropic and any T1 ⟂ N is used.
    """
    normal = np.asarray(normal, dtype=np.float64)
    view = np.asarray(view, dtype=np.float64)
    tangent = view - _dot(view, normal)[:, None] * normal
    length = np.sqrt(_dot(tangent, tangent))
    # Fallback axis: the coordinate axis least aligned with N, made perpendicular to it.
    helper = np.eye(3)[np.argmin(np.abs(normal), axis=1)]
    fallback = helper - _dot(helper, normal)[:, None] * normal
    fallback /= np.linalg.norm(fallback, axis=1, keepdims=True)
    tangent = np.where((length > 1e-12)[:, None], tangent / np.maximum(length, 1e-300)[:, None], fallback)
    bitangent = np.cross(normal, tangent)
    return np.stack([tangent, bitangent, normal], axis=1)


def ltc_inverse_matrix(roughness, cos_view) -> np.ndarray:
    """M⁻¹ (M, 3, 3) interpolated bilinearly from the fit at (roughness, sqrt(1 - cos θ_o))."""
    roughness = np.asarray(roughness, dtype=np.float64)
    coordinate = view_parameter(cos_view)
    table = ltc_tables()["inverse_matrix"]
    a, b, c, d = (lookup_table(table[..., k], roughness, coordinate) for k in range(4))
    inverse = np.zeros(a.shape + (3, 3))
    inverse[..., 0, 0], inverse[..., 0, 2] = a, c
    inverse[..., 1, 1] = 1.0
    inverse[..., 2, 0], inverse[..., 2, 2] = b, d
    return inverse


def ltc_density(directions, normal, view, roughness) -> np.ndarray:
    """The fitted lobe D_ltc (S,) per unit solid angle at unit directions (S, 3): the clamped cosine
    D_o(ω_o) = max(ω_o.z, 0) / π at ω_o = M⁻¹ F ω / |M⁻¹ F ω|, times the Jacobian |det M⁻¹| / |M⁻¹ F ω|³
    (F the receiver's ``ltc_frame``); normal, view (S, 3), roughness (S,). Its integral over a polygon is
    ``ltc_shape_integral``'s share."""
    cos_view = _dot(normal, view)
    inverse = ltc_inverse_matrix(roughness, cos_view)
    local = np.einsum("sij,sjk,sk->si", inverse, ltc_frame(normal, view), directions)
    length = np.linalg.norm(local, axis=1)
    determinant = np.abs(np.linalg.det(inverse))
    length = np.maximum(length, 1e-300)
    return np.maximum(local[:, 2] / length, 0.0) / np.pi * determinant / length ** 3


def ltc_adjugate(inverse: np.ndarray) -> np.ndarray:
    """adj(M⁻¹) (M, 3, 3) = det(M⁻¹) · M for LTC's M⁻¹ with its fitted zeros (``ltc_inverse_matrix``: [[a, 0, c],
    [0, 1, 0], [b, 0, d]], whose adjugate is [[d, 0, -c], [0, ad - bc, 0], [-b, 0, a]]; the fit's determinant
    ad - bc is positive). By components: np.linalg calls OpenBLAS, whose own threads fought the render's pool."""
    a, c, b, d = inverse[:, 0, 0], inverse[:, 0, 2], inverse[:, 2, 0], inverse[:, 2, 2]
    adjugate = np.zeros_like(inverse)
    adjugate[:, 0, 0], adjugate[:, 0, 2] = d, -c
    adjugate[:, 1, 1] = a * d - b * c
    adjugate[:, 2, 0], adjugate[:, 2, 2] = -b, a
    return adjugate


def ltc_shape_integral(directions, normal, view, roughness, count=None, centroid: bool = False):
    """∫_P D_ltc dω: the fraction of the fitted lobe that falls in each polygon, (M,) in [0, 1].

    Parameters
    ----------
    directions : (M, K, 3) float64  convex polygon vertices relative to the receiver, padded by repeating
                                     the last vertex (any length, any winding). Clipped to N·p >= 0 here
                                     (a no-op for pieces already clipped to the receiver's hemisphere).
    normal : (M, 3) unit shading normal; view : (M, 3) unit direction towards the camera.
    roughness : (M,) or scalar (α = roughness²).
    count : (M,) int64, optional vertex counts (inferred from the padding when omitted).
    centroid : bool                  also return the lobe-weighted mean direction over each polygon, (M, 3)
                                     unit world vectors (zero where the share is 0): the clamped cosine's
                                     mean direction over M⁻¹P (its vector form factor) mapped back by M.
                                     Cycles' Fresnel evaluated there weights the polygon's share of the lobe.
    """
    points = np.asarray(directions, dtype=np.float64)
    normal = np.asarray(normal, dtype=np.float64)
    view = np.asarray(view, dtype=np.float64)
    rows = len(points)
    count = vertex_count_from_padding(points) if count is None else np.asarray(count, dtype=np.int64)
    roughness = np.broadcast_to(np.asarray(roughness, dtype=np.float64), (rows,))
    points, count = clip_to_half_spaces(points, count, normal)
    cos_view = _dot(normal, view)
    # local_from_world is the frame; the transformed vertex is M⁻¹ (frame p).
    inverse = ltc_inverse_matrix(roughness, cos_view)
    frame = ltc_frame(normal, view)
    transform = np.einsum("mij,mjk->mik", inverse, frame)
    transformed = np.einsum("mij,mkj->mki", transform, points)
    clipped, clipped_count = clip_convex(transformed, count, transformed[..., 2])
    vector = irradiance_vector(clipped)
    vector *= np.where(vector[:, 2] < 0.0, -1.0, 1.0)[:, None]  # either winding: the upper side
    fraction = vector[:, 2] / np.pi
    smooth = alpha_from_roughness(roughness) ** 2 <= ROUGHNESS_SQ_THRESHOLD
    valid = (clipped_count >= 3) & (cos_view > 0.0) & ~smooth
    share = np.where(valid, fraction, 0.0)
    if not centroid:
        return share
    # Back by M = adj(M⁻¹) / det M⁻¹; directions only matter, so the determinant is dropped.
    local = np.einsum("mij,mj->mi", ltc_adjugate(inverse), vector)
    world = np.einsum("mji,mj->mi", frame, local)
    length = np.linalg.norm(world, axis=1, keepdims=True)
    world = np.where(valid[:, None] & (length > 0), world / np.maximum(length, 1e-300), 0.0)
    return share, world


def lobe_magnitudes(roughness, cos_view) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact hemispherical moments of Cycles' single-scattering lobe at (roughness, cos θ_o), each (M,).

    norm = ∫ f cos θ_i dω_i; schlick = ∫ f cos θ_i (1 - c)^5 dω_i; f82 = ∫ f cos θ_i c (1 - c)^6 dω_i,
    c = ω_o · h.
    """
    tables = albedo_tables()
    coordinate = view_parameter(cos_view)
    norm = lookup_table(tables["ltc_norm"], roughness, coordinate)
    schlick = norm * lookup_table(tables["ltc_schlick"], roughness, coordinate)
    f82 = norm * lookup_table(tables["ltc_f82"], roughness, coordinate)
    return norm, schlick, f82


def ltc_ggx_integral(directions, normal, view, roughness, f0=1.0, f90=1.0, count=None) -> np.ndarray:
    """∫_P f cos θ_i dω_i for the single-scattering GGX lobe with Schlick Fresnel, (M, 3), dimensionless.

    f = F D G2 / (4 cos θ_i cos θ_o), F = f0 + (f90 - f0)(1 - ω_o·h)^5; the Fresnel term is integrated over
    the hemisphere (f0 (norm - schlick) + f90 schlick) and the polygon takes the LTC's share of the lobe.
    f0, f90 : scalar, (3,), (M, 1) or (M, 3). f0 = f90 = 1 is Cycles' white Glossy BSDF (GGX, no
    multiscatter). Parameters otherwise as ``ltc_shape_integral``.
    """
    normal = np.asarray(normal, dtype=np.float64)
    rows = len(normal)
    roughness = np.broadcast_to(np.asarray(roughness, dtype=np.float64), (rows,))
    cos_view = _dot(normal, np.asarray(view, dtype=np.float64))
    norm, schlick, _ = lobe_magnitudes(roughness, cos_view)
    f0 = np.broadcast_to(np.asarray(f0, dtype=np.float64), (rows, 3))
    f90 = np.broadcast_to(np.asarray(f90, dtype=np.float64), (rows, 3))
    magnitude = f0 * (norm - schlick)[:, None] + f90 * schlick[:, None]
    return ltc_shape_integral(directions, normal, view, roughness, count)[:, None] * magnitude


def material_magnitude(material: GGXMaterial, roughness, cos_view) -> np.ndarray:
    """∫_hemisphere F(ω_o·h) D G2 / (4 cos θ_o) dω_i for a Cycles closure's Fresnel model, (M, 3).

    Glossy: norm. Principled dielectric: norm · mix(f0, 1, t) with t the lobe-weighted mean of the real
    Fresnel blend s(c, η) (table ``ltc_dielectric``). Principled metal (F82-tint, unclamped):
    f0 (norm - schlick) + schlick - b · f82.
    """
    cos_view = np.asarray(cos_view, dtype=np.float64)
    rows = len(cos_view)
    roughness = np.broadcast_to(np.asarray(roughness, dtype=np.float64), (rows,))
    norm, schlick, f82 = lobe_magnitudes(roughness, cos_view)
    if isinstance(material, GlossyMaterial):
        return np.repeat(norm[:, None], 3, axis=1)
    if isinstance(material, PrincipledSpecular):
        eta, f0 = material.eta_f0(rows)
        z = np.sqrt(np.abs((eta - 1.0) / (eta + 1.0)))
        blend = lookup_table(albedo_tables()["ltc_dielectric"], roughness, view_parameter(cos_view), z)[:, None]
        value = norm[:, None] * (f0 + (1.0 - f0) * blend)
        return np.where(material.exists(rows)[:, None], value, 0.0)
    if isinstance(material, PrincipledMetal):
        f0, b = material.f0_b(rows)
        return f0 * (norm - schlick)[:, None] + schlick[:, None] - b * f82[:, None]
    raise TypeError(f"unsupported material {type(material).__name__}")


def ltc_ggx_material_integral(directions, normal, view, roughness, material: GGXMaterial = GlossyMaterial(),
                              count=None) -> np.ndarray:
    """∫_P ggx_brdf(ω_i, ω_o; material) cos θ_i dω_i, (M, 3), dimensionless: Cycles' closure over a polygon.

    The LTC share of the lobe times the exact hemispherical magnitude of the closure's Fresnel model
    (``material_magnitude``) times its weight and Multiscatter GGX factor (``ggx.energy_factor``, constant
    over ω_i). Parameters as ``ltc_shape_integral``.
    """
    normal = np.asarray(normal, dtype=np.float64)
    rows = len(normal)
    roughness = np.broadcast_to(np.asarray(roughness, dtype=np.float64), (rows,))
    cos_view = _dot(normal, np.asarray(view, dtype=np.float64))
    magnitude = material_magnitude(material, roughness, cos_view) * energy_factor(material, roughness, cos_view)
    return ltc_shape_integral(directions, normal, view, roughness, count)[:, None] * magnitude
