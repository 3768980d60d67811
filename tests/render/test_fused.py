"""The fused (compiled, analytic-gradient) kernels agree with the eager reference."""
import pytest
import torch

from bayes_brdf.render import SVBRDF, PlanarSample, PointLight, View, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import shade, shade_loss

RES = 8


def setup(dtype=torch.float64, lights=1):
    views = collocated_views(3, radius=6.0, camera="rectified", resolution=RES, power=50.0, method="sobol")
    if lights == 2:
        views = [View(v.camera, v.lights + (PointLight((1.0, -2.0, 4.0), (20.0, 10.0, 5.0)),)) for v in views]
    g = GBuffer.build(views, PlanarSample(3.0), dtype=dtype)
    gen = torch.Generator().manual_seed(1)
    u = lambda *s: torch.rand(*s, generator=gen, dtype=dtype)  # noqa: E731
    leaves = [u(4, 3, RES, RES).requires_grad_(), (0.05 + 0.9 * u(4, 1, RES, RES)).requires_grad_(),
              (0.5 * u(4, 3, RES, RES)).requires_grad_()]
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=dtype)[:, None, None].expand(3, RES, RES)
    return g, leaves, normal


@pytest.mark.parametrize("ks_factor", [True, False])
@pytest.mark.parametrize("lights", [1, 2])
def test_compiled_images_and_gradients_match_eager(ks_factor, lights):
    g, leaves, normal = setup(lights=lights)
    outs = {}
    for b in ("eager", "compiled"):
        img = shade(SVBRDF(*leaves, normal), g, backend=b, ks_factor=ks_factor)
        gout = torch.linspace(-1, 1, img.numel(), dtype=img.dtype).reshape(img.shape)
        outs[b] = (img, *torch.autograd.grad(img, leaves, gout))
    for a, e in zip(outs["compiled"], outs["eager"]):
        torch.testing.assert_close(a, e, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", ["l1", "l2"])
@pytest.mark.parametrize("lights", [1, 2])
def test_fused_loss_matches_eager_and_image_loss(kind, lights):
    g, leaves, normal = setup(lights=lights)
    with torch.no_grad():
        target = shade(SVBRDF(*(t[:1] * 0.9 for t in leaves), normal), g, backend="eager")[0]
    weight = torch.rand(target.shape[:3], generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    res = {}
    for b in ("eager", "compiled"):
        e = shade_loss(SVBRDF(*leaves, normal), g, target, weight, kind=kind, backend=b)
        res[b] = (e, *torch.autograd.grad(e.sum(), leaves))
    for a, e in zip(res["compiled"], res["eager"]):
        torch.testing.assert_close(a, e, rtol=1e-10, atol=1e-12)
    img = shade(SVBRDF(*(t.detach() for t in leaves), normal), g, backend="eager")
    d = img - target
    want = (weight[..., None] * (d.abs() if kind == "l1" else d * d)).flatten(1).sum(1)
    torch.testing.assert_close(res["compiled"][0].detach(), want)


def test_loss_gradcheck_compiled():
    g, leaves, normal = setup()
    target = torch.rand(3, RES, RES, 3, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    f = lambda kd, r, ks: shade_loss(SVBRDF(kd, r, ks, normal), g, target, kind="l2", backend="compiled")  # noqa: E731
    assert torch.autograd.gradcheck(f, leaves, eps=1e-6, atol=1e-5, rtol=1e-5)
