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
    assert "other settings" in err and err.count("\n") == 1


def test_infer_bad_input(tmp_path, capsys):
    assert main(["infer", str(tmp_path / "missing")]) == 2
    assert main(["infer", str(tmp_path), "--model", "nope"]) == 2
    err = capsys.readouterr().err
    assert all(line.startswith("bayes-brdf: error:") for line in err.strip().splitlines())
