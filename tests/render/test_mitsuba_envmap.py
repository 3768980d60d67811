"""The Mitsuba reference under an environment light (render.mitsuba_reference): envmap passes, MIS, the BSDF's sampling.

An environment pass is Mitsuba's ``direct`` integrator with one emitter and one BSDF sample per pixel sample
(MIS), ``spp`` of them averaged. Checked here against what needs no Mitsuba and none of our renderer: the
BRDF written once more in numpy and integrated by quadrature over the hemisphere (a white constant
environment makes a pixel's radiance the BRDF's cosine-weighted integral), and, for the BSDF's sampling,
its ``eval`` and ``pdf`` integrated by quadrature over half vectors against what ``sample`` draws.
"""
import math

import numpy as np
import pytest
import torch

from bayes_brdf.render import SVBRDF, PerspectiveCamera, View
from bayes_brdf.render.environment import EnvironmentLight
from bayes_brdf.render.mesh import Mesh
from bayes_brdf.render.mitsuba_reference import SCENES, render_reference

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.needs_llvm

WHITE = EnvironmentLight(torch.ones(16, 32, 3))
#: a camera above the plane of side 4 that also sees the sky beyond its far edge
SKY_CAMERA = PerspectiveCamera((0.4, -2.2, 1.6), target=(0.0, 0.5, 0.2), up=(0.0, 0.0, 1.0), fov=50.0,
                               resolution=(24, 32))


# ---------------------------------------------------------------------- the BRDF again, in numpy
def brdf_cos(nl, nv, nh, vh, kd, r, ks, eps=1e-8):
    """MaterialGAN's ``f (n.l)`` for unit vectors' cosines (clamped at ``eps``), kd/ks scalars."""
    nl, nv, nh, vh = (np.maximum(c, eps) for c in (nl, nv, nh, vh))
    a = r * r
    a2 = a * a
    d = a2 / (math.pi * (nh * nh * (a2 - 1) + 1) ** 2)
    k = a / 2
    g = nl / (nl * (1 - k) + k) * nv / (nv * (1 - k) + k)
    f = ks + (1 - ks) * 2.0 ** ((-5.55473 * vh - 6.98316) * vh)
    return (kd * (1 - ks) / math.pi + d * f * g / (4 * nl * nv)) * nl


def half_vector_grid(ns=600, nphi=256):
    """Half vectors about ``+z`` with their solid-angle weights: ``theta_h = (pi/2) s^2`` (s midpoints, dense
    at the normal: every lobe down to r = 0.05 resolved) times ``phi`` midpoints."""
    s = (np.arange(ns) + 0.5) / ns
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * math.pi
    th = 0.5 * math.pi * s * s
    w_th = np.sin(th) * math.pi * s / ns            # sin(theta) dtheta/ds ds
    T, P = np.meshgrid(th, phi, indexing="ij")
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    w = (w_th[:, None] * np.full(nphi, 2 * math.pi / nphi)[None]).reshape(-1)
    return h, w, np.repeat(s, nphi)


def white_sky_radiance(nv, kd, r, ks):
    """``int f (n.l) dl`` over the upper hemisphere (normal ``+z``) for a view at cosine ``nv``: by quadrature
    over half vectors (``dl = 4 (v.h) dh``), l = reflect(v, h) kept where it lies above the surface."""
    h, w, _ = half_vector_grid()
    v = np.array([math.sqrt(max(0.0, 1 - nv * nv)), 0.0, nv])
    vh = h @ v
    lo = 2 * vh[:, None] * h - v
    keep = (vh > 0) & (lo[:, 2] > 0)
    val = brdf_cos(lo[:, 2], nv, h[:, 2], vh, kd, r, ks)
    return float((val * 4 * vh * w)[keep].sum())


def sky_table(kd, r, ks, lo_nv, hi_nv, nodes=48):
    xs = np.linspace(lo_nv, hi_nv, nodes)
    return xs, np.array([white_sky_radiance(x, kd, r, ks) for x in xs])


def ground_hits(cam):
    """Per pixel ``(x, y)`` where the pixel-centre ray meets ``z = 0``, and ``n.v`` there (``[H, W]`` each)."""
    o, d = cam.rays(dtype=torch.float64)
    o, d = o.numpy(), d.numpy()
    t = -o[2] / np.where(d[2] < 0, d[2], -1e-30)
    return o[0] + t * d[0], o[1] + t * d[1], -d[2], d[2] < 0


# ---------------------------------------------------------------------- the BSDF's sampling
@pytest.mark.parametrize("r", [0.05, 0.3, 1.0])
def test_bsdf_sample_draws_its_pdf_and_its_weights_integrate_eval(r):
    """For a view 50 degrees off a tilted mapped normal: (1) weight * pdf = eval per sample; (2) the share of
    samples drawn equals the quadrature of ``pdf`` (the GGX lobe loses the half vectors facing away from the
    view), and the histogram of the sampled half vectors' angle from the mapped normal equals ``pdf``'s
    mass per bin; (3) the mean weight equals the quadrature of ``eval`` over the sphere."""
    from bayes_brdf.mitsuba_env import mitsuba_variant
    mesh = Mesh.plane(2.0)
    nmap = np.array([0.15, -0.1, 1.0])
    nw = nmap / np.linalg.norm(nmap)                                       # plane: t = +x, b = +y, n = +z
    maps = SVBRDF.constant(0.2, r, 0.5, normal=tuple(nmap), dtype=torch.float64)
    th = math.radians(50.0)
    e1 = np.cross(nw, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    wi = math.cos(th) * nw + math.sin(th) * e1
    with mitsuba_variant() as mi:
        import drjit as dr
        rs = SCENES.get(mesh, mi.variant())
        rs.set_maps(maps)
        ctx = mi.BSDFContext()

        def interaction(n):
            o = 1.5 * wi + np.array([0.05, -0.03, 0.0])
            ray = mi.Ray3f(mi.Point3f(*(float(x) for x in o)),
                           mi.Vector3f(*(mi.Float(np.full(n, -x, np.float32)) for x in wi)))
            return rs.scene.ray_intersect(ray)

        def world(v):
            return np.stack([np.asarray(v.x), np.asarray(v.y), np.asarray(v.z)], -1).astype(np.float64)

        # what sample draws
        n = 1 << 20
        si = interaction(n)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(3, n)
        bs, weight = rs.bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), si.is_valid())
        value, pdf = rs.bsdf.eval_pdf(ctx, si, bs.wo, si.is_valid())
        lo_s = si.to_world(bs.wo)
        dr.eval(weight, value, pdf, lo_s, bs.pdf)
        w = np.stack([np.asarray(weight[i]) for i in range(3)], -1).astype(np.float64)
        v = np.stack([np.asarray(value[i]) for i in range(3)], -1).astype(np.float64)
        bpdf, epdf = np.asarray(bs.pdf, np.float64), np.asarray(pdf, np.float64)
        lo_s = world(lo_s)
        drawn = bpdf > 0
        assert bool(np.asarray(si.is_valid()).all())

        # eval and pdf on a half-vector grid about the mapped normal (l = reflect(wi, h), dl = 4 (wi.h) dh)
        h0, wq, s_q = half_vector_grid(800, 256)
        e2 = np.cross(nw, e1)
        h = h0[:, :1] * e1 + h0[:, 1:2] * e2 + h0[:, 2:] * nw
        vh = h @ wi
        lo = 2 * vh[:, None] * h - wi
        m = len(lo)
        sq = interaction(m)
        lw = mi.Vector3f(*(mi.Float(np.ascontiguousarray(lo[:, i], np.float32)) for i in range(3)))
        qv, qp = rs.bsdf.eval_pdf(ctx, sq, sq.to_local(lw), sq.is_valid())
        dr.eval(qv, qp)
        qv = np.stack([np.asarray(qv[i]) for i in range(3)], -1).astype(np.float64)
        qp = np.asarray(qp, np.float64)
    jac = np.where(vh > 0, 4 * vh * wq, 0.0)

    # (1) weight * pdf = eval, and pdf(wo) = the sample's pdf
    assert drawn.mean() > 0.5
    assert np.allclose((w * bpdf[:, None])[drawn], v[drawn], rtol=2e-4, atol=1e-7)
    assert np.allclose(epdf[drawn], bpdf[drawn], rtol=1e-4, atol=1e-7)
    # (2) P(a direction is drawn) = int pdf, and the histogram in s = sqrt(2 theta_h / pi) matches pdf's mass
    mass = float((qp * jac).sum())
    assert abs(drawn.mean() - mass) < 3e-3, (drawn.mean(), mass)
    hs = lo_s[drawn] + wi
    hs /= np.linalg.norm(hs, axis=1, keepdims=True)
    s_s = np.sqrt(2 * np.arccos(np.clip(hs @ nw, -1, 1)) / math.pi)
    bins = np.linspace(0, 1, 17)
    got = np.histogram(s_s, bins)[0] / n
    want = np.histogram(s_q, bins, weights=qp * jac)[0]
    sigma = np.sqrt(np.maximum(want, 1e-6) / n)
    assert np.all(np.abs(got - want) < 5 * sigma + 2e-4), np.c_[got, want]
    # (3) mean weight = int eval
    integral = (qv * jac[:, None]).sum(0)
    estimate = w.mean(0)
    print(f"r={r}: drawn {drawn.mean():.4f} / int pdf {mass:.4f}; int eval {integral.round(4)} "
          f"sampled {estimate.round(4)}")
    assert np.allclose(estimate, integral, rtol=0.02)


# ---------------------------------------------------------------------- a white sky on a plane
@pytest.mark.parametrize("r,ks", [(1.0, 0.0), (0.3, 0.1), (0.05, 0.5)])
def test_white_sky_on_a_plane_matches_the_quadrature(r, ks):
    """Under a white constant environment a pixel of an unoccluded plane shows ``int f (n.l) dl``: the
    reference (256 samples) matches the numpy quadrature per pixel within its Monte Carlo noise, and on
    average to well under a percent; pixels off the plane (rays that see the sky) are black."""
    kd = 0.5
    cam = SKY_CAMERA
    maps = SVBRDF.constant(kd, r, ks, dtype=torch.float64)
    img = render_reference(maps, [View(cam, (WHITE,))], Mesh.plane(4.0), spp=256)[0].numpy()
    x, y, nv, down = ground_hits(cam)
    on = down & (np.abs(x) < 1.95) & (np.abs(y) < 1.95)
    off = ~down | (np.abs(x) > 2.05) | (np.abs(y) > 2.05)
    xs, table = sky_table(kd, r, ks, nv[on].min() - 1e-3, nv[on].max() + 1e-3)
    want = np.interp(nv[on], xs, table)
    got = img[on]                                                        # [N, 3], grey
    rel = got / want[:, None] - 1
    print(f"r={r} ks={ks}: want {want.min():.4f}..{want.max():.4f}, mean rel err {rel.mean():+.4f}, "
          f"rms {np.sqrt((rel ** 2).mean()):.4f}")
    assert on.sum() > 300 and off.sum() > 100
    assert abs(rel.mean()) < 0.006
    assert np.sqrt((rel ** 2).mean()) < 0.06
    assert np.abs(rel).max() < 0.3
    assert np.all(img[off] == 0)


# ---------------------------------------------------------------------- shadows: ambient occlusion
def test_block_on_plane_darkens_the_ground_beside_it_and_not_far_away():
    """A box on a wide ground under a white sky: ground pixels beside the box's +x face are darker than the
    unoccluded sky term, the more so the closer (ambient occlusion); far away the ground matches the
    unoccluded quadrature. The two views share the light: its Mitsuba scene is built once."""
    from bayes_brdf.mitsuba_env import mitsuba_variant
    mesh = Mesh.block_on_plane(8.0, (0.5, 0.5, 0.5))
    kd = 0.5
    maps = SVBRDF.constant(kd, 1.0, 0.0, dtype=torch.float64)
    near = PerspectiveCamera((1.6, -0.4, 1.6), target=(0.5, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov=45.0,
                             resolution=40)
    far = PerspectiveCamera((2.8, 2.8, 2.2), target=(2.8, 2.8, 0.0), fov=30.0, resolution=40)
    with mitsuba_variant() as mi:
        builds = SCENES.get(mesh, mi.variant()).env_builds
    img = render_reference(maps, [View(near, (WHITE,)), View(far, (WHITE,))], mesh, spp=256).numpy()
    with mitsuba_variant() as mi:
        assert SCENES.get(mesh, mi.variant()).env_builds == builds + 1       # one envmap scene for both views
    xs, table = sky_table(kd, 1.0, 0.0, 0.2, 1.0, nodes=33)

    # far: the unoccluded quadrature (the box's share of the sky there is ~0.1%)
    x, y, nv, down = ground_hits(far)
    assert down.all() and (np.minimum(x, y) > 2.0).all()
    rel = img[1].mean(-1) / np.interp(nv, xs, table) - 1
    print(f"far from the box: mean rel err {rel.mean():+.4f}, rms {np.sqrt((rel ** 2).mean()):.4f}")
    assert abs(rel.mean()) < 0.006
    assert np.sqrt((rel ** 2).mean()) < 0.06

    # beside the +x face: ground points with x > 0.25 are all seen from this camera (it stands at x > 0.25)
    x, y, nv, down = ground_hits(near)
    ratio = img[0].mean(-1) / np.interp(nv, xs, table)
    beside = down & (np.abs(y) < 0.15)
    bands = [(0.27, 0.35), (0.35, 0.5), (0.5, 0.7), (0.9, 1.3)]
    means = [float(ratio[beside & (x > a) & (x < b)].mean()) for a, b in bands]
    print("ground / unoccluded sky beside the box, by distance:", dict(zip(bands, np.round(means, 3))))
    assert all(int((beside & (x > a) & (x < b)).sum()) >= 4 for a, b in bands)
    assert means[0] < 0.8                                                  # about half the sky is the box
    assert all(m1 < m2 for m1, m2 in zip(means, means[1:]))               # brighter further away
    assert means[-1] < 0.99                                                # still a little occluded at ~1


# ---------------------------------------------------------------------- a sky that varies: the map's orientation
def test_a_varying_sky_on_a_plane_matches_the_quadrature_of_its_radiance():
    """A coloured sky varying in azimuth and elevation, turned by ``z_up(30)``: the reference matches the numpy
    quadrature of ``f (n.l) L(l)`` with ``L`` read by :meth:`EnvironmentLight.eval` (our own reading of
    Mitsuba's envmap), and not the same sky turned half a turn further (the map's orientation reaches Mitsuba)."""
    from bayes_brdf.render.environment import z_up
    h, w = 32, 64
    v, u = torch.meshgrid((torch.arange(h) + 0.0) / (h - 1), (torch.arange(w) + 0.5) / w, indexing="ij")
    rad = torch.stack([0.2 + (1 - v) * (1 + torch.cos(2 * math.pi * u + ph)) for ph in (0.0, 2.0, 4.0)], -1)
    env = EnvironmentLight(rad, scale=1.5, to_world=z_up(30.0))
    kd, r, ks = 0.6, 0.6, 0.2
    cam = PerspectiveCamera((0.3, -1.8, 1.4), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov=50.0,
                            resolution=(12, 16))
    img = render_reference(SVBRDF.constant(kd, r, ks, dtype=torch.float64), [View(cam, (env,))],
                           Mesh.plane(6.0), spp=1024)[0].numpy()
    x, y, nv, down = ground_hits(cam)
    assert down.all() and (np.abs(x) < 2.9).all() and (np.abs(y) < 2.9).all()

    # directions of the upper hemisphere (theta, phi midpoints), the radiance there read once
    nt, nph = 256, 512
    th = (np.arange(nt) + 0.5) / nt * math.pi / 2
    ph = (np.arange(nph) + 0.5) / nph * 2 * math.pi
    T, P = np.meshgrid(th, ph, indexing="ij")
    lo = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    dw = (np.sin(T) * (math.pi / 2 / nt) * (2 * math.pi / nph)).reshape(-1)
    sky = env.eval(torch.from_numpy(lo)).numpy()
    turned = EnvironmentLight(rad, scale=1.5, to_world=z_up(210.0)).eval(torch.from_numpy(lo)).numpy()
    o, d = cam.rays(dtype=torch.float64)
    view_dirs = -d.numpy().reshape(3, -1).T                               # towards the camera
    want, wrong = [], []
    for vd in view_dirs:
        hh = lo + vd
        hh /= np.linalg.norm(hh, axis=1, keepdims=True)
        f = brdf_cos(lo[:, 2], vd[2], hh[:, 2], hh @ vd, kd, r, ks) * dw
        want.append(f @ sky)
        wrong.append(f @ turned)
    want, wrong = np.array(want).reshape(*img.shape), np.array(wrong).reshape(*img.shape)
    rel = img / want - 1
    print(f"varying sky: mean rel err {rel.mean():+.4f}, rms {np.sqrt((rel ** 2).mean()):.4f}; "
          f"the sky turned by 180 degrees off by {np.abs(wrong / want - 1).mean():.3f}")
    assert abs(rel.mean()) < 0.01
    assert np.sqrt((rel ** 2).mean()) < 0.05
    assert np.abs(wrong / want - 1).mean() > 0.1
    assert np.abs(img / wrong - 1).mean() > 3 * np.abs(rel).mean()


# ---------------------------------------------------------------------- passes, cameras
def test_a_view_with_a_point_light_and_the_sky_is_the_sum_of_its_passes():
    """Point lights keep their exact one-sample passes next to an environment pass: a view with both equals
    the point light's view plus the sky's (the same seed: the same samples), to float32 rounding."""
    from bayes_brdf.render import PointLight
    cam = PerspectiveCamera((0.4, -2.2, 1.6), up=(0.0, 0.0, 1.0), fov=40.0, resolution=16)
    maps, mesh = SVBRDF.constant(0.5, 0.4, 0.1, dtype=torch.float64), Mesh.plane(4.0)
    lamp = PointLight((1.0, 0.5, 2.0), 6.0)
    both = render_reference(maps, [View(cam, (lamp, WHITE))], mesh, spp=32, seed=5)
    lamp_only = render_reference(maps, [View(cam, (lamp,))], mesh, spp=32, seed=5)
    sky_only = render_reference(maps, [View(cam, (WHITE,))], mesh, spp=32, seed=5)
    assert float(lamp_only.amax()) > 0.1 and float(sky_only.amax()) > 0.1
    assert torch.allclose(both, lamp_only + sky_only, rtol=1e-12, atol=1e-12)
    again = render_reference(maps, [View(cam, (WHITE,))], mesh, spp=32, seed=6)
    assert float((again - sky_only).abs().max()) > 1e-3                  # another seed, other samples


def test_the_sensor_camera_renders_the_sky_too():
    """``camera="sensor"`` (Mitsuba's perspective camera, pixel areas, Mitsuba's spp) under the white sky:
    on average the unoccluded quadrature on the plane, black off it."""
    kd = 0.5
    cam = SKY_CAMERA
    img = render_reference(SVBRDF.constant(kd, 1.0, 0.0, dtype=torch.float64), [View(cam, (WHITE,))],
                           Mesh.plane(4.0), camera="sensor", spp=256)[0].numpy()
    x, y, nv, down = ground_hits(cam)
    on = down & (np.abs(x) < 1.9) & (np.abs(y) < 1.9)
    hit = down & (np.abs(x) < 2.0) & (np.abs(y) < 2.0)
    near_hit = np.pad(hit, 1)
    near_hit = np.any([near_hit[1 + i:near_hit.shape[0] - 1 + i, 1 + j:near_hit.shape[1] - 1 + j]
                       for i in (-1, 0, 1) for j in (-1, 0, 1)], 0)
    off = ~near_hit                                                      # no part of the pixel sees the plane
    xs, table = sky_table(kd, 1.0, 0.0, nv[on].min() - 1e-2, nv[on].max() + 1e-2)
    rel = img[on].mean(-1) / np.interp(nv[on], xs, table) - 1
    print(f"sensor: mean rel err {rel.mean():+.4f}, rms {np.sqrt((rel ** 2).mean()):.4f}")
    assert abs(rel.mean()) < 0.006
    assert np.sqrt((rel ** 2).mean()) < 0.06
    assert off.sum() > 50
    assert np.all(img[off] == 0)
