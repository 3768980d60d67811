"""Analytic vs finite-difference gradients (float64 gradcheck) through the whole shading path."""
import pytest
import torch

from bayes_brdf.render import SVBRDF, PerspectiveCamera, PlanarSample, PointLight, RectifiedCamera, View
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import shade

RES = 4
VIEWS = [
    View(RectifiedCamera((0.5, 0.2, 6.0), RES), (PointLight((0.5, 0.2, 6.0), 40.0),)),
    View(RectifiedCamera((-2.0, 1.0, 5.0), RES), (PointLight((2.0, -1.0, 4.0), (30.0, 20.0, 10.0)),)),
]


def leaf_maps(n=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    u = lambda *s: torch.rand(*s, generator=g, dtype=torch.float64)  # noqa: E731
    nrm = torch.cat([0.3 * (u(n, 2, RES, RES) - 0.5), torch.ones(n, 1, RES, RES, dtype=torch.float64)], 1)
    return [t.requires_grad_() for t in (u(n, 3, RES, RES), 0.1 + 0.8 * u(n, 1, RES, RES), 0.5 * u(n, 3, RES, RES), nrm)]


@pytest.mark.parametrize("backend", ["eager", "compiled"])
@pytest.mark.parametrize("lookup", ["aligned", "bilinear"])
def test_gradcheck_all_maps(backend, lookup):
    g = GBuffer.build(VIEWS, PlanarSample(3.0), dtype=torch.float64)
    if lookup == "bilinear":
        g.aligned = False  # force the bilinear texture lookup path
    maps = leaf_maps()
    if backend == "compiled":  # the fused kernel applies when the normals are held fixed
        fixed_n = maps.pop().detach()[0]

        def f(kd, r, ks):
            return shade(SVBRDF(kd, r, ks, fixed_n), g, backend=backend)
    else:
        def f(kd, r, ks, n):
            return shade(SVBRDF(kd, r, ks, n), g, backend=backend)

    assert torch.autograd.gradcheck(f, maps, eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("backend", ["eager", "compiled"])
def test_gradcheck_perspective_view_with_subset_fixed(backend):
    view = View.collocated(PerspectiveCamera((0.3, -1.0, 3.0), fov=40, resolution=(5, 6)), power=5.0)
    g = GBuffer.build([view], PlanarSample(2.0), dtype=torch.float64)
    kd, r, ks, n = leaf_maps()
    fixed_ks, fixed_n = ks[0].detach(), n[0].detach()  # held fixed: no particle dimension

    def f(kd, r):
        return shade(SVBRDF(kd, r, fixed_ks, fixed_n), g, backend=backend)

    assert torch.autograd.gradcheck(f, (kd, r), eps=1e-6, atol=1e-6, rtol=1e-5)
