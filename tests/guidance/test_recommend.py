"""Recommendations: greedy top-K with hypersphere exclusion, MI / std / Sobol / random picks, bad input."""
import math

import numpy as np
import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.guidance.recommend import configuration, distances, low_discrepancy, recommend, top_k
from bayes_brdf.guidance.scores import score_views
from bayes_brdf.render import SVBRDF, PlanarSample
from bayes_brdf.render.views import collocated_views, hemisphere_directions, light_stage_views

S = PlanarSample(2.0)
R = 8


def _maps(n=6, seed=0):
    g = torch.Generator().manual_seed(seed)
    return SVBRDF(torch.rand(n, 3, R, R, generator=g) * 0.8 + 0.1, torch.rand(n, 1, R, R, generator=g) * 0.5 + 0.2,
                  torch.full((3, 1, 1), 0.04), torch.tensor([0.0, 0, 1]).view(3, 1, 1))


def _cands(n=40, **kw):
    return collocated_views(n, 3.0, camera="rectified", resolution=R, power=10.0, max_zenith=60, **kw)


def _cam_dirs(views):
    p = np.array([v.camera.position for v in views], dtype=np.float64)
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _angle_deg(a, b):
    return math.degrees(math.acos(float(np.clip(a @ b, -1, 1))))


def _greedy_reference(values, views, k, radius, exclude=()):
    """Pick the best remaining view, then drop every view within `radius` degrees of it (angle between the
    camera directions: collocated views have light = camera)."""
    d = _cam_dirs(views)
    alive = [i for i in range(len(views)) if i not in set(exclude)]
    out = []
    while alive and len(out) < k:
        i = max(alive, key=lambda j: float(values[j]))
        out.append(i)
        alive = [j for j in alive if j != i and _angle_deg(d[i], d[j]) >= radius]
    return out


def test_configuration_and_distances_for_collocated_views():
    views = _cands(12)
    conf = configuration(views)
    d = _cam_dirs(views)
    np.testing.assert_allclose(conf[:, :3].numpy(), d, atol=1e-12)
    np.testing.assert_allclose(conf[:, 3:].numpy(), d, atol=1e-12)   # the flash sits at the camera
    ref = np.linalg.norm(d[:, None] - d[None], axis=-1)                  # RMS of two equal chords = the chord
    np.testing.assert_allclose(distances(views, views).numpy(), ref, atol=1e-6)


def test_top_k_without_radius_is_argsort():
    views = _cands(30)
    vals = torch.randn(30, generator=torch.Generator().manual_seed(0))
    for k in (1, 5, 30):
        assert top_k(vals, views, k) == torch.argsort(vals, descending=True)[:k].tolist()
    assert top_k(vals, views, 50) == torch.argsort(vals, descending=True).tolist()   # at most all of them


@pytest.mark.parametrize("radius", [10.0, 25.0])
def test_top_k_with_radius_keeps_picks_apart_and_respects_exclusion(radius):
    views = _cands(80)
    vals = torch.rand(80, generator=torch.Generator().manual_seed(int(radius)))
    exclude = torch.argsort(vals, descending=True)[:3].tolist()          # the three best are taken already
    picks = top_k(vals, views, 6, radius, exclude=exclude)
    assert picks == _greedy_reference(vals, views, 6, radius, exclude)
    assert not set(picks) & set(exclude) and len(set(picks)) == len(picks)
    d = _cam_dirs(views)
    chord = 2 * math.sin(math.radians(radius) / 2)
    for a in range(len(picks)):
        for b in range(a):
            assert np.linalg.norm(d[picks[a]] - d[picks[b]]) >= chord - 1e-12
            assert _angle_deg(d[picks[a]], d[picks[b]]) >= radius - 1e-6
    # a radius covering the whole hemisphere leaves one pick
    assert top_k(vals, views, 6, 179.0) == [int(torch.argmax(vals))]


def test_top_k_returns_fewer_when_exclusion_leaves_none():
    views = _cands(5)
    vals = torch.arange(5.0)
    assert top_k(vals, views, 4, exclude=[4, 1, 2]) == [3, 0]
    assert top_k(vals, views, 3, exclude=range(5)) == []


def test_mi_recommendation_is_the_argmax_of_the_scores():
    maps, views = _maps(), _cands(30)
    s = score_views(maps, views, S, seed=3)                                  # default estimator (MC), seed 3
    rec = recommend(maps, views, 1, surface=S, seed=3)
    assert rec.method == "mi" and rec.indices == [int(torch.argmax(s.mi))]   # Algorithm 1's greedy step
    torch.testing.assert_close(rec.scores.mi, s.mi)
    assert rec.views == [views[rec.indices[0]]]
    # a batch with exclusion follows the greedy reference on the same scores
    rec5 = recommend(maps, views, 5, radius=20, surface=S, seed=3, exclude=[rec.indices[0]])
    assert rec5.indices == _greedy_reference(s.mi, views, 5, 20.0, [rec.indices[0]])
    # the quadrature estimator is passed through to the scores
    q = score_views(maps, views, S, estimator="quadrature")
    recq = recommend(maps, views, 3, surface=S, estimator="quadrature")
    assert recq.indices == torch.argsort(q.mi, descending=True)[:3].tolist()
    d = recq.to_dict()
    assert d["picked_mi"] == pytest.approx([float(q.mi[i]) for i in recq.indices])
    # reusing precomputed scores skips rendering and gives the same picks
    assert recommend(None, views, 3, scores=q).indices == recq.indices


def test_std_recommendation_ranks_by_mean_std():
    maps, views = _maps(), _cands(30)
    s = score_views(maps, views, S)
    rec = recommend(maps, views, 4, method="std", surface=S)
    assert rec.indices == torch.argsort(s.mean_std, descending=True)[:4].tolist()


def test_sobol_is_deterministic_nested_and_maps_to_the_nearest_camera():
    views = _cands(200)
    a = recommend(None, views, 10, method="sobol", seed=2).indices
    assert a == recommend(None, views, 10, method="sobol", seed=2).indices
    assert a != recommend(None, views, 10, method="sobol", seed=3).indices
    first = recommend(None, views, 5, method="sobol", seed=2).indices
    nxt = recommend(None, views, 5, method="sobol", seed=2, offset=5, exclude=first).indices
    assert first + nxt == a                                              # offset continues one sequence
    nxt_free = low_discrepancy(views, 5, seed=2, offset=5)                # without exclusion: same set here
    assert set(first) | set(nxt_free) == set(a)
    # each pick is the candidate camera nearest to the next point of the scrambled Sobol sequence,
    # mapped uniformly in solid angle over the candidates' zenith range
    d = _cam_dirs(views)
    pts = torch.quasirandom.SobolEngine(2, scramble=True, seed=2).draw(10, dtype=torch.float64).numpy()
    cmin = d[:, 2].min()
    cos_t = 1 - pts[:, 0] * (1 - cmin)
    sin_t = np.sqrt(1 - cos_t ** 2)
    dirs = np.stack([sin_t * np.cos(2 * np.pi * pts[:, 1]), sin_t * np.sin(2 * np.pi * pts[:, 1]), cos_t], -1)
    nearest = [int(np.argmin(np.linalg.norm(d - p, axis=1))) for p in dirs]
    assert len(set(nearest)) == 10                                       # no collisions on 200 candidates
    assert a == nearest


def test_fibonacci_baseline_maps_a_spiral_of_k_points_to_the_nearest_cameras():
    views = _cands(200)
    k = 7
    picks = recommend(None, views, k, method="fibonacci").indices
    d = _cam_dirs(views)
    i = np.arange(k)
    u, v = (i + 0.5) / k, (i * (math.sqrt(5) - 1) / 2) % 1.0
    cos_t = 1 - u * (1 - d[:, 2].min())
    sin_t = np.sqrt(1 - cos_t ** 2)
    dirs = np.stack([sin_t * np.cos(2 * np.pi * v), sin_t * np.sin(2 * np.pi * v), cos_t], -1)
    assert picks == [int(np.argmin(np.linalg.norm(d - p, axis=1))) for p in dirs]
    # not a sequence: offset and seed do not change it
    assert recommend(None, views, k, method="fibonacci", offset=5, seed=3).indices == picks


def _min_pairwise(d):
    D = np.linalg.norm(d[:, None] - d[None], axis=-1)
    return D[~np.eye(len(d), dtype=bool)].min()


def test_sobol_spreads_out_more_than_random():
    views = _cands(200)
    d = _cam_dirs(views)
    sob = [_min_pairwise(d[recommend(None, views, 8, method="sobol", seed=s).indices]) for s in range(20)]
    rnd = [_min_pairwise(d[recommend(None, views, 8, method="random", seed=s).indices]) for s in range(20)]
    assert np.mean(sob) > 1.5 * np.mean(rnd)
    # random picks: deterministic per seed, never excluded, never repeated
    r = recommend(None, views, 50, method="random", seed=1, exclude=range(100)).indices
    assert r == recommend(None, views, 50, method="random", seed=1, exclude=range(100)).indices
    assert len(set(r)) == 50 and min(r) >= 100


def test_sobol_on_light_stage_picks_a_camera_then_a_random_light():
    cams, lights = hemisphere_directions(6, max_zenith=60), hemisphere_directions(4, "sobol", seed=1)
    views = light_stage_views(cams, lights, 3.0, 5.0, camera="rectified", resolution=R, power=10.0)
    cam_dirs = cams.numpy()
    light_used = set()
    for seed in range(12):
        picks = recommend(None, views, 4, method="sobol", seed=seed).indices
        assert picks == recommend(None, views, 4, method="sobol", seed=seed).indices
        assert len(set(picks)) == 4
        pts = torch.quasirandom.SobolEngine(2, scramble=True, seed=seed).draw(4, dtype=torch.float64).numpy()
        cmin = cam_dirs[:, 2].min()
        cos_t = 1 - pts[:, 0] * (1 - cmin)
        sin_t = np.sqrt(1 - cos_t ** 2)
        dirs = np.stack([sin_t * np.cos(2 * np.pi * pts[:, 1]), sin_t * np.sin(2 * np.pi * pts[:, 1]), cos_t], -1)
        for p, i in zip(dirs, picks):                                   # k <= lights: no camera runs out
            assert i // 4 == int(np.argmin(np.linalg.norm(cam_dirs - p, axis=1)))
            light_used.add(i % 4)
    assert light_used == {0, 1, 2, 3}                                    # the light is drawn, not fixed


def test_bad_arguments_raise_input_error():
    views = _cands(5)
    with pytest.raises(InputError, match="unknown recommendation method"):
        recommend(None, views, 1, method="entropy")
    with pytest.raises(InputError, match="k must be"):
        recommend(None, views, 0, method="sobol")
    with pytest.raises(InputError, match="radius"):
        recommend(None, views, 1, method="sobol", radius=-1)
