"""G-buffer geometry: analytic formulas, Mitsuba's ray casting, and the pixel->texel footprint."""
import math

import numpy as np
import pytest
import torch

from bayes_brdf.render import PerspectiveCamera, PlanarSample, PointLight, RectifiedCamera, View
from bayes_brdf.render.gbuffer import GBuffer, GBufferCache


def test_rectified_positions_follow_materialgan_texel_centres():
    res, size = 8, 6.848
    g = GBuffer.build([View.collocated(RectifiedCamera((1.0, 0.3, 16.7), res), 1500.0)], PlanarSample(size),
                      dtype=torch.float64)
    x = ((np.arange(res) + 0.5) / res - 0.5) * size
    np.testing.assert_allclose(g.position[0, 0].numpy(), np.tile(x, (res, 1)))
    np.testing.assert_allclose(g.position[0, 1].numpy(), np.tile(-x[:, None], (1, res)))  # row 0 at +y
    assert torch.all(g.position[0, 2] == 0) and g.mask.all() and g.aligned


def test_directions_distances_and_light_scale():
    light = PointLight((2.0, -1.0, 5.0), (10.0, 20.0, 30.0))
    g = GBuffer.build([View(RectifiedCamera((0.0, 1.0, 4.0), 5), (light, PointLight((0, 0, 3.0), 7.0, falloff=False)))],
                      PlanarSample(2.0), dtype=torch.float64)
    for t in (g.view_dir, g.light_dir[:, 0], g.light_dir[:, 1]):
        torch.testing.assert_close(t.norm(dim=1), torch.ones(1, 5, 5, dtype=torch.float64))
    p = g.position[0]
    d2 = ((torch.tensor(light.position, dtype=torch.float64)[:, None, None] - p) ** 2).sum(0)
    torch.testing.assert_close(g.light_dist2[0, 0, 0], d2)
    torch.testing.assert_close(g.light_scale[0, 0], torch.tensor(light.power, dtype=torch.float64)[:, None, None] / d2)
    assert torch.all(g.light_scale[0, 1] == 7.0)  # directions only: no falloff


def test_perspective_camera_looks_at_target_with_image_conventions():
    cam = PerspectiveCamera((0.0, 0.0, 3.0), fov=60, resolution=(9, 9))
    o, d = cam.rays(dtype=torch.float64)
    torch.testing.assert_close(d[:, 4, 4], torch.tensor([0.0, 0, -1], dtype=torch.float64))
    assert d[0, 4, 8] > 0 and d[1, 0, 4] > 0  # column increases to +x (right), row 0 is up (+y)
    # the edge pixel centre sits half a pixel inside the field of view
    angle = math.degrees(math.atan2(-float(d[0, 4, 0]), -float(d[2, 4, 0])))
    assert angle == pytest.approx(math.degrees(math.atan((1 - 1 / 9) * math.tan(math.radians(30)))))


@pytest.fixture(scope="module")
def mitsuba():
    mi = pytest.importorskip("mitsuba")
    try:
        mi.set_variant("scalar_rgb")
    except Exception as e:  # pragma: no cover
        pytest.skip(f"mitsuba scalar_rgb unavailable: {e}")
    return mi


def test_perspective_hits_match_mitsuba_ray_casting(mitsuba):
    """Our analytic plane hits vs Mitsuba's own camera rays intersected with a rectangle mesh."""
    mi = mitsuba
    cam = PerspectiveCamera((0.7, -2.0, 2.5), target=(0.1, 0.2, 0.0), up=(0, 0, 1), fov=50, resolution=(12, 16))
    g = GBuffer.build([View.collocated(cam)], PlanarSample(2.0), dtype=torch.float64)
    scene = mi.load_dict({
        "type": "scene",
        "rect": {"type": "rectangle"},  # [-1, 1]^2 on z = 0, normal +z
        "sensor": {"type": "perspective", "fov": cam.fov, "fov_axis": "x",
                   "to_world": mi.ScalarTransform4f().look_at(origin=cam.position, target=cam.target, up=cam.up),
                   "film": {"type": "hdrfilm", "width": cam.resolution[1], "height": cam.resolution[0]}},
    })
    sensor = scene.sensors()[0]
    h, w = cam.resolution
    hit = np.zeros((h, w), bool)
    pos = np.zeros((3, h, w))
    for i in range(h):
        for j in range(w):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((j + 0.5) / w, (i + 0.5) / h), mi.Point2f(0.5, 0.5))
            si = scene.ray_intersect(ray)
            hit[i, j] = bool(si.is_valid())
            if hit[i, j]:
                pos[:, i, j] = np.array(si.p)
    inner = hit & g.mask[0].numpy()
    assert (hit != g.mask[0].numpy()).sum() <= 2  # only grazing edge pixels may disagree
    assert inner.sum() > 50
    np.testing.assert_allclose(g.position[0].numpy()[:, inner], pos[:, inner], atol=1e-4)


def test_footprint_one_pixel_per_texel():
    res = 4
    # a high-resolution rectified view: 4x4 pixels per texel of a 4x4 map
    g = GBuffer.build([View.collocated(RectifiedCamera((0, 0, 5.0), 16))], PlanarSample(2.0))
    idx = g.texel_index(res)[0]
    assert idx.min() == 0 and idx.max() == res * res - 1
    assert torch.all(torch.bincount(idx.reshape(-1)) == 16)
    keep = g.unique_pixel_mask(res)
    assert keep.sum() == res * res
    assert torch.equal(torch.sort(idx[keep[0]]).values, torch.arange(res * res))
    # at equal resolution every pixel is its own texel
    assert g.unique_pixel_mask(16).all()


def test_footprint_ignores_pixels_off_the_sample():
    g = GBuffer.build([View.collocated(PerspectiveCamera((0, 0, 3.0), fov=90, resolution=(20, 20)))], PlanarSample(1.0))
    idx = g.texel_index(8)
    assert torch.all(idx[~g.mask] == -1)
    keep = g.unique_pixel_mask(8)
    assert not keep[~g.mask].any()
    assert keep.sum() == len(torch.unique(idx[g.mask]))


def test_cache_returns_same_gbuffer_and_builds_once():
    cache = GBufferCache()
    vs = (View.collocated(RectifiedCamera((0, 0, 5.0), 4)),)
    a = cache.get(vs, PlanarSample())
    assert cache.get(vs, PlanarSample()) is a
    assert cache.get(vs, PlanarSample(), dtype=torch.float64) is not a


def test_camera_below_the_sample_sees_nothing():
    g = GBuffer.build([View.collocated(PerspectiveCamera((0, 0, -3.0), resolution=(4, 4)))], PlanarSample())
    assert not g.mask.any()


def test_gbuffer_cache_stays_within_its_byte_budget():
    from bayes_brdf.render.gbuffer import GBufferCache
    from bayes_brdf.render.views import collocated_views

    S = PlanarSample(2.0)
    sets = [tuple(collocated_views(2, 3.0, resolution=16, seed=i, method="random")) for i in range(4)]
    one = GBuffer.build(list(sets[0]), S).nbytes
    assert one >= 2 * GBuffer.bytes_per_view(sets[0][0]) * 0.9      # the planning estimate is close
    cache = GBufferCache(max_entries=10, max_bytes=int(2.5 * one))
    for vs in sets:
        cache.get(vs, S)
    assert cache.nbytes <= 2.5 * one and len(cache._store) == 2     # the two most recent are kept
    assert cache.get(sets[3], S) is cache.get(sets[3], S)
    big = tuple(collocated_views(6, 3.0, resolution=16))
    g = cache.get(big, S)                                            # alone over the budget: returned, not kept
    assert g.num_views == 6 and cache.get(big, S) is not g and cache.nbytes <= 2.5 * one
