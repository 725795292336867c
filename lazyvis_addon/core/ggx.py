"""The GGX microfacet BRDF exactly as Cycles (Blender 4.x / 5.0) evaluates it, for Monte Carlo and for tests.

Conventions (all arrays float64, one row per shading sample, N rows):

- ``wi`` (N, 3): unit direction from the receiver towards the light (the incident direction ω_i).
- ``wo`` (N, 3): unit direction from the receiver towards the camera (ω_o, the view).
- ``normal`` (N, 3): unit shading normal.
- ``roughness`` (N,) or scalar: the user-facing roughness in [0, 1]; the GGX width is α = roughness².
- Every BRDF is in 1/sr; colours are (N, 3) linear RGB.

What Cycles does (read in ``intern/cycles/kernel/closure/bsdf_microfacet.h``, ``bsdf_util.h``,
``kernel/svm/closure.h``, ``kernel/util/lookup_table.h`` and ``app/cycles_precompute.cpp``):

- ``bsdf_D``: D(h) = α² / (π ((1 - cos²θ_h) + α² cos²θ_h)²).
- ``bsdf_lambda``: Λ(ω) = (sqrt(1 + α² tan²θ) - 1) / 2, and ``bsdf_G`` is the *height-correlated*
  G2 = 1 / (1 + Λ(ω_i) + Λ(ω_o)), not G1·G1.
- ``bsdf_microfacet_eval`` (reflection): f = F(h·ω_o) · D · G2 / (4 cos θ_i cos θ_o), zero unless both
  cosines are positive and α_x α_y > 2e-10 (``BSDF_ROUGHNESS_SQ_THRESH``: smoother is a mirror, which
  has no evaluable density and contributes nothing to area-light shading).
- Glossy BSDF (``CLOSURE_BSDF_MICROFACET_GGX_ID`` / ``..._MULTI_GGX_ID``): no Fresnel, the node colour
  is the closure weight.
- Principled BSDF dielectric specular: Fresnel type ``GENERALIZED_SCHLICK`` with a negative exponent,
  i.e. the real dielectric Fresnel curve remapped onto [F0, F90]:
  F = mix(f0, 1, s), s = saturate((F_real(h·ω_o, η) - F0(η)) / (1 - F0(η))), where the IOR is first
  adjusted by Specular IOR Level (f0 = F0(ior) · 2 · level, η = ior_from_F0(f0)) and f0 is then tinted by
  Specular Tint and saturated. No specular lobe exists when η = 1 (IOR 1 or level 0).
- Principled BSDF metal: ``F82_TINT`` (Kutz et al., Adobe Standard Material): Schlick with F0 = base
  colour minus b cos θ (1 - cos θ)^6, b chosen so that the value at cos θ = 1/7 is Schlick times the
  Specular Tint; b = 0 for a white tint, i.e. plain Schlick.
- Multiscatter GGX (``microfacet_ggx_preserve_energy``, Kulla & Conty 2017): the single-scattering
  lobe is multiplied by the constant (over ω_i) 1 + F_ms (1 - E) / E, with E = E(roughness, cos θ_o) the
  single-scattering albedo, E_avg its cosine-weighted average, F_ss the average Fresnel and
  F_ms = F_ss E_avg / (1 - F_ss (1 - E_avg)). For a white lobe this is 1 / E: the albedo becomes 1.
- Principled layering (``closure_layering_weight`` with ``bsdf_microfacet_estimate_albedo``): the diffuse
  base under the dielectric specular is weighted by saturate(1 - max_rgb(albedo_spec)), with
  albedo_spec = darkening · mix(f0, 1, s̄) and s̄ from the ``ggx_gen_schlick_ior_s`` table.

The albedo tables (E, E_avg, s̄) are generated here by deterministic quadrature on Cycles' own grids
(``tools/make_ggx_tables.py`` -> ``data/ggx_albedo.npz``); they agree with the Monte Carlo tables shipped in
Cycles' ``scene/shader.tables`` to within that file's sampling noise (see ``data/README.md``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

DATA_DIR = Path(__file__).resolve().parent / "data"
ALBEDO_TABLE_PATH = DATA_DIR / "ggx_albedo.npz"

ROUGHNESS_SQ_THRESHOLD = 2e-10
"""Cycles' ``BSDF_ROUGHNESS_SQ_THRESH``: below α² = 2e-10 (roughness < 0.0038) a GGX lobe is a mirror."""



# ------------------------------------------------------------------------------------------------------
# Small helpers
# ------------------------------------------------------------------------------------------------------

def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot product over the last axis."""
    return np.einsum("...k,...k->...", a, b)


def _rows(value, count: int) -> np.ndarray:
    """A scalar or (N,) parameter as an (N,) float64 array."""
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (count,)).astype(np.float64)


def _colours(value, count: int) -> np.ndarray:
    """A scalar, (3,) or (N, 3) colour as an (N, 3) float64 array."""
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (count, 3)).astype(np.float64)


def alpha_from_roughness(roughness) -> np.ndarray:
    """GGX width α = saturate(roughness)², as both the Glossy and the Principled BSDF compute it."""
    return np.clip(np.asarray(roughness, dtype=np.float64), 0.0, 1.0) ** 2


# ------------------------------------------------------------------------------------------------------
# Microfacet distribution and shadowing
# ------------------------------------------------------------------------------------------------------

def ggx_distribution(cos_nh, alpha) -> np.ndarray:
    """GGX normal distribution D(h) in 1/sr (per unit solid angle of microfacet normals).

    D = α² / (π (sin²θ_h + α² cos²θ_h)²); ∫ D cos θ_h dω_h = 1 over the hemisphere. Written with
    sin²θ_h = 1 - cos²θ_h as Cycles does, which keeps the peak exact for tiny α.
    """
    cos2 = np.minimum(np.asarray(cos_nh, dtype=np.float64) ** 2, 1.0)
    alpha2 = np.asarray(alpha, dtype=np.float64) ** 2
    return alpha2 / (np.pi * ((1.0 - cos2) + alpha2 * cos2) ** 2)


def ggx_lambda(cos_n, alpha) -> np.ndarray:
    """Smith's Λ for GGX: (sqrt(1 + α² tan²θ) - 1) / 2; +inf at grazing (cos θ = 0), 0 at cos θ = 1."""
    cos2 = np.asarray(cos_n, dtype=np.float64) ** 2
    alpha2 = np.asarray(alpha, dtype=np.float64) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        tan2 = np.maximum(1.0 / cos2 - 1.0, 0.0)
        return 0.5 * (np.sqrt(1.0 + alpha2 * tan2) - 1.0)


def ggx_g1(cos_n, alpha) -> np.ndarray:
    """Smith masking G1 = 1 / (1 + Λ)."""
    return 1.0 / (1.0 + ggx_lambda(cos_n, alpha))


def ggx_g2(cos_i, cos_o, alpha) -> np.ndarray:
    """Height-correlated Smith masking-shadowing G2 = 1 / (1 + Λ(ω_i) + Λ(ω_o)) (Heitz 2014, Eq. 99)."""
    return 1.0 / (1.0 + ggx_lambda(cos_i, alpha) + ggx_lambda(cos_o, alpha))


def ggx_single_scatter(wi, wo, normal, roughness) -> tuple[np.ndarray, np.ndarray]:
    """The Fresnel-free single-scattering GGX lobe D G2 / (4 cos θ_i cos θ_o) and the half-vector cosine.

    Parameters
    ----------
    wi, wo, normal : (N, 3) float64 unit vectors (light, view, shading normal).
    roughness : (N,) or scalar.

    Returns
    -------
    value : (N,) float64 in 1/sr; 0 where either direction is at or below the horizon, where ω_i = -ω_o,
        or where α² <= ``ROUGHNESS_SQ_THRESHOLD`` (a mirror).
    cos_hv : (N,) float64, h · ω_o (= h · ω_i), the cosine every Fresnel term is evaluated at.
    """
    wi, wo, normal = (np.asarray(v, dtype=np.float64) for v in (wi, wo, normal))
    alpha = alpha_from_roughness(_rows(roughness, len(wi)))
    cos_i, cos_o = _dot(normal, wi), _dot(normal, wo)
    half = wi + wo
    half_length = np.sqrt(_dot(half, half))
    valid = (cos_i > 0.0) & (cos_o > 0.0) & (half_length > 0.0) & (alpha ** 2 > ROUGHNESS_SQ_THRESHOLD)
    half = half / np.where(half_length > 0.0, half_length, 1.0)[:, None]
    cos_nh = _dot(normal, half)
    cos_hv = np.clip(_dot(half, wo), 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        value = ggx_distribution(cos_nh, alpha) * ggx_g2(cos_i, cos_o, alpha) / (4.0 * cos_i * cos_o)
    return np.where(valid, value, 0.0), cos_hv


def orthonormal_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (N, 3) completing unit normals (N, 3) to a right-handed frame (Duff et al. 2017)."""
    x, y, z = normal[:, 0], normal[:, 1], normal[:, 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    tangent = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=1)
    bitangent = np.stack([b, sign + y * y * a, -y], axis=1)
    return tangent, bitangent


def sample_ggx_reflection(wo, normal, roughness, u) -> tuple[np.ndarray, np.ndarray]:
    """Directions ω_i reflected about GGX microfacet normals sampled from the visible normals (Heitz 2018).

    Parameters
    ----------
    wo, normal : (N, 3) unit (view, shading normal; wo above the surface); roughness : (N,); u : (N, 2).

    Returns
    -------
    wi : (N, 3) unit, possibly below the horizon (then its BSDF is 0).
    pdf : (N,) per steradian of ω_i: G1(ω_o) D(h) / (4 cos θ_o) (``ggx_reflection_pdf``).
    """
    wo, normal = np.asarray(wo, dtype=np.float64), np.asarray(normal, dtype=np.float64)
    alpha = np.maximum(alpha_from_roughness(_rows(roughness, len(wo))), 1e-4)
    tangent, bitangent = orthonormal_basis(normal)
    local = np.stack([_dot(wo, tangent), _dot(wo, bitangent), _dot(wo, normal)], axis=1)
    stretched = np.stack([alpha * local[:, 0], alpha * local[:, 1], local[:, 2]], axis=1)
    stretched /= np.linalg.norm(stretched, axis=1, keepdims=True)
    length2 = stretched[:, 0] ** 2 + stretched[:, 1] ** 2
    inv = np.where(length2 > 0.0, 1.0 / np.sqrt(np.maximum(length2, 1e-300)), 0.0)
    t1 = np.where((length2 > 0.0)[:, None], np.stack([-stretched[:, 1] * inv, stretched[:, 0] * inv,
                                                        np.zeros(len(wo))], axis=1), [1.0, 0.0, 0.0])
    t2 = np.cross(stretched, t1)
    radius, phi = np.sqrt(u[:, 0]), 2.0 * np.pi * u[:, 1]
    p1, p2 = radius * np.cos(phi), radius * np.sin(phi)
    blend = 0.5 * (1.0 + stretched[:, 2])
    p2 = (1.0 - blend) * np.sqrt(np.maximum(1.0 - p1 * p1, 0.0)) + blend * p2
    pz = np.sqrt(np.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))
    hemisphere = p1[:, None] * t1 + p2[:, None] * t2 + pz[:, None] * stretched
    h_local = np.stack([alpha * hemisphere[:, 0], alpha * hemisphere[:, 1], np.maximum(hemisphere[:, 2], 0.0)],
                       axis=1)
    h_local /= np.maximum(np.linalg.norm(h_local, axis=1, keepdims=True), 1e-300)
    half = h_local[:, :1] * tangent + h_local[:, 1:2] * bitangent + h_local[:, 2:] * normal
    wi = 2.0 * _dot(wo, half)[:, None] * half - wo
    return wi, ggx_reflection_pdf(wi, wo, normal, roughness)


def ggx_reflection_pdf(wi, wo, normal, roughness) -> np.ndarray:
    """Density (N,) per steradian of ``sample_ggx_reflection`` at ω_i: D(h) G1(ω_o) / (4 cos θ_o)."""
    alpha = np.maximum(alpha_from_roughness(_rows(roughness, len(wi))), 1e-4)
    cos_o = _dot(normal, wo)
    half = wi + wo
    length = np.sqrt(_dot(half, half))
    half = half / np.maximum(length, 1e-300)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        pdf = ggx_distribution(_dot(normal, half), alpha) * ggx_g1(cos_o, alpha) / (4.0 * cos_o)
    return np.where((cos_o > 0.0) & (length > 0.0) & (_dot(half, wo) > 0.0), pdf, 0.0)


# ------------------------------------------------------------------------------------------------------
# Fresnel
# ------------------------------------------------------------------------------------------------------

def fresnel_dielectric(cos_theta, eta) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a smooth dielectric interface (Cycles' ``fresnel_dielectric``).

    cos_theta : cosine of the incidence angle (its absolute value is used); eta : relative IOR
    (inside / outside). Written as F = ½ ((g - c)/(g + c))² (1 + ((c(g + c) - 1)/(c(g - c) + 1))²),
    g = sqrt(η² - 1 + c²); 1 under total internal reflection (g² <= 0).
    """
    c = np.abs(np.asarray(cos_theta, dtype=np.float64))
    eta = np.asarray(eta, dtype=np.float64)
    g2 = eta ** 2 - 1.0 + c ** 2
    g = np.sqrt(np.maximum(g2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        value = 0.5 * a * a * (1.0 + b * b)
    return np.where(g2 > 0.0, np.nan_to_num(value, nan=1.0), 1.0)


# Every closure's Fresnel as a combination of four functions of c = ω_o·h, so that an integral over a piece
# can carry the Fresnel point by point in one pass (``illumination.ltc_residual``): F(c) = Σ_k coefficient_k
# · basis_k(c), basis = (1, s(c, η), (1 - c)^5, c (1 - c)^6) with s the dielectric blend of
# ``PrincipledSpecular.blend``. Exact for the Glossy BSDF (1), the Principled specular (F0 + (1 - F0) s) and
# the unclamped F82-tint metal (F0 + (1 - F0)(1 - c)^5 - b c (1 - c)^6). Cycles clamps the metal's to [0, 1],
# which the basis leaves out: it binds where a dark base colour meets a strong edge tint (F0 0 and Specular
# Tint 0: below 0 for c in 0.15-0.85), never at the default tint of 1 (b = 0); there the correction
# integrates the unclamped curve.
FRESNEL_BASIS_SIZE = 4


def fresnel_basis(cos_hv, eta) -> np.ndarray:
    """The four Fresnel basis functions at c = ``cos_hv`` (N,) for relative IORs ``eta`` (N,), (N, 4)."""
    c = np.clip(np.asarray(cos_hv, dtype=np.float64), 0.0, 1.0)
    s = 1.0 - c
    return np.stack([np.ones_like(c), PrincipledSpecular.blend(c, np.asarray(eta, np.float64)), s ** 5,
                     c * s ** 6], axis=1)


@njit(cache=True, nogil=True)
def dielectric_blend(c, eta):
    """``PrincipledSpecular.blend`` for one cosine c in [0, 1] and one η (compiled, for the kernels)."""
    g2 = eta * eta - 1.0 + c * c
    if g2 <= 0.0:
        real = 1.0
    else:
        g = np.sqrt(g2)
        a = (g - c) / (g + c)
        denominator = c * (g - c) + 1.0
        b = (c * (g + c) - 1.0) / denominator if denominator != 0.0 else 0.0
        real = 0.5 * a * a * (1.0 + b * b)
    real_f0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    if real_f0 >= 1.0:
        return 0.0
    return min(max((real - real_f0) / (1.0 - real_f0), 0.0), 1.0)


def f0_from_ior(ior) -> np.ndarray:
    """Normal-incidence reflectance ((η - 1) / (η + 1))²."""
    ior = np.asarray(ior, dtype=np.float64)
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def ior_from_f0(f0) -> np.ndarray:
    """Inverse of ``f0_from_ior`` for η >= 1, with f0 clamped to [0, 0.99] as Cycles does."""
    root = np.sqrt(np.clip(np.asarray(f0, dtype=np.float64), 0.0, 0.99))
    return (1.0 + root) / (1.0 - root)


def fresnel_dielectric_average(eta) -> np.ndarray:
    """Cosine-weighted average 2 ∫ F(μ, η) μ dμ of the dielectric Fresnel term.

    Cycles' ``fresnel_dielectric_Fss``, a rational fit from Kulla & Conty, "Revisiting Physically Based
    Shading at Imageworks" (SIGGRAPH 2017 course). Used only for multiscatter colour, so the fit's
    ~1e-3 error is immaterial.
    """
    eta = np.asarray(eta, dtype=np.float64)
    below = 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607))
    above = (eta - 1.0) / (4.08567 + 1.00071 * eta)
    return np.where(eta < 1.0, below, above)


def f82_tint_b(f0, tint) -> np.ndarray:
    """The F82-tint coefficient b (per channel) from F0 and the edge tint (Cycles' ``fresnel_f82tint_B``).

    Solves Schlick(1/7) - b (1/7)(6/7)^6 = tint · Schlick(1/7): b = Schlick(1/7) · 7 / (6/7)^6 · (1 - tint).
    """
    f0, tint = np.asarray(f0, dtype=np.float64), np.asarray(tint, dtype=np.float64)
    edge = 6.0 / 7.0
    schlick_82 = f0 + (1.0 - f0) * edge ** 5
    return schlick_82 * (7.0 / edge ** 6) * (1.0 - tint)


def fresnel_f82_tint(cos_theta, f0, b) -> np.ndarray:
    """F82-tint conductor Fresnel saturate(f0 + (1 - f0)(1 - μ)^5 - b μ (1 - μ)^6), per channel.

    cos_theta : (N,); f0, b : (N, 3). Returns (N, 3).
    """
    mu = np.asarray(cos_theta, dtype=np.float64)[:, None]
    s = np.clip(1.0 - mu, 0.0, 1.0)
    return np.clip(f0 + (1.0 - f0) * s ** 5 - b * mu * s ** 6, 0.0, 1.0)


def f82_average(f0, b) -> np.ndarray:
    """Exact cosine-weighted average of the unclamped F82 model: mix(f0, 1, 1/21) - b / 126."""
    f0 = np.asarray(f0, dtype=np.float64)
    return f0 + (1.0 - f0) / 21.0 - np.asarray(b, dtype=np.float64) / 126.0


# ------------------------------------------------------------------------------------------------------
# Albedo tables and multiscatter compensation
# ------------------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def albedo_tables() -> dict[str, np.ndarray]:
    """The precomputed albedo tables (read once). See ``tools/make_ggx_tables.py`` and ``data/README.md``.

    Keys
    ----
    E : (32, 32) float64, [cos θ_o index, roughness index]: single-scattering albedo of the white lobe,
        nodes at roughness = i / 31, cos θ_o = max(j / 31, 1e-4) (Cycles' ``table_ggx_E`` grid).
    E_avg : (32,) float64: 2 ∫ E μ dμ per roughness node (``table_ggx_Eavg``).
    gen_schlick_ior_s : (16, 16, 16) float64, [z, cos θ_o, roughness]: Cycles' Fresnel blend factor
        (``table_ggx_gen_schlick_ior_s``), z = sqrt((η - 1) / (η + 1)) on nodes z = clamp(k / 15, 1e-4, 0.99).
    ltc_norm, ltc_schlick, ltc_f82 : (64, 64), ltc_dielectric : (16, 32, 32): the LTC magnitudes
        (see ``ltc.lobe_magnitudes`` and ``ltc.material_magnitude``).
    """
    with np.load(ALBEDO_TABLE_PATH) as data:
        return {key: np.asarray(data[key], dtype=np.float64) for key in data.files}


def lookup_table(table: np.ndarray, *coordinates) -> np.ndarray:
    """Multilinear lookup on a regular grid over [0, 1]^d, as Cycles' ``lookup_table_read_{,2D,3D}``.

    table : (n_d, ..., n_1) array, the last axis indexed by the *first* coordinate (Cycles' x).
    coordinates : d arrays of equal shape, clamped to [0, 1]; node i of an axis of size n sits at i / (n - 1).

    Compiled (the 2^d corners' weights and sum in the order numpy took them, so the same numbers): as numpy
    passes per corner it was the glossy sample's largest numpy cost (678 small lookups at 256 px).
    """
    coordinates = [np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0) for c in coordinates]
    shape = np.broadcast(*coordinates).shape
    stacked = np.stack([np.broadcast_to(c, shape).ravel() for c in coordinates], axis=1)
    sizes = np.asarray(table.shape[::-1], dtype=np.int64)        # per coordinate, the axis it indexes
    out = np.empty(len(stacked))
    _lookup(np.ascontiguousarray(table, dtype=np.float64).ravel(), sizes, stacked, out)
    return out.reshape(shape)


@njit(cache=True, nogil=True)
def _lookup(flat, sizes, coordinates, out):
    """``lookup_table`` on the C-order ``flat`` table: coordinate a indexes the axis of size sizes[a], whose
    stride is the product of the sizes before it."""
    dims = len(sizes)
    lower = np.empty(dims, np.int64)
    frac = np.empty(dims)
    for n in range(len(out)):
        for axis in range(dims):
            position = coordinates[n, axis] * (sizes[axis] - 1)
            lower[axis] = min(np.int64(position), sizes[axis] - 1)
            frac[axis] = position - lower[axis]
        result = 0.0
        for corner in range(1 << dims):  # 2^d corners
            weight = 1.0
            index, stride = 0, 1
            for axis in range(dims):
                up = (corner >> axis) & 1
                index += min(lower[axis] + up, sizes[axis] - 1) * stride
                stride *= sizes[axis]
                weight = weight * (frac[axis] if up else 1.0 - frac[axis])
            result += weight * flat[index]
        out[n] = result


def single_scatter_albedo(roughness, cos_view) -> np.ndarray:
    """E(roughness, cos θ_o): directional albedo of the white single-scattering GGX lobe, (N,)."""
    return lookup_table(albedo_tables()["E"], roughness, cos_view)


def single_scatter_albedo_average(roughness) -> np.ndarray:
    """E_avg(roughness) = 2 ∫ E(μ) μ dμ, (N,)."""
    return lookup_table(albedo_tables()["E_avg"], roughness)


def multiscatter_compensation(roughness, cos_view, average_fresnel) -> np.ndarray:
    """Cycles' multiscatter factor 1 + F_ms (1 - E) / E on the single-scattering lobe, (N, 3).

    Parameters
    ----------
    roughness, cos_view : (N,) (cos_view = normal · ω_o).
    average_fresnel : (N, 3) F_ss, the lobe's cosine-weighted average Fresnel (white: 1).

    Cycles stores this as ``energy_scale`` = 1 + (1 - E)/E times a per-channel ``darkening`` (1 + F_ms
    missing) / energy_scale on the closure weight; the product is returned here. Constant over ω_i.
    """
    roughness = np.asarray(roughness, dtype=np.float64)
    energy = single_scatter_albedo(roughness, cos_view)[:, None]
    energy_avg = single_scatter_albedo_average(roughness)[:, None]
    fss = np.asarray(average_fresnel, dtype=np.float64)
    fms = fss * energy_avg / (1.0 - fss * (1.0 - energy_avg))
    return 1.0 + fms * (1.0 - energy) / energy


# ------------------------------------------------------------------------------------------------------
# Materials: the Fresnel model and multiscatter setting of one GGX closure
# ------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class GlossyMaterial:
    """Glossy BSDF, distribution GGX (``multiscatter=False``) or Multiscatter GGX (the default).

    colour : (3,) or (N, 3) linear RGB tint (the closure weight); no Fresnel.
    """

    colour: object = (1.0, 1.0, 1.0)
    multiscatter: bool = True

    def reflectance(self, cos_hv: np.ndarray) -> np.ndarray:
        """The Fresnel factor at the microfacet, (N, 3): none (1); the tint is the closure weight."""
        return np.ones((len(cos_hv), 3))

    def fresnel_terms(self, count: int) -> tuple[np.ndarray, None]:
        """``reflectance`` in the Fresnel basis (``fresnel_basis``): coefficients (N, 4, 3), and no η."""
        terms = np.zeros((count, FRESNEL_BASIS_SIZE, 3))
        terms[:, 0] = 1.0
        return terms, None

    def average_fresnel(self, count: int) -> np.ndarray:
        """F_ss for the multiscatter colour, (N, 3): the tint itself (``setup_fresnel_constant``)."""
        return _colours(self.colour, count)

    def weight(self, count: int) -> np.ndarray:
        """Factor outside the Fresnel-weighted lobe, (N, 3): the tint (Cycles' closure weight)."""
        return _colours(self.colour, count)


@dataclass(frozen=True)
class PrincipledSpecular:
    """The dielectric specular layer of the Principled BSDF (metallic 0, transmission 0, no coat).

    ior : (N,) or scalar IOR input; specular_ior_level : Specular IOR Level (0.5 = physical);
    specular_tint : (3,) or (N, 3).
    """

    ior: object = 1.5
    specular_ior_level: object = 0.5
    specular_tint: object = (1.0, 1.0, 1.0)
    multiscatter: bool = True

    def eta_f0(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """The adjusted relative IOR η (N,) and tinted, saturated F0 (N, 3), as ``svm_node_closure_bsdf``."""
        ior = np.maximum(_rows(self.ior, count), 1e-5)
        level = np.maximum(_rows(self.specular_ior_level, count), 0.0)
        f0 = f0_from_ior(ior)
        adjusted = level != 0.5
        f0 = np.where(adjusted, f0 * 2.0 * level, f0)
        eta = np.where(adjusted, ior_from_f0(f0), ior)
        eta = np.where(adjusted & (ior < 1.0), 1.0 / eta, eta)
        tint = np.maximum(_colours(self.specular_tint, count), 0.0)
        return eta, np.clip(f0[:, None] * tint, 0.0, 1.0)

    def exists(self, count: int) -> np.ndarray:
        """(N,) bool: Cycles creates the specular closure only when η != 1."""
        return self.eta_f0(count)[0] != 1.0

    @staticmethod
    def blend(cos_hv: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """s = saturate((F_real - F0_real) / (1 - F0_real)), the real Fresnel curve mapped to [0, 1], (N,)."""
        real_f0 = f0_from_ior(eta)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (fresnel_dielectric(cos_hv, eta) - real_f0) / (1.0 - real_f0)
        return np.clip(np.nan_to_num(s, nan=0.0), 0.0, 1.0)

    def reflectance(self, cos_hv: np.ndarray) -> np.ndarray:
        eta, f0 = self.eta_f0(len(cos_hv))
        s = self.blend(cos_hv, eta)[:, None]
        return np.where(self.exists(len(cos_hv))[:, None], f0 + (1.0 - f0) * s, 0.0)

    def fresnel_terms(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """``reflectance`` in the Fresnel basis: coefficients (N, 4, 3) and the blend's η (N,)."""
        eta, f0 = self.eta_f0(count)
        exists = self.exists(count)[:, None]
        terms = np.zeros((count, FRESNEL_BASIS_SIZE, 3))
        terms[:, 0], terms[:, 1] = np.where(exists, f0, 0.0), np.where(exists, 1.0 - f0, 0.0)
        return terms, eta

    def average_fresnel(self, count: int) -> np.ndarray:
        eta, f0 = self.eta_f0(count)
        real_f0 = f0_from_ior(eta)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (fresnel_dielectric_average(eta) - real_f0) / (1.0 - real_f0)
        s = np.clip(np.nan_to_num(s, nan=0.0), 0.0, 1.0)[:, None]
        return f0 + (1.0 - f0) * s

    def weight(self, count: int) -> np.ndarray:
        return np.ones((count, 3))


@dataclass(frozen=True)
class PrincipledMetal:
    """The metallic lobe of the Principled BSDF: F82-tint Fresnel with F0 = base colour.

    base_colour : (3,) or (N, 3), clamped to [0, 1]; specular_tint : (3,) or (N, 3), the edge tint
    (clamped to <= 1).
    """

    base_colour: object = (0.8, 0.8, 0.8)
    specular_tint: object = (1.0, 1.0, 1.0)
    multiscatter: bool = True

    def f0_b(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        f0 = np.clip(_colours(self.base_colour, count), 0.0, 1.0)
        tint = np.minimum(np.maximum(_colours(self.specular_tint, count), 0.0), 1.0)
        return f0, np.where(tint == 1.0, 0.0, f82_tint_b(f0, tint))

    def reflectance(self, cos_hv: np.ndarray) -> np.ndarray:
        f0, b = self.f0_b(len(cos_hv))
        return fresnel_f82_tint(cos_hv, f0, b)

    def fresnel_terms(self, count: int) -> tuple[np.ndarray, None]:
        """``reflectance`` unclamped in the Fresnel basis: coefficients (N, 4, 3), and no η."""
        f0, b = self.f0_b(count)
        terms = np.zeros((count, FRESNEL_BASIS_SIZE, 3))
        terms[:, 0], terms[:, 2], terms[:, 3] = f0, 1.0 - f0, -b
        return terms, None

    def average_fresnel(self, count: int) -> np.ndarray:
        return f82_average(*self.f0_b(count))

    def weight(self, count: int) -> np.ndarray:
        return np.ones((count, 3))


GGXMaterial = GlossyMaterial | PrincipledSpecular | PrincipledMetal


def energy_factor(material: GGXMaterial, roughness, cos_view) -> np.ndarray:
    """Everything that multiplies the Fresnel-weighted single-scattering lobe, constant over ω_i, (N, 3).

    The closure weight (Glossy tint) times, for Multiscatter GGX, ``multiscatter_compensation``.
    """
    cos_view = np.asarray(cos_view, dtype=np.float64)
    count = len(cos_view)
    factor = material.weight(count)
    if material.multiscatter:
        factor = factor * multiscatter_compensation(_rows(roughness, count), cos_view,
                                                    material.average_fresnel(count))
    return factor


def ggx_brdf(wi, wo, normal, roughness, material: GGXMaterial = GlossyMaterial()) -> np.ndarray:
    """Cycles' GGX BRDF value f(ω_i, ω_o) for one closure, (N, 3) in 1/sr.

    f = weight · F(h · ω_o) · D G2 / (4 cos θ_i cos θ_o) · multiscatter factor.

    Parameters
    ----------
    wi, wo, normal : (N, 3) float64 unit vectors (towards the light, towards the camera, shading normal).
    roughness : (N,) or scalar, user roughness (α = roughness²).
    material : a ``GlossyMaterial``, ``PrincipledSpecular`` or ``PrincipledMetal``.
    """
    wo, normal = np.asarray(wo, dtype=np.float64), np.asarray(normal, dtype=np.float64)
    lobe, cos_hv = ggx_single_scatter(wi, wo, normal, roughness)
    factor = energy_factor(material, roughness, _dot(normal, wo))
    return lobe[:, None] * material.reflectance(cos_hv) * factor


# ------------------------------------------------------------------------------------------------------
# The Principled BSDF (base colour, metallic, roughness, IOR, specular level and tint)
# ------------------------------------------------------------------------------------------------------

def principled_diffuse_weight(roughness, cos_view, specular: PrincipledSpecular) -> np.ndarray:
    """Weight of the diffuse base under the dielectric specular layer, (N,) in [0, 1].

    Cycles' ``closure_layering_weight``: saturate(1 - max_rgb(albedo)), albedo = darkening · mix(f0, 1, s̄),
    with s̄ = ``gen_schlick_ior_s``(roughness, cos θ_o, sqrt((η - 1)/(η + 1))) and darkening the
    multiscatter colour term (1 + F_ms (1 - E)/E) / (1 + (1 - E)/E) (1 without Multiscatter GGX).
    1 where there is no specular layer (η = 1).
    """
    cos_view = np.asarray(cos_view, dtype=np.float64)
    count = len(cos_view)
    roughness = _rows(roughness, count)
    eta, f0 = specular.eta_f0(count)
    z = np.sqrt(np.abs((eta - 1.0) / (eta + 1.0)))
    s = lookup_table(albedo_tables()["gen_schlick_ior_s"], roughness, cos_view, z)[:, None]
    albedo = f0 + (1.0 - f0) * s
    if specular.multiscatter:
        energy = single_scatter_albedo(roughness, cos_view)[:, None]
        albedo = albedo * multiscatter_compensation(roughness, cos_view, specular.average_fresnel(count)) * energy
    weight = np.clip(1.0 - albedo.max(axis=1), 0.0, 1.0)
    return np.where(specular.exists(count), weight, 1.0)


def principled_bsdf(wi, wo, normal, roughness, base_colour, metallic=0.0, ior=1.5, specular_ior_level=0.5,
                    specular_tint=(1.0, 1.0, 1.0), multiscatter=True) -> np.ndarray:
    """Cycles' Principled BSDF (no transmission, coat, sheen, subsurface; Diffuse Roughness 0), (N, 3) 1/sr.

    f = metallic · f_metal + (1 - metallic) · (f_specular + w_diffuse · base_colour / π),
    with w_diffuse from ``principled_diffuse_weight``.
    """
    wi, wo, normal = (np.asarray(v, dtype=np.float64) for v in (wi, wo, normal))
    count = len(wi)
    metallic = np.clip(_rows(metallic, count), 0.0, 1.0)[:, None]
    base = np.maximum(_colours(base_colour, count), 0.0)
    metal = PrincipledMetal(base, specular_tint, multiscatter)
    specular = PrincipledSpecular(ior, specular_ior_level, specular_tint, multiscatter)
    cos_i, cos_o = _dot(normal, wi), _dot(normal, wo)
    diffuse = np.where(((cos_i > 0.0) & (cos_o > 0.0))[:, None], base / np.pi, 0.0)
    diffuse = diffuse * principled_diffuse_weight(roughness, cos_o, specular)[:, None]
    dielectric = ggx_brdf(wi, wo, normal, roughness, specular) + diffuse
    return metallic * ggx_brdf(wi, wo, normal, roughness, metal) + (1.0 - metallic) * dielectric


def compile_ggx() -> tuple:
    """Compile the table lookup (or load it from Numba's cache); returns it."""
    lookup_table(np.zeros((2, 2)), np.zeros(1), np.zeros(1))
    return (_lookup,)
