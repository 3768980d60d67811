"""Priors: exact normalisation, closed-form values, and one-line errors for bad preset tables."""
import math

import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.models import priors as P
from bayes_brdf.models.material import from_preset


def test_truncated_gaussian_is_normalised_and_sampled_right():
    d = P.TruncatedNormal(torch.tensor(0.1, dtype=torch.float64), torch.tensor(0.05, dtype=torch.float64), 0.05, 1.0)
    x = torch.linspace(0.05, 1.0, 200001, dtype=torch.float64)
    dens = d.log_prob(x).exp()
    integral = float(((dens[1:] + dens[:-1]) / 2 * (x[1] - x[0])).sum())
    assert integral == pytest.approx(1.0, abs=1e-6)
    mean_q = float(((x * dens)[1:] + (x * dens)[:-1]).sum() / 2 * (x[1] - x[0]))
    torch.manual_seed(0)
    s = d.sample((200000,))
    assert s.min() >= 0.05 and s.max() <= 1.0
    assert float(s.mean()) == pytest.approx(mean_q, abs=5e-4)


def test_box_density_and_support():
    b = P.Box(torch.full((2, 3), 0.05), torch.full((2, 3), 1.0), event_dims=2)
    assert b.event_shape == (2, 3) and b.batch_shape == ()
    assert float(b.log_prob(torch.full((2, 3), 1.0))) == pytest.approx(-6 * math.log(0.95))  # finite at the bound
    e = b.expand(torch.Size([4]))
    assert e.log_prob(torch.rand(4, 2, 3)).shape == (4,)


def test_smoothness_closed_forms():
    x = torch.tensor([[[0.0, 1.0], [3.0, 3.0]]])           # [C=1, 2, 2]
    # horizontal diffs: 1, 0; vertical: 3, 2
    assert float(P.tv(2.0).log_prob(x)) == pytest.approx(-2.0 * (1 + 0 + 3 + 2))
    assert float(P.gmrf(2.0).log_prob(x)) == pytest.approx(-2.0 * 0.5 * (1 + 0 + 9 + 4))


@pytest.mark.parametrize("table, msg", [
    ({"model": "per_texel", "resolution": 0}, "resolution must be a positive integer"),
    ({"model": "per_texel", "colour": 3}, "unknown key(s) ['colour']"),
    ({"model": "nope"}, "unknown model 'nope'"),
    ({"model": "homogeneous", "prior": {"kind": "cauchy"}}, "unknown prior kind 'cauchy'"),
    ({"model": "homogeneous", "prior": {"kind": "gaussian", "mean": 0.1}}, "needs a mean and a std"),
    ({"model": "homogeneous", "sigma": -1}, "sigma must be a positive number or \"auto\""),
    ({"model": "homogeneous", "sigma": "big"}, "sigma must be a positive number or \"auto\""),
    ({"model": "homogeneous", "roughness_range": [0.5, 0.1]}, "roughness_range must satisfy"),
    ({"model": "per_texel", "smoothness": {"kind": "tv", "wieght": 1}}, "unknown key(s) ['wieght']"),
])
def test_bad_model_presets_are_one_line_errors(table, msg):
    with pytest.raises(InputError) as e:
        from_preset(table)
    assert msg in str(e.value) and "\n" not in str(e.value)


def test_preset_tables_per_site():
    m = from_preset({"model": "per_texel", "resolution": 8,
                     "prior": {"roughness": {"kind": "gaussian", "mean": 0.1, "std": 0.05}},
                     "smoothness": {"albedo": {"kind": "tv", "weight": 3.0}}})
    assert m._prior("roughness").kind == "gaussian" and m._prior("albedo").kind == "uniform"
    assert m.smoothness["albedo"].weight == 3.0 and "roughness" not in m.smoothness
    # the factor is there for the albedo alone
    import pyro.poutine as poutine
    import torch
    from bayes_brdf.models.data import ModelData
    from bayes_brdf.observations import Observations
    from bayes_brdf.render.views import collocated_views
    d = ModelData.from_observations(Observations(collocated_views(1, 3.0, resolution=8), torch.zeros(1, 8, 8, 3)))
    sites = poutine.trace(m.sample_sites).get_trace(d).nodes
    assert "albedo_smoothness" in sites and "roughness_smoothness" not in sites
