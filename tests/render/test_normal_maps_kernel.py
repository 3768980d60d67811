"""The native loss with a normal map per particle (``_native_normal_maps.c``) against the eager reference: the loss
and its gradients w.r.t. every map and the normals, clamped cosines included."""
import pytest
import torch

from bayes_brdf.render import SVBRDF, native
from bayes_brdf.render.maps import unit_vectors
from bayes_brdf.render.shade import shade, shade_loss

from .test_fused import RES, setup

pytestmark = pytest.mark.needs_native


def normals(n, seed=5, dtype=torch.float64):
    """Tilted unit normals, one texel turned past the horizon of every view (its n.l, n.v, n.h clamp)."""
    gen = torch.Generator().manual_seed(seed)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=dtype)[:, None, None]
    nrm = unit_vectors(0.5 * torch.randn(n, 3, RES, RES, generator=gen, dtype=dtype) + up)
    nrm[:, :, 0, 0] = torch.tensor([1.0, 0.0, -0.2], dtype=dtype)
    return nrm


def loss_and_grads(maps, leaves, g, target, weight, kind, backend):
    e = shade_loss(maps, g, target, weight, kind=kind, backend=backend)
    scale = torch.arange(1.0, e.shape[0] + 1.0, dtype=e.dtype)   # a different upstream gradient per particle
    return (e, *torch.autograd.grad((e * scale).sum(), leaves))


def calls(monkeypatch):
    """Count the native kernel's runs (so a test knows the fast path ran, not the eager one twice)."""
    seen = []
    real = native.NativeNormalMapLoss.apply
    monkeypatch.setattr(native.NativeNormalMapLoss, "apply", lambda *a: seen.append(1) or real(*a))
    return seen


@pytest.mark.parametrize("kind", ["l1", "l2"])
@pytest.mark.parametrize("lights", [1, 2, 4])
def test_per_particle_normals_loss_and_gradients_match_eager(monkeypatch, kind, lights):
    g, (kd, r, ks), flat = setup(lights=lights)
    nrm = normals(4).requires_grad_()
    leaves = [kd, r, ks, nrm]
    with torch.no_grad():
        target = shade(SVBRDF(kd[:1] * 0.9, r[:1], ks[:1], flat), g, backend="eager")[0]
    weight = torch.rand(target.shape[:3], generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    seen = calls(monkeypatch)
    got = loss_and_grads(SVBRDF(*leaves), leaves, g, target, weight, kind, "compiled")
    assert seen, "the native per-particle-normals kernel did not run"
    want = loss_and_grads(SVBRDF(*leaves), leaves, g, target, weight, kind, "eager")
    for a, e in zip(got, want):
        torch.testing.assert_close(a, e, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("wanted", [(True, True, True, True), (False, True, False, True), (True, False, True, False)])
def test_constant_maps_shared_normals_and_unwanted_gradients_match_eager(monkeypatch, wanted):
    """1x1 roughness and specular per particle (the kernel sums their gradients per block), one normal map shared by
    all particles but differentiated (its gradient is the particles' sum), and some gradients not asked for."""
    g, (kd, r, ks), flat = setup()
    maps = [kd.detach().clone(), r[:, :, :1, :1].detach().clone(), ks[:, :, :1, :1].detach().clone(),
            normals(1)[0]]
    for m, w in zip(maps, wanted):
        m.requires_grad_(w)
    leaves = [m for m, w in zip(maps, wanted) if w]
    target = torch.rand(3, RES, RES, 3, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    seen = calls(monkeypatch)
    got = loss_and_grads(SVBRDF(*maps), leaves, g, target, 1.0, "l2", "compiled")
    assert seen == ([1] if wanted[3] else [])     # normals neither per particle nor differentiated: the pixel kernel
    want = loss_and_grads(SVBRDF(*maps), leaves, g, target, 1.0, "l2", "eager")
    for a, e in zip(got, want):
        torch.testing.assert_close(a, e, rtol=1e-10, atol=1e-12)


def test_per_particle_normals_gradcheck():
    g, (kd, r, ks), _ = setup()
    nrm = normals(4).requires_grad_()
    target = torch.rand(3, RES, RES, 3, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    f = lambda kd, r, ks, n: shade_loss(SVBRDF(kd, r, ks, n), g, target, kind="l2", backend="compiled")  # noqa: E731
    assert torch.autograd.gradcheck(f, [kd, r, ks, nrm], eps=1e-6, atol=1e-5, rtol=1e-5)


def test_float32_per_particle_normals_loss_is_deterministic_and_close_to_float64():
    g, (kd, r, ks), _ = setup()
    nrm = normals(4)
    target = torch.rand(3, RES, RES, 3, generator=torch.Generator().manual_seed(4))
    m32 = SVBRDF(*(t.detach().float() for t in (kd, r, ks, nrm)))
    m32.normal.requires_grad_()
    a = shade_loss(m32, g.to(dtype=torch.float32), target, backend="compiled")
    ga, = torch.autograd.grad(a.sum(), m32.normal)
    b = shade_loss(m32, g.to(dtype=torch.float32), target, backend="compiled")
    gb, = torch.autograd.grad(b.sum(), m32.normal)
    assert torch.equal(a, b) and torch.equal(ga, gb)
    n64 = nrm.clone().requires_grad_()
    ref = shade_loss(SVBRDF(*(t.detach() for t in (kd, r, ks)), n64), g, target.double(), backend="eager")
    gref, = torch.autograd.grad(ref.sum(), n64)
    torch.testing.assert_close(a.double(), ref, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(ga.double(), gref, rtol=1e-3, atol=1e-4 * float(gref.abs().max()))
