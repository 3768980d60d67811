"""Guided acquisition (Algorithm 1): capture callbacks, per-round files, growth of the view set, resume."""
import json
import math

import pytest
import torch

import bayes_brdf as bb
import bayes_brdf.inference
from bayes_brdf.errors import InputError
from bayes_brdf.guidance import Evaluation, PoolCapture, SyntheticCapture, guided_acquisition
from bayes_brdf.posterior import Posterior
from bayes_brdf.render import SVBRDF, PlanarSample
from bayes_brdf.render.shade import render
from bayes_brdf.render.views import collocated_views

S = PlanarSample(2.0)
R = 8


def _truth():
    g = torch.Generator().manual_seed(0)
    return SVBRDF(torch.rand(3, R, R, generator=g) * 0.8 + 0.1, torch.rand(1, R, R, generator=g) * 0.5 + 0.2,
                  torch.full((3, 1, 1), 0.04), torch.tensor([0.0, 0, 1]).view(3, 1, 1))


def _cands(n=30, res=R):
    return collocated_views(n, 3.0, camera="rectified", resolution=res, power=10.0, max_zenith=60)


def test_synthetic_capture_is_the_render_and_noise_is_per_view_and_scaled():
    truth = _truth()
    views = _cands(6, res=32)
    clean = render(truth, views, S)[0]
    obs = SyntheticCapture(truth, S)(views)
    torch.testing.assert_close(obs.images, clean.float())
    assert obs.views == views and obs.surface == S
    b = 0.02
    cap = SyntheticCapture(truth, S, noise_sigma=b, seed=1)
    a = cap(views).images
    # the same view gives the same image (same noise), alone or in another batch, in any order
    # (float32 rendering of a different batch may differ in the last bit: 1e-6 << the noise 0.02)
    torch.testing.assert_close(cap([views[3]]).images[0], a[3], rtol=0, atol=1e-6)
    torch.testing.assert_close(cap(views[::-1]).images, a.flip(0), rtol=0, atol=1e-6)
    torch.testing.assert_close(cap(views).images, a, rtol=0, atol=0)
    # different views get different noise; another seed other noise
    e = (a - clean).double()
    assert not torch.allclose(e[0], e[1])
    assert not torch.equal(SyntheticCapture(truth, S, noise_sigma=b, seed=2)(views).images, a)
    # Laplace(0, b): mean 0, std b sqrt(2), mean |e| = b (a Gaussian of that std would have 0.8 b sqrt 2)
    assert abs(float(e.mean())) < 0.05 * b
    assert float(e.std()) == pytest.approx(b * math.sqrt(2), rel=0.05)
    assert float(e.abs().mean()) == pytest.approx(b, rel=0.05)
    eg = (SyntheticCapture(truth, S, noise_sigma=b, noise="gaussian")(views).images - clean).double()
    assert float(eg.std()) == pytest.approx(b, rel=0.05)
    assert float(eg.abs().mean()) == pytest.approx(b * math.sqrt(2 / math.pi), rel=0.05)


def test_pool_capture_returns_the_pools_images():
    views = _cands(8)
    pool = SyntheticCapture(_truth(), S, noise_sigma=0.01)(views)
    cap = PoolCapture(pool)
    assert cap.candidates == views
    got = cap([views[5], views[2], views[7]])
    assert got.views == [views[5], views[2], views[7]]
    assert torch.equal(got.images, pool.images[[5, 2, 7]])
    other = collocated_views(3, 3.5, camera="rectified", resolution=R, power=10.0)
    with pytest.raises(InputError, match="not in the capture pool"):
        cap([views[0], other[1]])


def _run(tmp_path, **kw):
    truth = _truth()
    cands = _cands(30)
    cap = SyntheticCapture(truth, S, noise_sigma=0.005)
    held = collocated_views(3, 3.0, method="sobol", camera="rectified", resolution=R, power=10.0)
    ev = Evaluation.synthetic(SyntheticCapture(truth, S), held)
    args = dict(rounds=2, k=2, steps=40, particles=6, initial_indices=[0, 1], evaluation=ev, out=tmp_path)
    args.update(kw)
    return guided_acquisition(bb.models.per_texel(R), cap(cands[:2]), cands, cap, **args), cands


def test_two_rounds_write_files_grow_views_and_resume(tmp_path, monkeypatch):
    records = []
    res, cands = _run(tmp_path, on_round=lambda rec, post: records.append((rec["round"], post.num_particles)))
    assert records == [(0, 6), (1, 6), (2, 6)]
    # one folder per posterior: rounds + 1 of them
    for r in range(3):
        d = tmp_path / f"round_{r:02d}"
        assert (d / "posterior.safetensors").is_file() and (d / "round.json").is_file()
        assert json.loads((d / "round.json").read_text())["round"] == r
    assert not (tmp_path / "round_03").exists()
    summary = json.loads((tmp_path / "acquisition.json").read_text())
    assert [r["views"] for r in summary["rounds"]] == [2, 4, 6]
    assert [r["views"] for r in res.rounds] == [2, 4, 6]                     # k views added per round
    picks = [r["picks"]["indices"] for r in res.rounds[:2]]
    assert res.rounds[2]["picks"] is None
    flat = [i for p in picks for i in p]
    assert len(flat) == 4 and len(set(flat)) == 4 and not set(flat) & {0, 1}
    assert res.rounds[1]["used"] == [0, 1] + picks[0]
    # the final observations are the initial views followed by the picks, captured by the callback
    assert res.observations.views == [cands[i] for i in [0, 1] + flat]
    cap = SyntheticCapture(_truth(), S, noise_sigma=0.005)
    torch.testing.assert_close(res.observations.images, cap(res.observations.views).images)
    # the saved posterior is the one returned
    back = Posterior.load(tmp_path / "round_02" / "posterior.safetensors")
    assert torch.equal(back.particles["albedo"], res.posterior.particles["albedo"])
    # metrics: present and finite every round
    for r in res.rounds:
        m = r["metrics"]
        vals = [m["novel_error"], m["mean_image_std"], m["param_error"]["albedo"], m["param_error"]["roughness"]]
        assert all(math.isfinite(v) and v >= 0 for v in vals), m
    assert [v for v, _ in res.series("novel_error")] == [2, 4, 6]

    # resume: everything is on disk, so no inference runs and the picks are the same
    def no_infer(*a, **k):
        raise AssertionError("inference re-ran on resume")
    monkeypatch.setattr(bayes_brdf.inference, "infer", no_infer)
    again, _ = _run(tmp_path)
    assert again.rounds == json.loads(json.dumps(res.rounds))               # the records, read back
    assert [r["picks"]["indices"] for r in again.rounds[:2]] == picks
    assert again.observations.views == res.observations.views
    assert torch.equal(again.posterior.particles["roughness"], res.posterior.particles["roughness"])
    monkeypatch.undo()
    # a folder of another acquisition run (other steps, other method) is refused, naming what differs
    for kw, word in (({"steps": 41}, "steps"), ({"method": "sobol"}, "method")):
        with pytest.raises(InputError, match=f"holds round 0 of another acquisition run.*{word}"):
            _run(tmp_path, **kw)
    # so is one whose sampler preset was edited since (the same name, another table: the preset's texel sweep
    # went from every 3 steps to every step on 2026-12-07, and a rerun must not replay the old rounds)
    import bayes_brdf.presets as presets
    real_load = presets.load_preset
    edited = lambda kind, name: ({**real_load(kind, name), "params": {**real_load(kind, name)["params"],  # noqa: E731
                                                                      "texel_moves": 3}}
                                 if kind == "samplers" else real_load(kind, name))
    monkeypatch.setattr(presets, "load_preset", edited)
    with pytest.raises(InputError, match="holds round 0 of another acquisition run.*sampler.params.texel_moves"):
        _run(tmp_path)
    monkeypatch.undo()

    # a run interrupted before its last round: only that round is fitted again
    import shutil
    shutil.rmtree(tmp_path / "round_02")
    calls = []
    real = bayes_brdf.inference.infer
    monkeypatch.setattr(bayes_brdf.inference, "infer", lambda *a, **k: calls.append(len(a[1])) or real(*a, **k))
    third, _ = _run(tmp_path)
    assert calls == [6]                                                      # round 2 only, on all 6 views
    assert (tmp_path / "round_02" / "round.json").is_file()
    assert [r["picks"]["indices"] for r in third.rounds[:2]] == picks
    assert third.observations.views == res.observations.views


def test_evaluation_metrics_match_a_direct_computation():
    truth = _truth()
    views = _cands(3)
    g = torch.Generator().manual_seed(4)
    n = 5
    post = Posterior({"albedo": torch.rand(n, 3, R, R, generator=g), "roughness": torch.rand(n, 1, R, R, generator=g) * .5 + .2},
                     torch.arange(n, 0, -1.0), model=bb.models.per_texel(R),
                     meta={"surface": {"size": 2.0, "grid": "centers"}})
    ev = Evaluation.synthetic(SyntheticCapture(truth, S), views)
    m = ev(post, S)
    best = n - 1                                                              # lowest energy
    pred = render(post.maps(best), views, S)[0]
    y = render(truth, views, S)[0]
    assert m["novel_error"] == pytest.approx(float((pred - y).abs().mean()), rel=1e-5)
    imgs = torch.stack([render(post.maps(i), views, S)[0] for i in range(n)])
    assert m["mean_image_std"] == pytest.approx(float(imgs.std(0).mean()), rel=1e-5)
    assert m["param_error"]["albedo"] == pytest.approx(float((post.particles["albedo"][best] - truth.albedo).abs().mean()), rel=1e-6)
    assert m["param_error"]["roughness"] == pytest.approx(
        float((post.particles["roughness"][best] - truth.roughness).abs().mean()), rel=1e-6)


def test_views_per_round_as_a_list_and_bad_rounds_or_k():
    cands = _cands(20)
    cap = SyntheticCapture(_truth(), S)
    model = bb.models.per_texel(R)
    res = guided_acquisition(model, cap(cands[:2]), cands, cap, rounds=2, k=[1, 3], method="sobol", steps=20,
                             particles=4, initial_indices=[0, 1])
    assert [r["views"] for r in res.rounds] == [2, 3, 6]
    assert [len(r["picks"]["indices"]) for r in res.rounds[:2]] == [1, 3]
    for bad in (dict(rounds=1, k=0), dict(rounds=-1), dict(rounds=2, k=[1]), dict(rounds=2, k=[1, 0])):
        with pytest.raises(InputError):
            guided_acquisition(model, cap(cands[:2]), cands, cap, **bad)
