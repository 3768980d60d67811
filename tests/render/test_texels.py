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
    """Many pixels scatter into one texel: the pixels come in fixed chunks, each with gradient rows of its own,
    and each texel sums its chunks' rows in chunk order, so one or two threads give the same bits (a rerun
    with the same seed gives the same posterior). Here about 4 chunks of pixels."""
    from bayes_brdf.render.texels import CHUNK_PIXELS
    views = collocated_views(3, 2.5, resolution=40, fov=40)
    g = GBuffer.build(views, PlanarSample(2.0))
    assert int(g.mask.sum()) > 3 * CHUNK_PIXELS
    gen = torch.Generator().manual_seed(3)
    kd = torch.rand(5, 3, 9, 9, generator=gen, requires_grad=True)
    maps = SVBRDF(kd, torch.full((1, 1, 1), 0.4), torch.full((3, 1, 1), 0.04), torch.tensor([0., 0, 1]).view(3, 1, 1))
    target = torch.rand(3, 40, 40, 3, generator=gen)
    before = torch.get_num_threads()
    grads = []
    try:
        for t in (1, 2):
            torch.set_num_threads(t)
            grads.append(torch.autograd.grad(shade_loss(maps, g, target, backend="compiled").sum(), kd)[0])
    finally:
        torch.set_num_threads(before)
    assert torch.equal(grads[0], grads[1])


@pytest.mark.parametrize("kind", ["l1", "l2"])
@pytest.mark.parametrize("lights", [1, 3])
@pytest.mark.parametrize("ks_factor", [True, False])
@pytest.mark.needs_native(kernel="texels")
def test_texel_kernel_matches_eager_with_constant_and_shared_maps(kind, lights, ks_factor, monkeypatch):
    """The native texel kernel (particles are its SIMD lanes: 11 particles fill one block of lanes and part of
    another) with an albedo map per particle, a constant roughness per particle and a specular map shared by
    all particles, each needing its gradient: the loss, the images and their gradients equal the eager
    per-view path (grid_sample, autograd)."""
    from bayes_brdf.render import PointLight, View, native
    from bayes_brdf.render.shade import shade
    extra = [PointLight((1.0, -2.0, 4.0), (20.0, 10.0, 5.0)), PointLight((-3.0, 1.0, 6.0), 30.0)]
    views = [View(v.camera, v.lights + tuple(extra[:lights - 1]))
             for v in collocated_views(3, 2.5, resolution=16, fov=70, method="sobol", power=20.0)]
    g = GBuffer.build(views, PlanarSample(2.0), dtype=torch.float64)
    gen = torch.Generator().manual_seed(4)
    kd = torch.rand(11, 3, 9, 9, generator=gen, dtype=torch.float64, requires_grad=True)
    r = (torch.rand(11, 1, 1, 1, generator=gen, dtype=torch.float64) * .7 + .2).requires_grad_()
    ks = (torch.rand(3, 9, 9, generator=gen, dtype=torch.float64) * .5).requires_grad_()
    maps = SVBRDF(kd, r, ks, torch.tensor([0., 0, 1], dtype=torch.float64).view(3, 1, 1))
    calls = []
    real_call = native._call
    monkeypatch.setattr(native, "_call", lambda *a, **k: calls.append(k.get("taps")) or real_call(*a, **k))
    target = torch.rand(3, 16, 16, 3, generator=gen, dtype=torch.float64)
    w = torch.rand(3, 16, 16, generator=gen, dtype=torch.float64)
    up = torch.arange(1.0, 12.0, dtype=torch.float64)           # a different upstream gradient per particle
    res = {}
    for b in ("compiled", "eager"):
        e = shade_loss(maps, g, target, w, kind=kind, ks_factor=ks_factor, backend=b)
        img = shade(maps, g, ks_factor=ks_factor, backend=b)
        gy = torch.linspace(-1, 1, img.numel(), dtype=img.dtype).reshape(img.shape)
        res[b] = (e, *torch.autograd.grad((e * up).sum(), (kd, r, ks)), img,
                  *torch.autograd.grad(img, (kd, r, ks), gy))
    assert calls and all(t is not None for t in calls)         # every native call went through the texel kernel
    for a, b in zip(res["compiled"], res["eager"]):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
