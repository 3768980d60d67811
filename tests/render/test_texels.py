"""Texture lookup at arbitrary pixels (meshes, perspective views): the sparse bilinear taps against grid_sample,
and the compacted fused loss against the plain per-view loss, values and gradients."""
import pytest
import torch
import torch.nn.functional as F

from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import compacted, shade_loss
from bayes_brdf.render.texels import gather, tap_matrix


@pytest.mark.parametrize("align_corners", [False, True])
def test_sparse_taps_equal_grid_sample_with_border_padding(align_corners):
    g = torch.Generator().manual_seed(0)
    uv = torch.rand(500, 2, generator=g, dtype=torch.float64) * 2.4 - 1.2      # some outside [-1, 1]
    x = torch.rand(3, 2, 7, 5, generator=g, dtype=torch.float64, requires_grad=True)
    S, St = tap_matrix(uv, (7, 5), align_corners, dtype=torch.float64)
    y = gather(x, S, St)
    ref = F.grid_sample(x, uv.view(1, 1, -1, 2).expand(3, -1, -1, -1), mode="bilinear", padding_mode="border",
                        align_corners=align_corners)[:, :, 0]
    torch.testing.assert_close(y, ref)
    gy = torch.rand(y.shape, generator=g, dtype=torch.float64)
    torch.testing.assert_close(torch.autograd.grad(y, x, gy)[0], torch.autograd.grad(ref, x, gy)[0])


def test_compacted_loss_equals_the_per_view_loss_with_gradients():
    views = collocated_views(3, 2.5, resolution=20, fov=70)                    # perspective: pixels off the plane
    g = GBuffer.build(views, PlanarSample(2.0), dtype=torch.float64)
    assert not bool(g.mask.all())
    c, sel = compacted(g)
    assert c.resolution == (1, int(g.mask.sum())) and c.gathered
    gen = torch.Generator().manual_seed(1)
    kd = torch.rand(4, 3, 9, 9, generator=gen, dtype=torch.float64, requires_grad=True)
    r = (torch.rand(4, 1, 9, 9, generator=gen, dtype=torch.float64) * .7 + .2).requires_grad_()
    maps = SVBRDF(kd, r, torch.full((3, 1, 1), 0.04, dtype=torch.float64), torch.tensor([0., 0, 1]).view(3, 1, 1))
    target = torch.rand(3, 20, 20, 3, generator=gen, dtype=torch.float64)
    w = torch.rand(3, 20, 20, generator=gen, dtype=torch.float64)
    fast = shade_loss(maps, g, target, w, backend="compiled")                   # compacted, fused
    ref = shade_loss(maps, g, target, w, backend="eager", chunk_views=3)        # per view, grid_sample, autograd
    torch.testing.assert_close(fast, ref)
    for a, b in zip(torch.autograd.grad(fast.sum(), (kd, r)), torch.autograd.grad(ref.sum(), (kd, r))):
        torch.testing.assert_close(a, b)


def test_compacted_images_and_their_gradients_equal_the_per_view_images():
    """Images of views whose pixels are not texels are shaded on the valid pixels through the native texel
    gather and put back: the same images (0 off the surface) and gradients as the plain per-view path."""
    from bayes_brdf.render.shade import shade
    views = collocated_views(4, 2.5, resolution=16, fov=70, method="sobol")
    g = GBuffer.build(views, PlanarSample(2.0), dtype=torch.float64)
    gen = torch.Generator().manual_seed(2)
    kd = torch.rand(3, 3, 8, 8, generator=gen, dtype=torch.float64, requires_grad=True)
    r = (torch.rand(3, 1, 8, 8, generator=gen, dtype=torch.float64) * .7 + .2).requires_grad_()
    maps = SVBRDF(kd, r, torch.full((3, 1, 1), 0.04, dtype=torch.float64), torch.tensor([0., 0, 1]).view(3, 1, 1))
    fast = shade(maps, g, backend="compiled", chunk_views=3)     # two chunks of views
    ref = shade(maps, g, backend="eager")
    torch.testing.assert_close(fast, ref)
    assert bool((fast[:, ~g.mask] == 0).all())                    # [n, V, H, W, 3]: 0 off the surface
    gy = torch.rand(ref.shape, generator=gen, dtype=torch.float64)
    for a, b in zip(torch.autograd.grad(fast, (kd, r), gy), torch.autograd.grad(ref, (kd, r), gy)):
        torch.testing.assert_close(a, b)


def test_texel_gradients_do_not_depend_on_the_thread_count():
    """Many pixels scatter into one texel: each particle's gradients have one writer and one order, so one or
    two threads give the same bits (a rerun with the same seed gives the same posterior)."""
    views = collocated_views(3, 2.5, resolution=20, fov=70)
    g = GBuffer.build(views, PlanarSample(2.0))
    gen = torch.Generator().manual_seed(3)
    kd = torch.rand(5, 3, 9, 9, generator=gen, requires_grad=True)
    maps = SVBRDF(kd, torch.full((1, 1, 1), 0.4), torch.full((3, 1, 1), 0.04), torch.tensor([0., 0, 1]).view(3, 1, 1))
    target = torch.rand(3, 20, 20, 3, generator=gen)
    before = torch.get_num_threads()
    grads = []
    try:
        for t in (1, 2):
            torch.set_num_threads(t)
            grads.append(torch.autograd.grad(shade_loss(maps, g, target, backend="compiled").sum(), kd)[0])
    finally:
        torch.set_num_threads(before)
    assert torch.equal(grads[0], grads[1])
