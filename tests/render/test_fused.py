"""The fused kernels (native C on CPU, torch.compile elsewhere) agree with the eager reference."""
import pytest
import torch

from bayes_brdf.render import SVBRDF, PlanarSample, PointLight, View, collocated_views
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import shade, shade_loss, shade_pixel_loss

RES = 8


@pytest.fixture(params=[pytest.param("native", marks=pytest.mark.needs_native), "torch.compile"])
def impl(request, monkeypatch):
    """Run the 'compiled' backend through each implementation (native is CPU-only)."""
    if request.param != "native":
        monkeypatch.setenv("BAYES_BRDF_NO_NATIVE", "1")
    return request.param


def setup(dtype=torch.float64, lights=1):
    views = collocated_views(3, radius=6.0, camera="rectified", resolution=RES, power=50.0, method="sobol")
    extra = [PointLight((1.0, -2.0, 4.0), (20.0, 10.0, 5.0)), PointLight((-3.0, 1.0, 6.0), 30.0),
             PointLight((0.0, 3.0, 5.0), 10.0, falloff=False), PointLight((2.0, 2.0, 2.0), 5.0)]
    views = [View(v.camera, v.lights + tuple(extra[:lights - 1])) for v in views]
    g = GBuffer.build(views, PlanarSample(3.0), dtype=dtype)
    gen = torch.Generator().manual_seed(1)
    u = lambda *s: torch.rand(*s, generator=gen, dtype=dtype)  # noqa: E731
    leaves = [u(4, 3, RES, RES).requires_grad_(), (0.05 + 0.9 * u(4, 1, RES, RES)).requires_grad_(),
              (0.5 * u(4, 3, RES, RES)).requires_grad_()]
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=dtype)[:, None, None].expand(3, RES, RES)
    return g, leaves, normal


def image_and_grads(maps_fn, leaves, g, backend, **kw):
    img = shade(maps_fn(*leaves), g, backend=backend, **kw)
    gout = torch.linspace(-1, 1, img.numel(), dtype=img.dtype).reshape(img.shape)
    return (img, *torch.autograd.grad(img, leaves, gout))


@pytest.mark.parametrize("ks_factor", [True, False])
@pytest.mark.parametrize("lights", [1, 2, 5])  # 5 > native.MAX_LIGHTS: falls back, must still agree
def test_compiled_images_and_gradients_match_eager(impl, ks_factor, lights):
    g, leaves, normal = setup(lights=lights)
    make = lambda kd, r, ks: SVBRDF(kd, r, ks, normal)  # noqa: E731
    got = image_and_grads(make, leaves, g, "compiled", ks_factor=ks_factor)
    want = image_and_grads(make, leaves, g, "eager", ks_factor=ks_factor)
    for a, e in zip(got, want):
        torch.testing.assert_close(a, e, rtol=1e-10, atol=1e-12)


def test_constant_and_shared_maps_match_eager(impl):
    """A homogeneous roughness (1x1) and a specular map shared by all particles, through the fused path."""
    g, (kd, r, ks), normal = setup()
    r1 = r[:, :, :1, :1].detach().clone().requires_grad_()
    ks1 = ks[:1].detach().clone().requires_grad_()
    make = lambda kd, r, ks: SVBRDF(kd, r, ks[0], normal)  # noqa: E731
    got = image_and_grads(make, [kd, r1, ks1], g, "compiled")
    want = image_and_grads(make, [kd, r1, ks1], g, "eager")
    for a, e in zip(got, want):
        torch.testing.assert_close(a, e, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("wanted", [(True, True, True), (True, True, False), (False, True, True)])
def test_fused_loss_with_constant_maps_matches_eager(impl, wanted):
    """The loss path with 1x1 maps per particle (a constant roughness, a constant specular: the kernel reads one
    value, sums its gradient per block) and maps whose gradient is not wanted, against the eager reference."""
    g, (kd, r, ks), normal = setup()
    maps = [kd.detach().clone(), r[:, :, :1, :1].detach().clone(), ks[:, :, :1, :1].detach().clone()]
    for m, w in zip(maps, wanted):
        m.requires_grad_(w)
    leaves = [m for m, w in zip(maps, wanted) if w]
    with torch.no_grad():
        target = shade(SVBRDF(*(t[:1] * 0.9 for t in maps), normal), g, backend="eager")[0]
    res = {}
    for b in ("eager", "compiled"):
        e = shade_loss(SVBRDF(*maps, normal), g, target, kind="l2", backend=b)
        scale = torch.arange(1.0, 5.0, dtype=e.dtype)
        res[b] = (e, *torch.autograd.grad((e * scale).sum(), leaves))
    for a, e in zip(res["compiled"], res["eager"]):
        torch.testing.assert_close(a, e, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", ["l1", "l2"])
@pytest.mark.parametrize("lights", [1, 2])
def test_fused_loss_matches_eager_and_image_loss(impl, kind, lights):
    g, leaves, normal = setup(lights=lights)
    with torch.no_grad():
        target = shade(SVBRDF(*(t[:1] * 0.9 for t in leaves), normal), g, backend="eager")[0]
    weight = torch.rand(target.shape[:3], generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    res = {}
    for b in ("eager", "compiled"):
        e = shade_loss(SVBRDF(*leaves, normal), g, target, weight, kind=kind, backend=b)
        scale = torch.arange(1.0, 5.0, dtype=e.dtype)  # a non-trivial upstream gradient per particle
        res[b] = (e, *torch.autograd.grad((e * scale).sum(), leaves))
    for a, e in zip(res["compiled"], res["eager"]):
        torch.testing.assert_close(a, e, rtol=1e-10, atol=1e-12)
    img = shade(SVBRDF(*(t.detach() for t in leaves), normal), g, backend="eager")
    d = img - target
    want = (weight[..., None] * (d.abs() if kind == "l1" else d * d)).flatten(1).sum(1)
    torch.testing.assert_close(res["compiled"][0].detach(), want)


def test_loss_gradcheck_compiled(impl):
    g, leaves, normal = setup()
    target = torch.rand(3, RES, RES, 3, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    f = lambda kd, r, ks: shade_loss(SVBRDF(kd, r, ks, normal), g, target, kind="l2", backend="compiled")  # noqa: E731
    assert torch.autograd.gradcheck(f, leaves, eps=1e-6, atol=1e-5, rtol=1e-5)


def test_float32_fused_loss_is_deterministic_and_close_to_float64(impl):
    g64, leaves, normal = setup()
    maps32 = SVBRDF(*(t.detach().float() for t in leaves), normal.float())
    target = torch.rand(3, RES, RES, 3, generator=torch.Generator().manual_seed(4))
    a = shade_loss(maps32, g64, target, backend="compiled")
    b = shade_loss(maps32, g64, target, backend="compiled")
    assert torch.equal(a, b)
    ref = shade_loss(SVBRDF(*(t.detach() for t in leaves), normal), g64, target.double(), backend="eager")
    torch.testing.assert_close(a.double(), ref, rtol=1e-5, atol=1e-6)


@pytest.mark.needs_native
@pytest.mark.parametrize("kind", ["l1", "l2"])
@pytest.mark.parametrize("lights", [1, 2, 5])     # 5 > native.MAX_LIGHTS: the eager reduction, same numbers
@pytest.mark.parametrize("constant", [False, True])
def test_per_pixel_loss_matches_eager_and_sums_to_the_loss(kind, lights, constant):
    """What a texel-local move scores: each pixel's loss summed over the views, from the kernel without images."""
    g, leaves, normal = setup(lights=lights)
    maps = [t.detach() for t in leaves]
    if constant:                                   # a 1 x 1 roughness: one value per particle
        maps[1] = maps[1][..., :1, :1].contiguous()
    x = SVBRDF(*maps, normal)
    target = shade(SVBRDF(*(t[:1] * 0.9 for t in maps), normal), g, backend="eager")[0]
    weight = torch.rand(target.shape[:3], generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    fast = shade_pixel_loss(x, g, target, weight, kind=kind, backend="auto")
    d = shade(x, g, backend="eager") - target
    want = torch.einsum("nvhwc,vhw->nhwc", d.abs() if kind == "l1" else d * d, weight)
    torch.testing.assert_close(fast, want, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(shade_pixel_loss(x, g, target, weight, kind=kind, backend="eager"), want)
    torch.testing.assert_close(fast.flatten(1).sum(1), shade_loss(x, g, target, weight, kind=kind, backend="eager"))
