"""The renderer on a CUDA device (runs where a GPU is present, skipped otherwise)."""
import pytest
import torch

from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import shade, shade_loss

pytestmark = pytest.mark.needs_cuda


@pytest.mark.parametrize("backend", ["eager", "compiled"])
def test_cuda_matches_cpu_and_follows_the_tensors(backend):
    views = collocated_views(4, 6.0, camera="rectified", resolution=32, power=50.0)
    g = GBuffer.build(views, PlanarSample(3.0))
    gen = torch.Generator().manual_seed(0)
    cpu = [torch.rand(5, c, 32, 32, generator=gen) for c in (3, 1, 3)]
    cpu[1] = 0.05 + 0.9 * cpu[1]
    normal = torch.tensor([0.0, 0, 1])[:, None, None].expand(3, 32, 32)
    out = {}
    for dev in ("cpu", "cuda"):
        leaves = [t.to(dev).requires_grad_() for t in cpu]
        img = shade(SVBRDF(*leaves, normal.to(dev)), g, backend=backend)
        assert img.device.type == dev
        target = img.detach()[0] * 0.8
        loss = shade_loss(SVBRDF(*leaves, normal.to(dev)), g, target, backend=backend)
        out[dev] = [img.detach(), loss.detach(), *torch.autograd.grad(loss.sum(), leaves)]
    for a, b in zip(out["cuda"], out["cpu"]):
        torch.testing.assert_close(a.cpu(), b, rtol=1e-4, atol=1e-4)
