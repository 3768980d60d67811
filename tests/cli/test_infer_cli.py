"""`bayes-brdf infer`: a rendered bundle in, a posterior and its maps out; resume; bad input in one line."""
import json

import torch

from bayes_brdf.cli.main import main
from bayes_brdf.posterior import Posterior


def test_infer_writes_posterior_maps_and_summary(tmp_path, capsys):
    bundle = tmp_path / "bundle"
    assert main(["render", "marble", "--views", "sobol:3", "--camera", "rectified", "--resolution", "8",
                 "--out", str(bundle)]) == 0
    out = tmp_path / "inf"
    argv = ["infer", str(bundle), "--resolution", "8", "--steps", "30", "--sampler", "svgd", "--views", "0,2",
            "--param", "step_size=0.02", "--out", str(out)]
    assert main(argv) == 0
    post = Posterior.load(out / "posterior.safetensors")
    assert post.particles["albedo"].shape == (20, 3, 8, 8)
    s = json.loads((out / "summary.json").read_text())
    assert s["sampler"] == "svgd" and s["params"]["step_size"] == 0.02 and s["views"] == [0, 2]
    for f in ("mean/albedo.png", "map/roughness.png", "std/albedo.exr", "std/roughness.exr"):
        assert any(p.name.startswith(f.split("/")[1].split(".")[0]) for p in (out / f.split("/")[0]).iterdir()), f
    # a rerun resumes from the finished checkpoint and gives the same posterior
    assert main(argv) == 0
    assert torch.equal(Posterior.load(out / "posterior.safetensors").particles["albedo"], post.particles["albedo"])
    # other settings with the same --out: one line saying what to do
    capsys.readouterr()
    assert main(argv[:-2] + ["--seed", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds a run of bundle" in err and "differs in seed" in err and "--overwrite" in err
    assert err.count("\n") == 1


def test_infer_bad_input(tmp_path, capsys):
    assert main(["infer", str(tmp_path / "missing")]) == 2
    assert main(["infer", str(tmp_path), "--model", "nope"]) == 2
    err = capsys.readouterr().err
    assert all(line.startswith("bayes-brdf: error:") for line in err.strip().splitlines())


def test_readme_python_route_and_the_cli_give_the_same_calibrated_answer(tmp_path, capsys):
    """README's ``bb.infer(bb.models.per_texel(R), obs, seed=0)`` and ``bayes-brdf infer CAPTURE`` are one
    computation (same model defaults, sampler, seed): the same particles. And the answer is calibrated on
    data with a known noise level: the inferred sigma is the true one, the true maps sit inside the
    posterior's intervals about as often as the intervals say."""
    import warnings

    import bayes_brdf as bb
    from bayes_brdf.experiments import highdim as H
    from bayes_brdf.io import save_observations

    R, sigma = 12, 0.02
    prob = H.setup(H.HighDimSetup(resolution=R, noise=True, sigma=sigma, seed=5))
    obs = prob.data.observations
    obs.images.clamp_(min=0)                # a saved photo holds no negative radiance (0.1 % of the values)
    save_observations(obs, tmp_path / "cap")
    from bayes_brdf.inference import resolve_model
    from bayes_brdf.presets import load_preset

    # the CLI's model preset and the Python defaults are the same model
    assert resolve_model({**load_preset("models", "per_texel"), "resolution": R}).to_dict() == \
        bb.models.per_texel(R).to_dict()
    # the same computation: identical particles (checked on a short run; the code path is the same at any length)
    short = tmp_path / "short"
    assert main(["infer", str(tmp_path / "cap"), "--resolution", str(R), "--steps", "60", "--out", str(short)]) == 0
    cli_short = Posterior.load(short / "posterior.safetensors")
    obs = bb.io.load_capture(tmp_path / "cap", resolution=R)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        py = bb.infer(bb.models.per_texel(R), obs, seed=0, steps=60, progress=False)
    for site in ("albedo", "roughness"):
        assert torch.allclose(py.particles[site], cli_short.particles[site], atol=1e-6), site
    assert py.noise_sigma == cli_short.noise_sigma
    # and the answer of a real run is calibrated
    out = tmp_path / "cli"
    assert main(["infer", str(tmp_path / "cap"), "--resolution", str(R), "--steps", "500", "--out", str(out)]) == 0
    py = Posterior.load(out / "posterior.safetensors")
    assert abs(py.noise_sigma - sigma) < 0.1 * sigma
    # the (gray) truth inside the central 90 % interval (mean +- 1.645 std) of the per-texel posterior about
    # 90 % of the time for albedo; roughness's posterior is wide and bounded, so the Gaussian interval
    # over-covers there: it must not under-cover (intervals that are too narrow are what misleads)
    cov90 = {}
    for site in ("albedo", "roughness"):
        z = (prob.truth[site] - py.mean(site)[0].double()).abs() / py.std(site)[0].double()
        cov90[site] = float((z <= 1.645).double().mean())
    assert 0.8 <= cov90["albedo"] <= 0.97 and cov90["roughness"] >= 0.8, cov90
