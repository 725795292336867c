"""Cycles' GGX (lazyvis_addon.core.ggx): normalisation, Smith G2, albedo tables, multiscatter, Fresnel.

Monte Carlo checks use fixed seeds and accept 4 standard errors (a false failure has probability ~6e-5
per check) plus the stated systematic allowance.
"""

import numpy as np
import pytest

from lazyvis_addon.core import ggx

UP = np.array([0.0, 0.0, 1.0])


def view_at(cos_view):
    return np.array([np.sqrt(1.0 - cos_view ** 2), 0.0, cos_view])


def leggauss01(count):
    x, w = np.polynomial.legendre.leggauss(count)
    return 0.5 * (x + 1.0), 0.5 * w


def sample_ggx_normals(rng, alpha, count):
    """Microfacet normals h with density D(h) cos θ_h (the GGX CDF inverted), (count, 3)."""
    u = rng.random((count, 2))
    tan_theta = alpha * np.sqrt(u[:, 0] / (1.0 - u[:, 0]))
    cos_theta = 1.0 / np.sqrt(1.0 + tan_theta ** 2)
    sin_theta = tan_theta * cos_theta
    phi = 2.0 * np.pi * u[:, 1]
    return np.stack([sin_theta * np.cos(phi), sin_theta * np.sin(phi), cos_theta], axis=1)


def furnace(rng, roughness, cos_view, material, count=200_000):
    """Monte Carlo ∫ ggx_brdf cos θ_i dω_i over the hemisphere: mean and standard error, (3,) each.

    Directions come from reflecting the view about normals sampled ∝ D cos θ_h, whose solid-angle density is
    D cos θ_h / (4 ω_o·h); only ggx_brdf is evaluated.
    """
    alpha = roughness ** 2
    wo = view_at(cos_view)
    h = sample_ggx_normals(rng, alpha, count)
    cos_vh = h @ wo
    wi = 2.0 * cos_vh[:, None] * h - wo
    pdf = ggx.ggx_distribution(h[:, 2], alpha) * h[:, 2] / (4.0 * np.abs(cos_vh))
    f = ggx.ggx_brdf(wi, np.tile(wo, (count, 1)), np.tile(UP, (count, 1)), roughness, material)
    samples = np.where((cos_vh > 0)[:, None], f * np.maximum(wi[:, 2], 0.0)[:, None] / pdf[:, None], 0.0)
    return samples.mean(axis=0), samples.std(axis=0) / np.sqrt(count)


# -- the microfacet distribution and shadowing ---------------------------------------------------------

@pytest.mark.parametrize("alpha", [0.001, 0.01, 0.1, 0.5, 1.0])
def test_distribution_is_normalised(alpha):
    # ∫ D cos θ_h dω_h = 2π ∫ D cos θ sin θ dθ, with θ = atan(α tan(πt/2)) to follow the peak.
    t, w = leggauss01(600)
    theta = np.arctan(alpha * np.tan(0.5 * np.pi * t))
    dtheta = alpha * 0.5 * np.pi / np.cos(0.5 * np.pi * t) ** 2 / (1.0 + (alpha * np.tan(0.5 * np.pi * t)) ** 2)
    integral = 2.0 * np.pi * np.sum(w * ggx.ggx_distribution(np.cos(theta), alpha) * np.cos(theta) * np.sin(theta)
                                    * dtheta)
    assert integral == pytest.approx(1.0, abs=1e-9)


def numerical_lambda(cos_n, alpha, nodes=800):
    """Smith Λ from its definition 1 + Λ(ω) = ∫ max(0, ω·h) D(h) dω_h / cos θ (projected microfacet area)."""
    t, wt = leggauss01(nodes)
    theta = 0.5 * np.pi * t
    phi, wp = leggauss01(nodes // 2)
    phi = np.pi * phi                                               # symmetric in φ: [0, π], doubled
    sin_n = np.sqrt(1.0 - cos_n ** 2)
    h_dot_w = np.sin(theta)[:, None] * np.cos(phi)[None, :] * sin_n + np.cos(theta)[:, None] * cos_n
    integrand = np.maximum(h_dot_w, 0.0) * ggx.ggx_distribution(np.cos(theta), alpha)[:, None] * np.sin(theta)[:, None]
    projected = 2.0 * np.pi * 0.5 * np.pi * np.einsum("i,j,ij->", wt, wp, integrand)
    return projected / cos_n - 1.0


@pytest.mark.parametrize("alpha", [0.3, 0.6, 1.0])
def test_height_correlated_g2_matches_the_projected_area_definition(alpha):
    for cos_i, cos_o in [(0.9, 0.8), (0.5, 0.95), (0.2, 0.6), (0.35, 0.35)]:
        expected = 1.0 / (1.0 + numerical_lambda(cos_i, alpha) + numerical_lambda(cos_o, alpha))
        assert ggx.ggx_g2(cos_i, cos_o, alpha) == pytest.approx(expected, rel=2e-5)


def test_g2_is_not_the_separable_product():
    # radiometry.md: the separable G1·G1 form is measurably off at roughness 0.6. It is lower than the
    # height-correlated G2 by 0.25% at a 60° light and 45° view, and by 4.4% with both at 72.5°.
    alpha = 0.36
    ratio = [ggx.ggx_g2(ci, co, alpha) / (ggx.ggx_g1(ci, alpha) * ggx.ggx_g1(co, alpha))
             for ci, co in [(0.5, np.cos(np.pi / 4)), (0.3, 0.3)]]
    assert ratio[0] == pytest.approx(1.0025, abs=1e-4)
    assert ratio[1] == pytest.approx(1.0445, abs=1e-4)


def test_brdf_is_reciprocal_without_fresnel_and_zero_below_the_horizon():
    rng = np.random.default_rng(1)
    wi = rng.normal(size=(1000, 3))
    wo = rng.normal(size=(1000, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    normal = np.tile(UP, (1000, 1))
    f = ggx.ggx_brdf(wi, wo, normal, 0.4, ggx.GlossyMaterial(multiscatter=False))
    assert np.allclose(f, ggx.ggx_brdf(wo, wi, normal, 0.4, ggx.GlossyMaterial(multiscatter=False)))
    assert np.all(f[(wi[:, 2] <= 0) | (wo[:, 2] <= 0)] == 0)
    assert np.all(ggx.ggx_brdf(wi, wo, normal, 0.0) == 0)          # a mirror has no density (Cycles)


# -- albedo tables ----------------------------------------------------------------------------------

def test_tables_reproduce_cycles_shader_tables():
    # Values of Cycles' Monte Carlo tables (intern/cycles/scene/shader.tables: table_ggx_E, table_ggx_Eavg)
    # at a few nodes; ours come from quadrature. E(1, 1) = 1 - ln 2 in closed form.
    tables = ggx.albedo_tables()
    assert tables["E"][31, 31] == pytest.approx(1.0 - np.log(2.0), abs=5e-6)
    assert tables["E"][31, 31] == pytest.approx(0.306853, abs=2e-5)
    assert tables["E"][1, 31] == pytest.approx(0.888202, abs=2e-5)      # μ = 1/31, r = 1
    assert tables["E"][15, 10] == pytest.approx(0.964995, abs=2e-5)     # μ = 15/31, r = 10/31
    assert tables["E"][0, 1] == pytest.approx(0.980405, abs=2e-5)       # μ = 1e-4, r = 1/31
    assert tables["E_avg"][31] == pytest.approx(0.409137, abs=2e-5)
    assert tables["E_avg"][15] == pytest.approx(0.893209, abs=2e-5)


@pytest.mark.parametrize("roughness,cos_view", [(10 / 31, 1.0), (0.5 - 0.5 / 31, 20 / 31), (1.0, 8 / 31),
                                                (25 / 31, 30 / 31)])
def test_white_furnace_single_scatter_matches_the_table(roughness, cos_view):
    rng = np.random.default_rng(11)
    mean, error = furnace(rng, roughness, cos_view, ggx.GlossyMaterial(multiscatter=False))
    table = ggx.single_scatter_albedo(np.array([roughness]), np.array([cos_view]))[0]
    assert abs(mean[0] - table) < 4 * error[0] + 2e-5


@pytest.mark.parametrize("roughness,cos_view", [(0.2, 0.9), (0.45, 0.6), (0.7, 0.33), (1.0, 0.8), (0.6, 0.15)])
def test_multiscatter_white_glossy_conserves_energy(roughness, cos_view):
    # Cycles' compensation divides by the tabulated E: the white lobe's albedo becomes 1, up to the
    # bilinear interpolation of E between nodes (these views and roughnesses are off the nodes).
    rng = np.random.default_rng(12)
    mean, error = furnace(rng, roughness, cos_view, ggx.GlossyMaterial())
    assert abs(mean[0] - 1.0) < 4 * error[0] + 3e-3


def test_multiscatter_matches_the_measured_cycles_boost():
    # radiometry.md, measured on Cycles 5.0.1: Multiscatter GGX adds +1.2% at roughness 0.3 and +19.6% at
    # 0.6 for a 45° view (the Glossy BSDF's default colour 0.8).
    cos_view = np.array([np.cos(np.pi / 4)])
    boosts = [ggx.multiscatter_compensation(np.array([r]), cos_view, np.full((1, 3), 0.8))[0, 0] - 1.0
              for r in (0.3, 0.6)]
    assert boosts[0] == pytest.approx(0.012, abs=0.0006)
    assert boosts[1] == pytest.approx(0.196, abs=0.0006)


def test_coloured_multiscatter_darkens_as_kulla_conty():
    # F_ss < 1: the multiscattered energy is F_ms (1 - E)/E with F_ms = F_ss E_avg / (1 - F_ss (1 - E_avg)).
    r, mu = np.array([0.7]), np.array([0.5])
    e, e_avg = ggx.single_scatter_albedo(r, mu)[0], ggx.single_scatter_albedo_average(r)[0]
    fss = np.array([[0.9, 0.5, 0.1]])
    fms = fss * e_avg / (1 - fss * (1 - e_avg))
    assert np.allclose(ggx.multiscatter_compensation(r, mu, fss), 1 + fms * (1 - e) / e)
    assert np.allclose(ggx.multiscatter_compensation(r, mu, np.ones((1, 3))), 1 / e)


def test_lookup_is_exact_at_nodes_and_linear_between():
    table = ggx.albedo_tables()["E"]
    assert ggx.single_scatter_albedo(np.array([7 / 31]), np.array([20 / 31]))[0] == pytest.approx(table[20, 7])
    halfway = ggx.single_scatter_albedo(np.array([7.5 / 31]), np.array([20 / 31]))[0]
    assert halfway == pytest.approx(0.5 * (table[20, 7] + table[20, 8]))


def test_principled_diffuse_weight_uses_cycles_blend_estimate():
    # Cycles' layering estimate: s̄ = mean over visible normals of the real-Fresnel blend, 0 for
    # reflections below the horizon. Independent estimate by sampling visible normals (Heitz 2018).
    rng = np.random.default_rng(5)
    roughness, cos_view, ior = 0.45, 0.3, 1.5
    alpha, wo, count = roughness ** 2, view_at(cos_view), 400_000
    stretched = np.array([alpha * wo[0], alpha * wo[1], wo[2]])
    stretched /= np.linalg.norm(stretched)
    u = rng.random((count, 2))
    t1 = np.cross([0, 0, 1.0], stretched)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(stretched, t1)
    radius, phi = np.sqrt(u[:, 0]), 2 * np.pi * u[:, 1]
    p1, p2 = radius * np.cos(phi), radius * np.sin(phi)
    s = 0.5 * (1 + stretched[2])
    p2 = (1 - s) * np.sqrt(1 - p1 ** 2) + s * p2
    normal_h = p1[:, None] * t1 + p2[:, None] * t2 + np.sqrt(np.maximum(0, 1 - p1 ** 2 - p2 ** 2))[:, None] * stretched
    h = np.stack([alpha * normal_h[:, 0], alpha * normal_h[:, 1], np.maximum(normal_h[:, 2], 0)], axis=1)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    cos_vh = h @ wo
    wi_z = 2 * cos_vh * h[:, 2] - wo[2]
    f0 = ggx.f0_from_ior(ior)
    blend = np.clip((ggx.fresnel_dielectric(cos_vh, ior) - f0) / (1 - f0), 0, 1) * (wi_z > 0)
    expected_weight = 1 - (f0 + (1 - f0) * blend.mean())
    weight = ggx.principled_diffuse_weight(roughness, np.array([cos_view]),
                                           ggx.PrincipledSpecular(ior=ior, multiscatter=False))[0]
    assert weight == pytest.approx(expected_weight, abs=4 * blend.std() / np.sqrt(count) + 1e-3)


# -- Fresnel -----------------------------------------------------------------------------------------

def fresnel_from_snell(cos_i, eta):
    """Unpolarised reflectance from the amplitude equations and Snell's law (textbook form)."""
    sin_t = np.sqrt(1 - cos_i ** 2) / eta
    if sin_t >= 1:
        return 1.0
    cos_t = np.sqrt(1 - sin_t ** 2)
    r_s = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    r_p = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (r_s ** 2 + r_p ** 2)


def test_dielectric_fresnel_known_values():
    assert ggx.fresnel_dielectric(1.0, 1.5) == pytest.approx(0.04, abs=1e-12)
    assert ggx.fresnel_dielectric(1.0, 1.33) == pytest.approx((0.33 / 2.33) ** 2, abs=1e-12)
    assert ggx.fresnel_dielectric(0.0, 1.5) == pytest.approx(1.0)
    brewster = np.cos(np.arctan(1.5))           # p-polarised reflection vanishes: F = R_s / 2
    r_s = ((np.cos(np.arctan(1.5)) - 1.5 * np.sin(np.arctan(1.5))) /
           (np.cos(np.arctan(1.5)) + 1.5 * np.sin(np.arctan(1.5)))) ** 2
    assert ggx.fresnel_dielectric(brewster, 1.5) == pytest.approx(r_s / 2, rel=1e-10)
    for eta in (1.1, 1.5, 2.4, 1 / 1.5):
        for cos_i in (0.05, 0.3, 0.7, 0.95):
            assert ggx.fresnel_dielectric(cos_i, eta) == pytest.approx(fresnel_from_snell(cos_i, eta), rel=1e-10)
    assert ggx.fresnel_dielectric(0.5, 1 / 1.5) == 1.0       # beyond the critical angle


def test_fresnel_averages():
    mu, w = leggauss01(400)
    # Cycles' fresnel_dielectric_Fss is Kulla & Conty's rational fit, used as is: within 0.007 of the exact
    # average (-0.0065 at η = 1.2, -0.0023 at 1.5, +0.006 at 3).
    for eta in (1.2, 1.5, 2.0, 3.0, 0.8, 0.67):
        exact = np.sum(w * 2 * mu * ggx.fresnel_dielectric(mu, eta))
        assert ggx.fresnel_dielectric_average(eta) == pytest.approx(exact, abs=7e-3)
    assert ggx.fresnel_dielectric_average(1.5) == pytest.approx(0.5 / (4.08567 + 1.00071 * 1.5))
    f0, b = np.array([[0.9, 0.6, 0.2]]), ggx.f82_tint_b(np.array([[0.9, 0.6, 0.2]]), np.array([[1.0, 0.8, 0.5]]))
    mu_col = mu[:, None]
    unclamped = f0 + (1 - f0) * (1 - mu_col) ** 5 - b * mu_col * (1 - mu_col) ** 6
    assert np.allclose(ggx.f82_average(f0, b), np.sum(w[:, None] * 2 * mu_col * unclamped, axis=0), atol=1e-12)


def test_f82_tint_hits_its_defining_values():
    f0, tint = np.array([[0.95, 0.64, 0.54]]), np.array([[1.0, 0.7, 0.3]])
    b = ggx.f82_tint_b(f0, tint)
    assert np.allclose(ggx.fresnel_f82_tint(np.array([1.0]), f0, b), f0)
    assert np.allclose(ggx.fresnel_f82_tint(np.array([0.0]), f0, b), 1.0)
    schlick = f0 + (1 - f0) * (6 / 7) ** 5
    assert np.allclose(ggx.fresnel_f82_tint(np.array([1 / 7]), f0, b), np.minimum(tint * schlick, 1))
    assert np.allclose(ggx.f82_tint_b(f0, np.ones((1, 3))), 0.0)      # white tint: plain Schlick


def test_principled_specular_fresnel_and_ior_level():
    spec = ggx.PrincipledSpecular(ior=1.5)
    cos = np.array([1.0, 0.5, 0.0])
    assert np.allclose(spec.reflectance(cos)[:, 0], ggx.fresnel_dielectric(cos, 1.5))   # level 0.5: real Fresnel
    doubled = ggx.PrincipledSpecular(ior=1.5, specular_ior_level=1.0)
    assert doubled.reflectance(np.array([1.0]))[0, 0] == pytest.approx(0.08)
    assert doubled.reflectance(np.array([0.0]))[0, 0] == pytest.approx(1.0)
    tinted = ggx.PrincipledSpecular(ior=1.5, specular_tint=(1.0, 0.5, 0.0))
    assert np.allclose(tinted.reflectance(np.array([1.0]))[0], [0.04, 0.02, 0.0])
    for none in (ggx.PrincipledSpecular(ior=1.0), ggx.PrincipledSpecular(ior=1.5, specular_ior_level=0.0)):
        assert not none.exists(1)[0]
        assert np.all(none.reflectance(cos) == 0)


def test_principled_is_lambert_without_specular():
    # radiometry.md: Principled is exactly base_color / π with Specular IOR Level 0 (or IOR 1).
    rng = np.random.default_rng(2)
    wi, wo = rng.normal(size=(500, 3)), rng.normal(size=(500, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    base = np.array([0.8, 0.5, 0.2])
    for kwargs in ({"specular_ior_level": 0.0}, {"ior": 1.0}):
        f = ggx.principled_bsdf(wi, wo, np.tile(UP, (500, 1)), 0.5, base, **kwargs)
        assert np.allclose(f, base / np.pi, rtol=0, atol=1e-15)


def test_principled_default_darkens_diffuse_by_a_few_percent():
    # radiometry.md: the default specular layer takes 1.5-3% off the diffuse part (and the weight only
    # depends on the view).
    weight = ggx.principled_diffuse_weight(0.5, np.array([1.0, np.cos(np.pi / 4)]), ggx.PrincipledSpecular())
    assert np.all((weight > 0.95) & (weight < 0.99))


def test_metal_is_the_f82_closure():
    """Principled metallic 1 against a microfacet BRDF written out here from the formulas (not through
    ``ggx``): D GGX, Smith's height-correlated G2 with Λ, and Hoffman's F82-tint Fresnel, whose b makes
    F(1/7) = tint · Schlick(1/7); a coloured edge tint, so the F82 term is not 0. Then Multiscatter GGX
    only scales the lobe by a factor of the view alone, above 1, towards 1 for a smooth metal."""
    rng = np.random.default_rng(4)
    wi, wo = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    base, tint, roughness = np.array([0.9, 0.6, 0.3]), np.array([0.7, 0.85, 1.0]), 0.35
    normal = np.tile(UP, (200, 1))
    metal = ggx.principled_bsdf(wi, wo, normal, roughness, base, metallic=1.0, specular_tint=tint,
                                multiscatter=False)

    alpha = roughness ** 2
    half = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    cos_h, cos_i, cos_o = half[:, 2], wi[:, 2], wo[:, 2]
    d = alpha ** 2 / (np.pi * (cos_h ** 2 * (alpha ** 2 - 1.0) + 1.0) ** 2)

    def smith_lambda(cos):
        return 0.5 * (np.sqrt(1.0 + alpha ** 2 * (1.0 - cos ** 2) / cos ** 2) - 1.0)

    g2 = 1.0 / (1.0 + smith_lambda(cos_i) + smith_lambda(cos_o))
    mu = np.sum(half * wo, axis=1)[:, None]

    def schlick(m):
        return base + (1.0 - base) * (1.0 - m) ** 5

    m82 = 1.0 / 7.0
    b = (schlick(m82) - tint * schlick(m82)) / (m82 * (1.0 - m82) ** 6)
    fresnel = np.clip(schlick(mu) - b * mu * (1.0 - mu) ** 6, 0.0, 1.0)
    expected = fresnel * (d * g2 / (4.0 * cos_i * cos_o))[:, None]
    np.testing.assert_allclose(metal, expected, rtol=1e-9, atol=1e-12)
    assert np.abs(fresnel - schlick(mu)).max() > 0.01  # the tint's term is there

    # Multiscatter: one factor per view direction (the same wo with other wi), > 1, ~1 when smooth.
    wo_one = np.tile(wo[:1], (200, 1))
    for r, low, high in ((0.35, 1.0, 1.5), (0.05, 1.0, 1.001)):
        ms = ggx.principled_bsdf(wi, wo_one, normal, r, base, metallic=1.0, specular_tint=tint)
        ss = ggx.principled_bsdf(wi, wo_one, normal, r, base, metallic=1.0, specular_tint=tint, multiscatter=False)
        lit = ss[:, 0] > 1e-12
        ratio = ms[lit] / ss[lit]
        assert np.ptp(ratio, axis=0).max() < 1e-9 and low < ratio.min() and ratio.max() < high, (r, ratio[0])

@pytest.mark.parametrize("closure", [
    ggx.GlossyMaterial(colour=(0.9, 0.5, 0.2)),
    ggx.PrincipledSpecular(ior=1.5, specular_ior_level=0.5, specular_tint=(1.0, 0.8, 0.6)),
    ggx.PrincipledSpecular(ior=1.33, specular_ior_level=0.8),   # F0 adjusted: another η
    ggx.PrincipledSpecular(ior=0.7, specular_ior_level=0.5),    # η < 1: total internal reflection at grazing
    ggx.PrincipledSpecular(ior=1.0, specular_ior_level=0.5),    # no specular closure
    ggx.PrincipledMetal(base_colour=(1.0, 0.77, 0.34), specular_tint=(0.9, 0.6, 1.0)),
], ids=["glossy", "dielectric", "dielectric_level", "dielectric_below_1", "ior_1", "metal"])
def test_fresnel_terms_reproduce_every_closures_reflectance(closure):
    """The Fresnel basis the glossy correction integrates point by point (coefficients from ``fresnel_terms``,
    functions from ``fresnel_basis``) gives each closure's own ``reflectance`` at every c = ω_o·h, and the
    compiled blend the kernel calls is the numpy one."""
    cos_hv = np.linspace(0.0, 1.0, 201)
    terms, eta = closure.fresnel_terms(len(cos_hv))
    basis = ggx.fresnel_basis(cos_hv, np.full(len(cos_hv), 1.5) if eta is None else eta)
    np.testing.assert_allclose(np.einsum("nk,nkc->nc", basis, terms), closure.reflectance(cos_hv), atol=1e-12)
    if eta is not None:
        compiled = np.array([ggx.dielectric_blend(c, e) for c, e in zip(cos_hv, eta)])
        np.testing.assert_allclose(compiled, ggx.PrincipledSpecular.blend(cos_hv, eta), atol=1e-12)
        assert np.ptp(compiled) > 0.5 or eta[0] == 1.0  # the blend runs from 0 (normal) to 1 (grazing)
