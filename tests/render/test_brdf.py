"""Each BRDF term against the independent numpy reference."""
import numpy as np
import pytest
import torch

from bayes_brdf.render import brdf

from . import numpy_reference as ref

rng = np.random.default_rng(0)
N = 1000
COS = {k: rng.uniform(1e-3, 1, N) for k in ("nl", "nv", "nh", "vh")}
R = rng.uniform(0.05, 1, N)
KS = rng.uniform(0, 1, N)
KD = rng.uniform(0, 1, N)
T = lambda a: torch.tensor(a, dtype=torch.float64)  # noqa: E731


def test_ggx_d_matches_reference_and_normalises():
    np.testing.assert_allclose(brdf.ggx_d(T(COS["nh"]), T(R**2)).numpy(), ref.D(COS["nh"], R**2), rtol=1e-12)
    # D is a normal distribution: the integral of D(h) (n.h) over the hemisphere is 1
    mu = np.linspace(0, 1, 200001)
    for alpha in (0.05, 0.3, 1.0):
        integral = 2 * np.pi * np.trapezoid(brdf.ggx_d(T(mu), T(alpha)).numpy() * mu, mu)
        assert integral == pytest.approx(1.0, rel=2e-3)


def test_smith_g_matches_reference_and_limits():
    got = brdf.smith_g(T(COS["nl"]), T(COS["nv"]), T(R**2)).numpy()
    np.testing.assert_allclose(got, ref.G(COS["nl"], COS["nv"], R**2), rtol=1e-12)
    assert np.all((got > 0) & (got <= 1))
    assert float(brdf.smith_g(T(1.0), T(1.0), T(0.5))) == pytest.approx(1.0)


def test_fresnel_matches_reference_and_limits():
    np.testing.assert_allclose(brdf.fresnel(T(COS["vh"]), T(KS)).numpy(), ref.F(COS["vh"], KS), rtol=1e-12)
    assert float(brdf.fresnel(T(0.0), T(0.04))) == pytest.approx(1.0)  # grazing: total reflection


@pytest.mark.parametrize("ks_factor", [True, False])
def test_diffuse_and_full_brdf_match_reference(ks_factor):
    want = KD * (1 - KS) / np.pi if ks_factor else KD / np.pi
    np.testing.assert_allclose(brdf.diffuse(T(KD), T(KS), ks_factor).numpy(), want, rtol=1e-12)
    got = brdf.microfacet(T(KD), T(R), T(KS), *(T(COS[k]) for k in ("nl", "nv", "nh", "vh")), ks_factor).numpy()
    spec = ref.D(COS["nh"], R**2) * ref.F(COS["vh"], KS) * ref.G(COS["nl"], COS["nv"], R**2) / (4 * COS["nl"] * COS["nv"])
    np.testing.assert_allclose(got, want + spec, rtol=1e-12)
