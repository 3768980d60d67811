"""The executor seam (bayes_brdf.executor): the same results in order, serial and on a local Ray of 2 CPUs."""
from __future__ import annotations

import sys

import pytest
import torch

from bayes_brdf.errors import InputError
from bayes_brdf.executor import RayExecutor, SerialExecutor, make_executor, score_candidates, using


def noisy(item, shared=None):
    """Reads the global generators (seeded per item by the executor) and the shared object."""
    return item * (shared or 1) + float(torch.rand(()))


def fails(item):
    if item == 1:
        raise InputError("item 1 is bad", fix="leave it out")
    return item


def test_serial_is_in_order_seeded_per_item_and_leaves_the_global_state_alone():
    ex = SerialExecutor()
    state = torch.get_rng_state()
    a = ex.map(noisy, [3, 1, 2], shared=10)
    assert torch.equal(torch.get_rng_state(), state)
    assert [round(x) // 10 for x in a] == [3, 1, 2]
    assert a == ex.map(noisy, [3, 1, 2], shared=10)                       # repeatable
    assert ex.map(noisy, [3, 1, 2], shared=10, seeds=[5, 6, 7]) != a     # the seeds are the items'
    assert ex.map(noisy, [], shared=1) == []
    with pytest.raises(InputError, match="item 1"):
        ex.map(fails, [0, 1, 2])


def test_ray_gives_the_serial_numbers(ray_local):
    with RayExecutor() as ex:
        assert ex.workers == 2
        assert ex.map(noisy, [3, 1, 2], shared=10) == SerialExecutor().map(noisy, [3, 1, 2], shared=10)
        assert ex.map(noisy, [4, 5], seeds=[9, 8]) == SerialExecutor().map(noisy, [4, 5], seeds=[9, 8])
        with pytest.raises(InputError, match="item 1 is bad; leave it out"):     # the original error
            ex.map(fails, [0, 1, 2])
    assert ray_local.is_initialized()          # the session's Ray is left running


def test_a_tiny_compare_is_the_same_serial_and_on_ray(ray_local):
    from bayes_brdf.experiments.table1 import Table1Setup, compare

    kw = dict(runs=3, particles=6, steps=40, seed=2)
    setup = Table1Setup(grid=150)
    names = ["spos", "emcee"]                   # a batched sampler (one piece) and an unbatched one (a piece a run)
    serial = compare(setup, names, **kw)
    ray = compare(setup, names, executor=True, **kw)
    for row in ("iid", *names):
        for col in ("mse_mean", "mse_var", "evaluations"):
            assert ray[row][col] == serial[row][col], (row, col)


def test_candidate_shards_score_as_one_call_and_the_same_on_ray(ray_local):
    from bayes_brdf.guidance.scores import score_views
    from bayes_brdf.render import SVBRDF, PlanarSample, collocated_views

    g = torch.Generator().manual_seed(0)
    maps = SVBRDF(torch.rand(6, 3, 8, 8, generator=g), torch.rand(6, 1, 8, 8, generator=g) * .5 + .2,
                  torch.full((3, 1, 1), .04), torch.tensor([0., 0, 1]).view(3, 1, 1))
    cands, surf = collocated_views(11, 3.0, camera="rectified", resolution=8), PlanarSample(2.0)
    whole = score_views(maps, cands, surf, seed=3)
    serial = score_candidates(maps, cands, surf, shard_size=4, seed=3)
    torch.testing.assert_close(serial.mi, whole.mi, rtol=1e-6, atol=1e-9)
    assert torch.equal(serial.pixels, whole.pixels)
    on_ray = score_candidates(maps, cands, surf, shard_size=4, seed=3, executor=True)
    assert torch.equal(on_ray.mi, serial.mi) and torch.equal(on_ray.mean_std, serial.mean_std)


def test_without_ray_the_choice_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)          # import ray -> ImportError
    assert isinstance(make_executor(None), SerialExecutor) and isinstance(make_executor(False), SerialExecutor)
    for choice, opt in ((True, "--ray"), ("10.0.0.1:6379", "--ray-address")):
        with pytest.raises(InputError, match=rf"{opt} needs Ray.*pip install 'bayes-brdf\[ray\]'"):
            make_executor(choice)
    with pytest.raises(InputError, match="executor=True needs Ray"):
        with using(True):
            pass
