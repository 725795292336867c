"""Regenerate ``lazyvis_addon/core/data/ggx_albedo.npz``: GGX albedo tables on Cycles' grids.

    .venv/bin/python tools/make_ggx_tables.py            # ~3 minutes on 2 cores

Every entry is an integral over the incident direction ω_i of the single-scattering GGX lobe for one view
direction ω_o = (sqrt(1 - μ²), 0, μ) and one roughness r (α = r²). It is evaluated by deterministic
quadrature in the microfacet normal h rather than by Monte Carlo (which is how Cycles' own
``app/cycles_precompute.cpp`` makes its tables):

- h is parametrised by (u, φ) with u the GGX CDF of θ_h, tan²θ_h = α² u / (1 - u). The measure
  D(h) cos θ_h dω_h is then du dφ / (2π), so the peak of even a very narrow lobe is resolved.
- With ω_i = 2 (ω_o · h) h - ω_o, dω_i = 4 (ω_o · h) dω_h, and f cos θ_i = D G2 / (4 μ), so
  ∫ f cos θ_i g dω_i = ∫∫ G2 (ω_o · h) / (μ cos θ_h) g du dφ/(2π).
- ω_i is above the horizon exactly when cos φ > μ (1 - 2 cos²θ_h) / (2 cos θ_h sin θ_o sin θ_h); the φ
  integral is taken over that interval only (symmetric in φ), so the integrand has no discontinuity and
  Gauss–Legendre converges fast. Doubling both node counts changes no entry by more than 3e-6.

Tables (indexing as in Cycles' ``lookup_table_read_*``: the last axis is the first coordinate):

- ``E[j, i]`` (32 x 32): albedo of the white lobe, r = i / 31, μ = max(j / 31, 1e-4). Cycles: ``table_ggx_E``.
- ``E_avg[i]`` (32): 2 ∫ E(μ) μ dμ. Cycles: ``table_ggx_Eavg``.
- ``gen_schlick_ior_s[k, j, i]`` (16 x 16 x 16): Cycles' ``table_ggx_gen_schlick_ior_s``, the mean over
  visible normals h (VNDF) of s(ω_o · h) = saturate((F(ω_o · h, η) - F0(η)) / (1 - F0(η))), counting
  0 for reflections below the horizon, with r = max(i / 15, 1e-4), μ = max(j / 15, 1e-4),
  z = clamp(k / 15, 1e-4, 0.99), η = ior_from_F0(z⁴).
- ``ltc_norm``, ``ltc_schlick``, ``ltc_f82`` (64 x 64) and ``ltc_dielectric`` (16 x 32 x 32): hemispherical
  magnitudes for the LTC integrals on the LTC grid r = i / 63, sqrt(1 - μ) = j / 63 (``table_ltc_magnitudes``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lazyvis_addon.core.ggx import (ALBEDO_TABLE_PATH, fresnel_dielectric, f0_from_ior,  # noqa: E402
                                    ggx_g1, ggx_g2, ior_from_f0)

NODES_U = 512
NODES_PHI = 64
NODES_MU = 96


def half_vector_quadrature(roughness: np.ndarray, cos_view: np.ndarray, integrand, nodes_u: int = NODES_U,
                           nodes_phi: int = NODES_PHI) -> np.ndarray:
    """∫ over microfacet normals h (with ω_i above the horizon) of integrand · D cos θ_h dω_h, per cell.

    Parameters
    ----------
    roughness, cos_view : (C,) float64, r and μ = cos θ_o of each cell.
    integrand : callable(cos_vh, cos_i, cos_h, alpha, mu) -> values, all arrays broadcast to (C, U, P).

    Returns (C,) float64.
    """
    alpha = np.maximum(roughness, 1e-4) ** 2
    mu = np.clip(cos_view, 1e-6, 1.0)
    x_u, w_u = np.polynomial.legendre.leggauss(nodes_u)
    x_p, w_p = np.polynomial.legendre.leggauss(nodes_phi)
    # u = sin²(πt/2): tan θ_h = α tan(πt/2), which removes the sqrt(u) and sqrt(1 - u) end-point
    # singularities of the integrand (grazing views) so that Gauss-Legendre in t converges fast.
    t = 0.5 * (x_u + 1.0)
    w_u = 0.5 * w_u * 0.5 * np.pi * np.sin(np.pi * t)
    theta_h = np.arctan2(alpha[:, None] * np.sin(0.5 * np.pi * t)[None, :], np.cos(0.5 * np.pi * t)[None, :])
    cos_h, sin_h = np.cos(theta_h), np.sin(theta_h)                             # (C, U)
    cos_h2 = cos_h ** 2
    sin_o = np.sqrt(np.maximum(1.0 - mu ** 2, 0.0))[:, None]
    denominator = 2.0 * cos_h * sin_o * sin_h
    with np.errstate(divide="ignore", invalid="ignore"):
        threshold = mu[:, None] * (1.0 - 2.0 * cos_h2) / denominator
    threshold = np.where(denominator > 0.0, threshold, np.where(1.0 - 2.0 * cos_h2 < 0.0, -np.inf, np.inf))
    phi_max = np.arccos(np.clip(threshold, -1.0, 1.0))                          # (C, U)
    phi = phi_max[:, :, None] * (0.5 * (x_p + 1.0))[None, None, :]              # (C, U, P)
    weight = (w_u[None, :, None] * (0.5 * w_p)[None, None, :] * phi_max[:, :, None]) / np.pi
    cos_vh = sin_o[:, :, None] * sin_h[:, :, None] * np.cos(phi) + mu[:, None, None] * cos_h[:, :, None]
    cos_i = 2.0 * cos_vh * cos_h[:, :, None] - mu[:, None, None]
    values = integrand(cos_vh, np.maximum(cos_i, 0.0), cos_h[:, :, None], alpha[:, None, None], mu[:, None, None])
    if values.ndim == 4:  # several integrands at once: (Q, C, U, P) -> (Q, C)
        return np.einsum("cup,qcup->qc", weight, values)
    return np.einsum("cup,cup->c", weight, values)


def lobe_weight(cos_vh, cos_i, cos_h, alpha, mu):
    """f cos θ_i dω_i per unit of D cos θ_h dω_h: G2 (ω_o · h) / (μ cos θ_h)."""
    return ggx_g2(cos_i, mu, alpha) * cos_vh / (mu * cos_h)


def visible_normal_weight(cos_vh, cos_i, cos_h, alpha, mu):
    """VNDF density per unit of D cos θ_h dω_h: G1(ω_o) (ω_o · h) / (μ cos θ_h)."""
    return ggx_g1(mu, alpha) * cos_vh / (mu * cos_h)


def in_chunks(function, *arrays, chunk: int = 32) -> np.ndarray:
    """Apply ``function`` to row chunks of equally long (C,) arrays (bounds memory at ~C·U·P doubles).

    ``function`` returns (c,) or (Q, c) per chunk; the chunks are joined along the last axis.
    """
    return np.concatenate([function(*(a[s:s + chunk] for a in arrays)) for s in range(0, len(arrays[0]), chunk)],
                          axis=-1)


def table_single_scatter_albedo() -> np.ndarray:
    roughness_nodes = np.clip(np.arange(32) / 31.0, 1e-4, 1.0)
    mu_nodes = np.clip(np.arange(32) / 31.0, 1e-4, 1.0)
    mu, rough = np.meshgrid(mu_nodes, roughness_nodes, indexing="ij")
    albedo = in_chunks(lambda r, m: half_vector_quadrature(r, m, lobe_weight), rough.ravel(), mu.ravel())
    return albedo.reshape(32, 32)


def table_single_scatter_albedo_average() -> np.ndarray:
    roughness_nodes = np.clip(np.arange(32) / 31.0, 1e-4, 1.0)
    x, w = np.polynomial.legendre.leggauss(NODES_MU)
    mu_nodes, mu_weights = 0.5 * (x + 1.0), 0.5 * w
    mu, rough = np.meshgrid(mu_nodes, roughness_nodes, indexing="ij")
    albedo = in_chunks(lambda r, m: half_vector_quadrature(r, m, lobe_weight), rough.ravel(), mu.ravel())
    return np.einsum("j,ji->i", 2.0 * mu_nodes * mu_weights, albedo.reshape(NODES_MU, 32))


def table_gen_schlick_ior_s() -> np.ndarray:
    roughness_nodes = np.clip(np.arange(16) / 15.0, 1e-4, 1.0)
    mu_nodes = np.clip(np.arange(16) / 15.0, 1e-4, 1.0)
    z_nodes = np.clip(np.arange(16) / 15.0, 1e-4, 0.99)
    z, mu, rough = np.meshgrid(z_nodes, mu_nodes, roughness_nodes, indexing="ij")
    eta = ior_from_f0(z ** 4)

    def blend_mean(r, m, e):
        real_f0 = f0_from_ior(e)[:, None, None]

        def integrand(cos_vh, cos_i, cos_h, alpha, mu_):
            s = np.clip((fresnel_dielectric(cos_vh, e[:, None, None]) - real_f0) / (1.0 - real_f0), 0.0, 1.0)
            return visible_normal_weight(cos_vh, cos_i, cos_h, alpha, mu_) * s

        return half_vector_quadrature(r, m, integrand)

    return in_chunks(blend_mean, rough.ravel(), mu.ravel(), eta.ravel()).reshape(16, 16, 16)


def ltc_grid(roughness_nodes: int, view_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Cells of the LTC grid: r = i / (n_r - 1), sqrt(1 - μ) = j / (n_v - 1); (n_v, n_r) arrays (μ >= 1e-4)."""
    v, rough = np.meshgrid(np.arange(view_nodes) / (view_nodes - 1.0),
                           np.arange(roughness_nodes) / (roughness_nodes - 1.0), indexing="ij")
    return np.clip(rough, 1e-4, 1.0), np.clip(1.0 - v ** 2, 1e-4, 1.0)


def table_ltc_magnitudes() -> dict[str, np.ndarray]:
    """Hemispherical magnitudes of the lobe on the 64 x 64 LTC grid (see ``core/ltc.py``).

    norm = ∫ f cos θ_i dω_i; schlick = ∫ f cos θ_i (1 - c)^5 / norm; f82 = ∫ f cos θ_i c (1 - c)^6 / norm
    with c = ω_o · h (the Schlick and F82-tint shapes); dielectric[k] = ∫ f cos θ_i s(c, η_k) / norm on a
    (16, 32, 32) grid, z = clamp(k / 15, 1e-4, 0.99), η_k = ior_from_F0(z⁴) as ``gen_schlick_ior_s``.
    """
    rough, mu = ltc_grid(64, 64)

    def moments(r, m):
        def integrand(cos_vh, cos_i, cos_h, alpha, mu_):
            lobe = lobe_weight(cos_vh, cos_i, cos_h, alpha, mu_)
            grazing = 1.0 - cos_vh
            return np.stack([lobe, lobe * grazing ** 5, lobe * cos_vh * grazing ** 6])
        return half_vector_quadrature(r, m, integrand)

    norm, schlick, f82 = in_chunks(moments, rough.ravel(), mu.ravel()).reshape(3, 64, 64)
    rough3, mu3 = ltc_grid(32, 32)
    z_nodes = np.clip(np.arange(16) / 15.0, 1e-4, 0.99)
    eta = np.repeat(ior_from_f0(z_nodes ** 4), 32 * 32)
    rough3, mu3 = np.tile(rough3.ravel(), 16), np.tile(mu3.ravel(), 16)

    def dielectric_moments(r, m, e):
        real_f0 = f0_from_ior(e)[:, None, None]

        def integrand(cos_vh, cos_i, cos_h, alpha, mu_):
            lobe = lobe_weight(cos_vh, cos_i, cos_h, alpha, mu_)
            s = np.clip((fresnel_dielectric(cos_vh, e[:, None, None]) - real_f0) / (1.0 - real_f0), 0.0, 1.0)
            return np.stack([lobe, lobe * s])
        return half_vector_quadrature(r, m, integrand)

    lobe, blended = in_chunks(dielectric_moments, rough3, mu3, eta)
    return {"ltc_norm": norm, "ltc_schlick": schlick / norm, "ltc_f82": f82 / norm,
            "ltc_dielectric": (blended / lobe).reshape(16, 32, 32)}


def main() -> None:
    start = time.perf_counter()
    tables = {
        "E": table_single_scatter_albedo(),
        "E_avg": table_single_scatter_albedo_average(),
        "gen_schlick_ior_s": table_gen_schlick_ior_s(),
        **table_ltc_magnitudes(),
    }
    ALBEDO_TABLE_PATH.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(ALBEDO_TABLE_PATH, **{k: v.astype(np.float64) for k, v in tables.items()})
    print(f"wrote {ALBEDO_TABLE_PATH} in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
