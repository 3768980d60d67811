"""Whole-image shading against the numpy reference, and the batching contract."""
import numpy as np
import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.render import SVBRDF, PerspectiveCamera, PlanarSample, PointLight, RectifiedCamera, View
from bayes_brdf.render.gbuffer import GBuffer
from bayes_brdf.render.shade import Renderer, render, shade

from . import numpy_reference as ref

RES, SIZE = 6, 9.7


def random_maps(n, res=RES, seed=0, dtype=torch.float64, normals=True):
    g = torch.Generator().manual_seed(seed)
    u = lambda *s: torch.rand(*s, generator=g, dtype=dtype)  # noqa: E731
    nrm = torch.cat([0.4 * (u(n, 2, res, res) - 0.5), torch.ones(n, 1, res, res, dtype=dtype)], 1) if normals else \
        torch.tensor([0.0, 0, 1], dtype=dtype)[None, :, None, None].expand(n, 3, res, res)
    return SVBRDF(u(n, 3, res, res), 0.05 + 0.95 * u(n, 1, res, res), 0.5 * u(n, 3, res, res), nrm / nrm.norm(dim=1, keepdim=True))


def np_maps(m, i):
    cl = lambda t: (t[i] if t.dim() == 4 else t).movedim(0, -1).numpy()  # noqa: E731
    return cl(m.albedo), cl(m.roughness)[..., 0], cl(m.specular), cl(m.normal)


VIEWS = [
    View(RectifiedCamera((1.0, 0.3, 16.7), RES), (PointLight((1.0, 0.3, 16.7), (1500, 1400, 1300)),)),
    View(RectifiedCamera((-3.0, 2.0, 10.0), RES), (PointLight((4.0, -1.0, 12.0), 800),)),
    View(RectifiedCamera((0.0, 0.0, 12.0), RES),
         (PointLight((5.0, 0.0, 5.0), 300), PointLight((-2.0, -3.0, 8.0), (100, 200, 300), falloff=False))),
]


@pytest.mark.parametrize("ks_factor", [True, False])
def test_rectified_views_match_numpy_reference(ks_factor):
    maps = random_maps(2)
    img = render(maps, VIEWS, PlanarSample(SIZE), ks_factor=ks_factor, backend="eager")
    assert img.shape == (2, len(VIEWS), RES, RES, 3)
    for p in range(2):
        for v, view in enumerate(VIEWS):
            lights = [(l.position, l.power, l.falloff) for l in view.lights]
            want = ref.render_rectified(*np_maps(maps, p), SIZE, view.camera.position, lights, ks_factor)
            np.testing.assert_allclose(img[p, v].numpy(), want, rtol=1e-9, atol=1e-12)


def test_fixed_maps_broadcast_over_particles():
    maps = random_maps(3)
    fixed = SVBRDF(maps.albedo, maps.roughness, maps.specular[0], maps.normal[1])  # specular + normal held fixed
    full = SVBRDF(maps.albedo, maps.roughness, maps.specular[0:1].expand(3, -1, -1, -1), maps.normal[1:2].expand(3, -1, -1, -1))
    a = render(fixed, VIEWS, PlanarSample(SIZE))
    b = render(full, VIEWS, PlanarSample(SIZE))
    assert a.shape == b.shape == (3, len(VIEWS), RES, RES, 3)
    torch.testing.assert_close(a, b, rtol=1e-12, atol=0)


def test_constant_maps_equal_uniform_maps():
    c = SVBRDF.constant((0.6, 0.5, 0.4), 0.35, 0.04, dtype=torch.float64)
    u = SVBRDF(*(t.expand(-1, RES, RES) for _, t in c.items()))
    torch.testing.assert_close(render(c, VIEWS, PlanarSample(SIZE)), render(u, VIEWS, PlanarSample(SIZE)))


def test_chunking_over_views_changes_nothing():
    maps = random_maps(2)
    g = GBuffer.build(VIEWS, PlanarSample(SIZE), dtype=torch.float64)
    torch.testing.assert_close(shade(maps, g, chunk_views=1), shade(maps, g), rtol=0, atol=0)


def test_aligned_fast_path_equals_bilinear_lookup():
    """Rectified views skip the texture lookup; forcing grid_sample must give the same image."""
    for grid in ("centers", "endpoints"):
        maps = random_maps(2)
        g = GBuffer.build(VIEWS, PlanarSample(SIZE, grid), dtype=torch.float64)
        fast = shade(maps, g)
        g.aligned = False
        torch.testing.assert_close(shade(maps, g), fast, rtol=1e-12, atol=1e-12)


def test_perspective_view_pixels_outside_sample_are_zero_and_inside_match_reference():
    cam = PerspectiveCamera((0.0, -3.0, 4.0), fov=70, resolution=(24, 32))
    view = View.collocated(cam, power=(10.0, 10.0, 10.0))
    surf = PlanarSample(2.0)
    g = GBuffer.build([view], surf, dtype=torch.float64)
    assert 0 < g.mask.float().mean() < 1  # the wide view sees the sample and beyond
    c = SVBRDF.constant((0.3, 0.5, 0.7), 0.4, 0.04, dtype=torch.float64)
    img = shade(c, g)[0, 0]
    assert torch.all(img[~g.mask[0]] == 0)
    # every valid pixel: the reference BRDF at that pixel's position
    pos = g.position[0].permute(1, 2, 0).numpy()
    ii, jj = np.nonzero(g.mask[0].numpy())
    for i, j in list(zip(ii, jj))[::17]:
        p = pos[i, j]
        lv = np.array(cam.position) - p
        d2 = lv @ lv
        f, nl = ref.brdf(np.array([0.3, 0.5, 0.7]), 0.4, np.full(3, 0.04), np.array([0, 0, 1.0]), lv / np.sqrt(d2), lv / np.sqrt(d2))
        np.testing.assert_allclose(img[i, j].numpy(), f * nl * 10 / d2, rtol=1e-9)


def test_renderer_float32_matches_float64():
    maps = random_maps(2)
    r64 = Renderer(VIEWS, PlanarSample(SIZE), dtype=torch.float64)(maps)
    r32 = Renderer(VIEWS, PlanarSample(SIZE))(maps.to(torch.float32))
    assert r32.dtype == torch.float32
    torch.testing.assert_close(r32.double(), r64, rtol=1e-4, atol=1e-6)


def test_views_of_different_resolutions_are_rejected():
    vs = [View.collocated(RectifiedCamera((0, 0, 5.0), 4)), View.collocated(RectifiedCamera((0, 0, 5.0), 8))]
    with pytest.raises(InputError, match="different resolutions"):
        GBuffer.build(vs, PlanarSample())


def test_bad_map_shape_is_one_line_error():
    with pytest.raises(InputError, match="roughness"):
        SVBRDF(torch.rand(3, 4, 4), torch.rand(4, 4, 1), torch.rand(3, 4, 4), torch.rand(3, 4, 4))


def test_mesh_loss_compacts_its_photos_once_for_a_number_weight():
    """The gathered (mesh) path keeps the photos at its compacted pixels while the same target and weight come
    again, also for a weight given as a number (a new tensor of it each call used to mean a new copy per call)."""
    from bayes_brdf.render import collocated_views
    from bayes_brdf.render.mesh import Mesh
    from bayes_brdf.render.shade import shade_loss

    mesh = Mesh.sphere()
    views = collocated_views(2, 3 * mesh.radius, resolution=16, target=mesh.center, fov=45)
    g = GBuffer.build(views, mesh)
    maps = SVBRDF.constant(0.5, 0.4, dtype=torch.float64)
    target = shade(maps, g)[0] * 1.1
    first = shade_loss(maps, g, target, 2.0)
    kept = g.__dict__["_compact_data"][2][0]
    again = shade_loss(maps, g, target, 2.0)
    assert g.__dict__["_compact_data"][2][0] is kept and torch.equal(first, again)
    other = shade_loss(maps, g, target, 3.0)                  # another value: made again, and 1.5x the loss
    assert g.__dict__["_compact_data"][2][0] is not kept
    torch.testing.assert_close(other, 1.5 * first)
