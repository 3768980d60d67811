"""The library's own optimisers: Adam against ``torch.optim.Adam`` (the same numbers), the Newton method on a
problem with a known minimum and on the noise level's fit, and no ``torch._dynamo`` import from a fit."""
from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from bayes_brdf.models.noise import fit_noise_level
from bayes_brdf.optimize import Adam, newton


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_adam_takes_the_same_steps_as_torch_optim(dtype):
    gen = torch.Generator().manual_seed(0)
    target = torch.randn(3, 50, generator=gen, dtype=dtype)
    scale = torch.rand(3, 50, generator=gen, dtype=dtype) * 10
    ours = torch.zeros(3, 50, dtype=dtype)
    ref = torch.zeros(3, 50, dtype=dtype, requires_grad=True)
    opt, topt = Adam(ours, lr=0.02, betas=(0.9, 0.99), eps=1e-6), torch.optim.Adam([ref], lr=0.02, betas=(0.9, 0.99),
                                                                                    eps=1e-6)
    for _ in range(100):
        opt.step(scale * (ours - target) ** 3)
        topt.zero_grad()
        ref.grad = scale * (ref.detach() - target) ** 3
        topt.step()
    assert torch.equal(ours, ref.detach())


def test_newton_descends_negative_curvature_and_finds_the_minimum():
    # f = x^4/4 - x^2/2 + y^2: a maximum at the start's x = 0 is left along the negative curvature
    def f(v):
        x, y = v
        return float(x ** 4 / 4 - x ** 2 / 2 + y ** 2), torch.stack([x ** 3 - x, 2 * y]), \
            torch.diag(torch.stack([3 * x ** 2 - 1, torch.tensor(2.0, dtype=v.dtype)]))
    x = newton(f, torch.tensor([1e-3, 0.7], dtype=torch.float64))
    assert x.tolist() == pytest.approx([1.0, 0.0], abs=1e-6)   # ftol: the value to 1e-13


@pytest.mark.parametrize("kind", ["laplace", "gaussian"])
@pytest.mark.parametrize("truth", [(1e-4, 2e-4, 2.5e-3), (2e-5, 5e-4, 0.0), (1e-3, 0.0, 0.0)])
def test_noise_level_fit_recovers_known_levels(kind, truth):
    """Each term the data has, found within 5 %; a term it lacks, negligible at the data's radiance."""
    a, b, c = truth
    gen = torch.Generator().manual_seed(1)
    y = torch.rand(300_000, generator=gen, dtype=torch.float64) * 0.5
    s = (a + b * y + c * y * y).sqrt()
    e = torch.empty(300_000, 3, dtype=torch.float64)
    if kind == "laplace":
        u = torch.rand(300_000, 3, generator=gen, dtype=torch.float64) - 0.5
        e = -s[:, None] * u.sign() * torch.log1p(-2 * u.abs())
    else:
        e = s[:, None] * torch.randn(300_000, 3, generator=gen, dtype=torch.float64)
    nl = fit_noise_level(y, e, kind=kind)
    for got, want, at in ((nl.a, a, 1.0), (nl.b, b, 0.5), (nl.c, c, 0.25)):
        if want > 0:
            assert got == pytest.approx(want, rel=0.05)
        else:
            assert got * at < 0.02 * (a + b * 0.5 + c * 0.25)


def test_a_fit_does_not_import_torch_dynamo(tmp_path):
    """torch.optim's first optimiser imports torch._dynamo (about a second of every command's start)."""
    code = ("import sys, torch, bayes_brdf as bb\n"
            "from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views\n"
            "from bayes_brdf.render.shade import render\n"
            "views = collocated_views(3, 3.0, camera='rectified', resolution=8)\n"
            "y = render(SVBRDF.constant(0.5, 0.3), views, PlanarSample(2.0))[0]\n"
            "y = y + 0.01 * torch.randn(y.shape, generator=torch.Generator().manual_seed(0))\n"
            "obs = bb.Observations(views, y, PlanarSample(2.0))\n"
            "post = bb.infer(bb.models.per_texel(resolution=8), obs, 'spos', steps=20, progress=False)\n"
            "post.refine_map(steps=5)\n"
            "print('torch._dynamo' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "False"
