"""The environment light: Mitsuba's envmap convention, its sampling, bad maps, and the precomputed transfer
against brute-force quadrature and a closed form of shadows (a sphere on a plane)."""
import math

import numpy as np
import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views
from bayes_brdf.render.environment import EnvironmentLight, z_up
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.scene import Scene
from bayes_brdf.render.shade import shade, shade_loss
from bayes_brdf.render.transfer import TransferSamples, interpolate, irradiance, transfer
from bayes_brdf.render.views import View

BALLROOM = "ballroom_1k.exr"


def _random_map(h=6, w=12, seed=0):
    return np.random.default_rng(seed).uniform(0.1, 2.0, (h, w, 3)).astype(np.float32)


def _dirs(n, seed=0):
    d = torch.randn(n, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return d / d.norm(dim=1, keepdim=True)


@pytest.mark.needs_llvm
def test_lookup_is_mitsubas_envmap_with_to_world_and_scale():
    from bayes_brdf.mitsuba_env import mitsuba_variant
    data = _random_map()
    T = z_up(33.0)
    env = EnvironmentLight(data, 1.7, T)
    d = _dirs(3000)
    with mitsuba_variant() as mi:
        import drjit as dr
        em = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(data), "scale": 1.7,
                           "to_world": mi.ScalarTransform4f(np.array(T))})
        si = dr.zeros(mi.SurfaceInteraction3f, d.shape[0])
        dn = d.numpy()
        si.wi = mi.Vector3f(-dn[:, 0], -dn[:, 1], -dn[:, 2])
        val = em.eval(si)
        theirs = np.stack([np.asarray(val[i]) for i in range(3)], 1)
    assert np.abs(env.eval(d).numpy() - theirs).max() < 1e-4


def test_z_up_puts_the_zenith_on_plus_z():
    data = np.zeros((5, 8, 3), np.float32)
    data[0] = 7.0                                       # the zenith row
    env = EnvironmentLight(data, to_world=z_up(20.0))
    assert env.eval(torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)).tolist() == [[7.0, 7.0, 7.0]]
    assert float(env.eval(torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64)).max()) == 0.0


def test_sampling_density_matches_its_samples():
    env = EnvironmentLight(_random_map(16, 32), to_world=z_up())
    d, pdf = env.sample(100_000, torch.Generator().manual_seed(0))
    assert torch.allclose(env.pdf(d), pdf, rtol=1e-6)
    assert abs(float((1 / pdf).mean()) / (4 * math.pi) - 1) < 0.01          # E[1 / p] = the sphere's area
    L = env.eval(d)
    u = _dirs(400_000, 1)
    assert torch.allclose((L / pdf[:, None]).mean(0), env.eval(u).mean(0) * 4 * math.pi, rtol=0.01)


def test_equal_by_content():
    a, b = EnvironmentLight(_random_map()), EnvironmentLight(_random_map())
    assert a == b and hash(a) == hash(b)
    assert a != EnvironmentLight(_random_map(), scale=2.0)


@pytest.mark.parametrize("bad, words", [
    (np.full((4, 8, 3), np.nan, np.float32), "NaN"),
    (-np.ones((4, 8, 3), np.float32), "negative"),
    (np.ones((2, 8, 3), np.float32), "at least 3 rows"),
    (np.ones((4, 8), np.float32), "RGB"),
])
def test_bad_maps_are_refused(bad, words):
    with pytest.raises(InputError, match=words):
        EnvironmentLight(bad)


def test_bad_to_world_and_files_are_refused(tmp_path):
    with pytest.raises(InputError, match="not rigid"):
        EnvironmentLight(np.ones((4, 8, 3), np.float32), to_world=np.diag([2.0, 1, 1, 1]))
    with pytest.raises(InputError, match="not found"):
        EnvironmentLight.from_file(tmp_path / "none.exr")
    (tmp_path / "x.exr").write_bytes(b"\x89PNG not an exr")
    with pytest.raises(InputError, match="not an HDR image"):
        EnvironmentLight.from_file(tmp_path / "x.exr")


def test_reads_exr_and_radiance_hdr(tmp_path):
    import cv2

    from bayes_brdf.io import write_exr
    data = _random_map(8, 16)
    write_exr(tmp_path / "e.exr", torch.from_numpy(data))
    cv2.imwrite(str(tmp_path / "e.hdr"), data[..., ::-1].copy())
    a = EnvironmentLight.from_file(tmp_path / "e.exr")
    b = EnvironmentLight.from_file(tmp_path / "e.hdr")
    assert torch.allclose(a.radiance, torch.from_numpy(data))
    assert torch.allclose(b.radiance, torch.from_numpy(data), atol=0.02)      # RGBE: 8-bit mantissas, one exponent


# ---------------------------------------------------------------------- the transfer
def _pixels(n, seed=3):
    g = torch.Generator().manual_seed(seed)
    th = torch.rand(n, generator=g, dtype=torch.float64) * 1.3
    ph = torch.rand(n, generator=g, dtype=torch.float64) * 2 * math.pi
    v = torch.stack([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()])[:, None]     # [3, 1, n]
    up = torch.tensor([0, 0, 1.0], dtype=torch.float64)[:, None, None].expand(3, 1, n)
    return torch.zeros(3, 1, n, dtype=torch.float64), up, v, torch.ones(1, n, dtype=torch.bool)


def _brute_force(env, v, kd, r, ks, grid=(1024, 4096)):
    """Radiance of a plane (normal +z) seen from ``v [3, 1, n]``: the BRDF times the environment summed over a
    dense grid of directions of the upper hemisphere (midpoint rule in theta, phi)."""
    from bayes_brdf.render.brdf import microfacet
    nt, nphi = grid
    th = (torch.arange(nt, dtype=torch.float64) + 0.5) / nt * (math.pi / 2)
    ph = (torch.arange(nphi, dtype=torch.float64) + 0.5) / nphi * 2 * math.pi
    T, Ph = torch.meshgrid(th, ph, indexing="ij")
    l = torch.stack([T.sin() * Ph.cos(), T.sin() * Ph.sin(), T.cos()], -1).reshape(-1, 3)
    dw = ((math.pi / 2 / nt) * (2 * math.pi / nphi) * T.sin()).reshape(-1)
    L = env.eval(l)
    out = []
    for k in range(v.shape[-1]):
        vv = v[:, 0, k]
        h = l + vv
        h = h / h.norm(dim=1, keepdim=True)
        nl, nv, nh, vh = l[:, 2], vv[2].expand(l.shape[0]), h[:, 2], (h @ vv).clamp_min(1e-8)
        f = microfacet(torch.tensor(kd, dtype=torch.float64), torch.tensor(r, dtype=torch.float64),
                       torch.tensor(ks, dtype=torch.float64), nl[:, None], nv[:, None], nh[:, None], vh[:, None])
        out.append((f * L * (nl * dw)[:, None]).sum(0))
    return torch.stack(out)                                     # [n, 3]


def test_white_environment_on_a_plane_is_pi_irradiance_and_the_brdfs_albedo():
    env = EnvironmentLight(torch.ones(16, 32, 3))
    pos, up, v, mask = _pixels(6)
    e = transfer(env, pos, up, up, v, mask, PlanarSample())
    assert torch.allclose(e[0:3], torch.full_like(e[0:3], math.pi), rtol=1e-3)
    for r in (0.2, 0.5, 1.0):
        E, a, b = interpolate(e, torch.full((1, 1, 6), r, dtype=torch.float64))
        ours = (0.5 * (1 - 0.04) / math.pi * E + 0.04 * a + b)[:, 0].T
        assert torch.allclose(ours, _brute_force(env, v, 0.5, r, 0.04, (512, 1024)), rtol=0.01), r


@pytest.mark.slow
def test_transfer_matches_brute_force_quadrature_under_a_real_environment(shared_data):
    env = EnvironmentLight.from_file(shared_data / "psdr_assets" / BALLROOM, to_world=z_up(30.0))
    pos, up, v, mask = _pixels(4)
    e = transfer(env, pos, up, up, v, mask, PlanarSample())
    for r, ks in ((0.3, 0.04), (0.6, 0.5), (1.0, 0.04)):
        E, a, b = interpolate(e, torch.full((1, 1, 4), r, dtype=torch.float64))
        ours = (0.5 * (1 - ks) / math.pi * E + ks * a + b)[:, 0].T
        truth = _brute_force(env, v, 0.5, r, ks)
        assert float((ours - truth).abs().max() / truth.max()) < 0.01, (r, ks)


def _sphere_on_plane(radius=0.5, size=8.0):
    plane, ball = Mesh.plane(size), Mesh.sphere(radius, center=(0.0, 0.0, radius), rings=48, segments=96)
    n0 = plane.vertices.shape[0]
    return Mesh(vertices=np.concatenate([plane.vertices, ball.vertices]),
                faces=np.concatenate([plane.faces, ball.faces + n0]),
                uv=np.concatenate([plane.uv, ball.uv]), normals=np.concatenate([plane.normals, ball.normals]),
                name="sphere_on_plane")


@pytest.mark.needs_llvm
def test_shadow_of_a_sphere_on_a_plane_is_the_closed_form():
    """Under a white sky of radiance 1, a point of the ground at distance D from the centre of a sphere of
    radius rho resting on it loses the cosine-weighted solid angle of the sphere's cap,
    ``pi sin^2(beta) cos(theta_c)`` with ``sin(beta) = rho / D`` and ``cos(theta_c) = rho / D``."""
    rho = 0.5
    mesh = _sphere_on_plane(rho)
    env = EnvironmentLight(torch.ones(16, 32, 3))
    x = torch.tensor([0.8, 1.1, 1.5, 2.0, 3.0], dtype=torch.float64)
    pos = torch.stack([x, torch.zeros_like(x), torch.zeros_like(x)])[:, None]
    up = torch.tensor([0, 0, 1.0], dtype=torch.float64)[:, None, None].expand(3, 1, len(x))
    v = torch.tensor([0.3, 0.0, 1.0], dtype=torch.float64)
    v = (v / v.norm())[:, None, None].expand(3, 1, len(x))
    e = transfer(env, pos, up, up, v, torch.ones(1, len(x), dtype=torch.bool), mesh)
    D2 = x * x + rho * rho
    closed = math.pi - math.pi * (rho * rho / D2) * (rho / D2.sqrt())
    assert torch.allclose(e[0, 0], closed, rtol=0.01)
    assert bool((e[0, 0] < math.pi - 1e-3).all())


# ---------------------------------------------------------------------- shading with it
def _views(env, flash=True, n=3, res=16):
    vs = collocated_views(n, 3.0, resolution=res, power=5)
    return [View(v.camera, (v.lights if flash else ()) + (env,), name=v.name) for v in vs]


def test_an_environment_adds_to_the_flash_and_gradients_are_exact():
    env = EnvironmentLight(_random_map(16, 32), to_world=z_up())
    both = GBuffer.build(_views(env), PlanarSample(2.0), dtype=torch.float64)
    flash = GBuffer.build(collocated_views(3, 3.0, resolution=16, power=5), PlanarSample(2.0), dtype=torch.float64)
    alone = GBuffer.build(_views(env, flash=False), PlanarSample(2.0), dtype=torch.float64)
    m = SVBRDF.constant(albedo=0.5, roughness=0.3).to(torch.float64)
    assert torch.allclose(shade(m, both), shade(m, flash) + shade(m, alone), atol=1e-12)
    R = 6
    g = torch.Generator().manual_seed(0)
    flat = torch.tensor([0, 0, 1.0], dtype=torch.float64)[:, None, None].expand(3, R, R)
    maps = SVBRDF(torch.rand(3, R, R, generator=g, dtype=torch.float64),
                  0.1 + 0.8 * torch.rand(1, R, R, generator=g, dtype=torch.float64),
                  torch.full((3, R, R), 0.04, dtype=torch.float64), flat)
    y = shade(maps, both)[0] * 1.1

    def loss(a, r, s):
        return shade_loss(SVBRDF(a, r, s, flat), both, y, kind="l2")

    args = [t.clone().requires_grad_() for t in (maps.albedo, maps.roughness, maps.specular)]
    assert torch.autograd.gradcheck(loss, args, eps=1e-6, atol=1e-6, rtol=1e-3)


def test_normals_that_the_transfer_cannot_follow_are_refused():
    env = EnvironmentLight(_random_map(8, 16))
    g = GBuffer.build(_views(env, n=1, res=8), PlanarSample(2.0))
    n = torch.tensor([0.3, 0.0, 1.0])[:, None, None].expand(3, 4, 4) / math.sqrt(1.09)
    with pytest.raises(InputError, match="normal map must be flat"):
        shade(SVBRDF(torch.full((3, 4, 4), 0.5), torch.full((1, 4, 4), 0.4), torch.full((3, 4, 4), 0.04), n), g)


def test_scene_with_an_environment_saves_and_loads():
    env = EnvironmentLight(_random_map(8, 16), scale=3.0, to_world=z_up(10.0), name="room")
    sc = Scene(PlanarSample(2.0), tuple(_views(env, n=2, res=8)))
    meta, tensors = sc.state()
    back = Scene.from_state(meta, tensors)
    assert back == sc and back.views[0].environment == env
    with pytest.raises(InputError, match="missing"):
        Scene.from_state(meta, {})


def test_irradiance_of_a_real_map_matches_quadrature(shared_data):
    env = EnvironmentLight.from_file(shared_data / "psdr_assets" / BALLROOM, to_world=z_up(30.0))
    n = _dirs(12, 5)
    h, w, _ = env.radiance.shape
    uu = (torch.arange(2 * w, dtype=torch.float64) + 0.5) / (2 * w)
    vv = (torch.arange(2 * h, dtype=torch.float64) + 0.5) / (2 * h)
    uv = torch.stack(torch.meshgrid(uu, vv, indexing="xy"), -1).reshape(-1, 2)
    d = env.from_uv(uv)
    L = env.eval(d) * ((2 * math.pi / (2 * w)) * (math.pi / (2 * h)) * (uv[:, 1] * math.pi).sin())[:, None]
    exact = ((d @ n.T).clamp_min(0).T @ L)
    assert torch.allclose(irradiance(env, n), exact, rtol=2e-3)


def _random_maps(n, R, gen, dtype):
    """``(kd, r, ks, flat normals)`` of ``n`` particles at ``R^2``: roughness past both ends of the tables."""
    flat = torch.tensor([0, 0, 1.0], dtype=dtype)[:, None, None].expand(3, R, R)
    kd = torch.rand(n, 3, R, R, generator=gen, dtype=dtype)
    r = 0.01 + 1.1 * torch.rand(n, 1, R, R, generator=gen, dtype=dtype)
    ks = 0.04 + 0.3 * torch.rand(n, 3, R, R, generator=gen, dtype=dtype)
    return kd, r, ks, flat


def _assert_loss_as_eager(kd, r, ks, flat, g, y, tol, label=None):
    """The L1 loss of the default backend and its gradients equal the eager reference's."""
    out = []
    for backend in ("eager", "auto"):
        ps = [t.clone().requires_grad_() for t in (kd, r, ks)]
        loss = shade_loss(SVBRDF(*ps, flat), g, y, kind="l1", backend=backend)
        loss.sum().backward()
        out.append((loss.detach(), [p.grad for p in ps]))
    (la, ga), (lb, gb) = out
    assert torch.allclose(la, lb, rtol=tol), (label, la, lb)
    for a, b in zip(ga, gb):
        assert float((a - b).abs().max() / a.abs().max()) < 10 * tol, label


@pytest.mark.needs_llvm
@pytest.mark.needs_native(kernel="texels")
@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-12), (torch.float32, 1e-4)])
def test_native_texel_kernel_shades_the_environment_as_the_reference(dtype, tol):
    """The fast path (the C texel kernel reading the tables) against the eager torch reference, on a mesh with a
    flash and an environment: images, losses and their gradients."""
    from bayes_brdf.render.mitsuba_reference import check_views
    mesh = Mesh.block_on_plane()
    env = EnvironmentLight(_random_map(16, 32), to_world=z_up(10.0))
    views = [View(v.camera, v.lights + (env,), name=v.name) for v in check_views(mesh, "block_on_plane", 24)]
    g = GBuffer.build(views, mesh, dtype=dtype)
    kd, r, ks, flat = _random_maps(3, 48, torch.Generator().manual_seed(0), dtype)
    ref = shade(SVBRDF(kd, r, ks, flat), g, backend="eager")
    assert float((shade(SVBRDF(kd, r, ks, flat), g) - ref).abs().max() / ref.abs().max()) < tol
    _assert_loss_as_eager(kd, r, ks, flat, g, ref[0] * 1.05, tol)


@pytest.mark.needs_native(kernel="texels")
@pytest.mark.parametrize("dtype, tol", [(torch.float64, 1e-12), (torch.float32, 1e-4)])
def test_rectified_views_under_an_environment_take_the_texel_kernel(dtype, tol, monkeypatch):
    """Rectified views of the plane (pixels = texels) under an environment alone and with a flash: the loss goes
    through the native texel kernel (one tap of weight 1 per pixel) and equals the eager reference, with its
    gradients, including maps of another resolution than the views' (read bilinearly)."""
    from bayes_brdf.render import native
    from bayes_brdf.render.shade import compacted_taps
    calls = []
    real = native.NativeLoss.apply
    monkeypatch.setattr(native.NativeLoss, "apply", lambda *a: calls.append(a[-1] is not None) or real(*a))
    env = EnvironmentLight(_random_map(16, 32), to_world=z_up(25.0))
    base = collocated_views(4, 3.0, camera="rectified", resolution=12, power=8.0)
    views = [View(v.camera, (env,) if i % 2 else v.lights + (env,), name=v.name) for i, v in enumerate(base)]
    g = GBuffer.build(views, PlanarSample(2.0), dtype=dtype)
    assert g.aligned
    gen = torch.Generator().manual_seed(1)
    y = 0.3 * torch.rand(4, 12, 12, 3, generator=gen, dtype=dtype)
    for R in (12, 9):
        _assert_loss_as_eager(*_random_maps(3, R, gen, dtype), g, y, tol, R)
    assert calls == [True, True]           # the auto losses, each with the environment's terms
    c, index = compacted_taps(g)
    assert c.texel is None and c.resolution == (1, 4 * 144) and sorted(index.tolist()) == list(range(4 * 144))


@pytest.mark.needs_native(kernel="texels")
def test_sixteen_lanes_give_the_eight_lanes_bits(monkeypatch):
    """The texel kernel's particles are its SIMD lanes: 8 per vector, or 16 where float32 vectors are 64 bytes
    (AVX-512) and that takes fewer passes (20 particles: 2 instead of 3). The lanes are independent particles,
    so both builds give the same images, losses and gradients, bit for bit, under a flash and an environment
    (whose table lookup transposes 8 lanes at a time), with particles that fill a block partly."""
    from bayes_brdf.render import native
    assert native.texel_lanes(torch.float64, 20) == 8 and native.texel_lanes(torch.float32, 8) == 8
    assert native.texel_lanes(torch.float32, 20) in (8, 16)
    env = EnvironmentLight(_random_map(16, 32), to_world=z_up(25.0))
    base = collocated_views(4, 3.0, camera="rectified", resolution=12, power=8.0)
    views = [View(v.camera, (env,) if i % 2 else v.lights + (env,), name=v.name) for i, v in enumerate(base)]
    g = GBuffer.build(views, PlanarSample(2.0), dtype=torch.float32)
    gen = torch.Generator().manual_seed(5)
    y = 0.3 * torch.rand(4, 12, 12, 3, generator=gen)
    kd, r, ks, flat = _random_maps(20, 9, gen, torch.float32)
    out = []
    for lanes in (8, 16):
        monkeypatch.setattr(native, "texel_lanes", lambda dtype, n, lanes=lanes: lanes)
        ps = [t.clone().requires_grad_() for t in (kd, r, ks)]
        loss = shade_loss(SVBRDF(*ps, flat), g, y, kind="l1")
        loss.sum().backward()
        with torch.no_grad():
            img = shade(SVBRDF(kd, r, ks, flat), g)
        out.append((img, loss.detach(), *[p.grad for p in ps]))
    for a, b in zip(*out):
        assert torch.equal(a, b)


@pytest.mark.needs_native(kernel="texels")
@pytest.mark.parametrize("light", ["flash", "environment"])
@pytest.mark.parametrize("n", [5, 20, 37])
def test_texel_kernel_fit_cases_match_eager(light, n, monkeypatch):
    """The cases a fit runs, which the texel kernel compiles with their options as constants: L1 loss, one
    flash per view or an environment alone, albedo and roughness per texel, a constant specular per particle
    whose gradient nobody wants, over particle counts that make one, two and three blocks of lanes (8 or 16):
    the loss and the maps' gradients equal the eager reference's."""
    from bayes_brdf.render import native
    calls = []
    real = native._call
    monkeypatch.setattr(native, "_call", lambda *a, **k: calls.append(k.get("taps") is not None) or real(*a, **k))
    env = EnvironmentLight(_random_map(16, 32), to_world=z_up(25.0))
    base = collocated_views(3, 2.5, resolution=10, fov=70, method="sobol", power=20.0)   # perspective: taps
    views = base if light == "flash" else [View(v.camera, (env,), name=v.name) for v in base]
    g = GBuffer.build(views, PlanarSample(2.0), dtype=torch.float64)
    gen = torch.Generator().manual_seed(n)
    kd, r, _, flat = _random_maps(n, 7, gen, torch.float64)
    ks = 0.04 + 0.3 * torch.rand(n, 3, 1, 1, generator=gen, dtype=torch.float64)
    y = 0.3 * torch.rand(3, 10, 10, 3, generator=gen, dtype=torch.float64)
    out = []
    for backend in ("eager", "auto"):
        ps = [t.clone().requires_grad_() for t in (kd, r)]
        loss = shade_loss(SVBRDF(*ps[:1], ps[1], ks, flat), g, y, kind="l1", backend=backend)
        (loss * torch.arange(1.0, n + 1, dtype=loss.dtype)).sum().backward()
        out.append((loss.detach(), *[p.grad for p in ps]))
    assert calls == [True]                     # the texel kernel
    for a, b in zip(*out):
        torch.testing.assert_close(b, a, rtol=1e-10, atol=1e-12)


def _level_by_level(light, pyr, l, footprint, bias):
    """The filtered look-up as its definition: every level ``k`` (0: the map, ``k``: ``pyr[k - 1]`` read
    bilinearly at cell centres) weighted by the tent ``max(0, 1 - |lev - k|)``, summed level by level."""
    uv = light.to_uv(l)
    h, w, _ = light.radiance.shape
    texel = (2 * math.pi / w) * (math.pi / (h - 1)) * (uv[..., 1] * math.pi).sin().clamp_min(1e-6)
    lev = (0.5 * torch.log2(footprint.clamp_min(1e-30) / texel) + bias).clamp(0, len(pyr))
    out = light.eval(l) * (1 - lev).clamp_min(0)[..., None]
    for k, img in enumerate(pyr, 1):
        hh, ww, _ = img.shape
        x = uv[..., 0] * ww - 0.5
        y = (uv[..., 1] * hh - 0.5).clamp(0, hh - 1)
        x0, y0 = torch.floor(x), torch.floor(y).clamp(max=hh - 2)
        fx, fy = (x - x0)[..., None], (y - y0)[..., None]
        x0, y0 = x0.long() % ww, y0.long()
        x1 = (x0 + 1) % ww
        look = (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x1] * fx * (1 - fy) + img[y0 + 1, x0] * (1 - fx) * fy
                + img[y0 + 1, x1] * fx * fy)
        out = out + look * (1 - (lev - k).abs()).clamp_min(0)[..., None] * light.scale
    return out


def test_filtered_lookup_is_the_tent_weighted_sum_of_the_pyramid_levels():
    """The transfer's pre-filtered radiance reads each direction's two neighbouring pyramid levels in one
    gather; it equals the level-by-level tent-weighted sum, for footprints from below a texel (the map itself)
    to past the coarsest level, at the poles and across the u seam."""
    from bayes_brdf.render.transfer import _filtered, pyramid
    light = EnvironmentLight(_random_map(64, 128), to_world=z_up(20.0), scale=1.7)
    pyr = pyramid(light)
    gen = torch.Generator().manual_seed(6)
    d = torch.randn(4000, 3, generator=gen, dtype=torch.float64)
    d[:4] = torch.tensor([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [-1.0, 1e-9, 0]])
    d = d / d.norm(dim=-1, keepdim=True)
    footprint = 10 ** (torch.rand(4000, generator=gen, dtype=torch.float64) * 7 - 6.5)
    for bias in (0.0, 0.5):
        ours, ref = _filtered(light, pyr, d, footprint, bias), _level_by_level(light, pyr, d, footprint, bias)
        assert torch.allclose(ours, ref, rtol=1e-12, atol=1e-12)
