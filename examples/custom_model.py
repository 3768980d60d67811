"""A user's own material model and prior, written outside the package, sampled with any bayes-brdf sampler.

The model: one homogeneous material whose RGB albedo shares a single
brightness ``b`` (a Beta prior: the user believes the sample is mid-gray-ish)
with a per-channel tint on a simplex (a Dirichlet prior), roughness with a
log-normal prior folded into the valid range, and a ``pyro.factor`` of the
user's own making (a soft penalty on very saturated tints). It ends with
``bb.models.observe``, the likelihood of Eq. (2).

Run it:  python examples/custom_model.py [sampler]
"""
import sys

import pyro
import pyro.distributions as dist
import torch

import bayes_brdf as bb
from bayes_brdf.render import SVBRDF


def my_model(data):
    """Pyro model of the material given ``data`` (a ``bb.models.ModelData``); vectorisable over particles."""
    b = pyro.sample("brightness", dist.Beta(torch.tensor(4.0), torch.tensor(4.0)))
    tint = pyro.sample("tint", dist.Dirichlet(torch.full((3,), 8.0)))
    rough = pyro.sample("roughness", dist.LogNormal(torch.tensor(-1.2), torch.tensor(0.4)))
    pyro.factor("not_too_saturated", -20.0 * ((tint - 1 / 3) ** 2).sum(-1))
    albedo = (3 * b[..., None] * tint).clamp(0.0, 1.0)             # [n, 3]
    r = rough.clamp(0.05, 1.0)[..., None]                            # [n, 1]
    maps = SVBRDF(albedo[..., None, None], r[..., None, None],
                  torch.full((3, 1, 1), 0.04), torch.tensor([0.0, 0.0, 1.0]).reshape(3, 1, 1))
    bb.models.observe(data, maps, sigma=0.01)


def synthetic_observations():
    views = bb.render.collocated_views(6, 3.0, camera="rectified", resolution=8, power=10.0)
    truth = SVBRDF.constant(albedo=(0.6, 0.45, 0.3), roughness=0.35)
    imgs = bb.render.shade.render(truth, views, bb.render.PlanarSample(2.0))[0]
    return bb.Observations(views, imgs, bb.render.PlanarSample(2.0))


if __name__ == "__main__":
    sampler = sys.argv[1] if len(sys.argv) > 1 else "spos"
    post = bb.infer(my_model, synthetic_observations(), sampler, steps=300, seed=0)
    print(post)
    for site, m in post.mean().items():
        print(f"{site:12s} mean {m.tolist()}  std {post.std(site).tolist()}")
