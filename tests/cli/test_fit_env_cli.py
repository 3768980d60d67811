"""`bayes-brdf fit` with held-out views on environment-lit captures (issue 24, part 5): exits 0, reports the
held-out coverage and Spearman in summary.json, and report.html says how every view is lit; the latent decoder
fits an environment-lit capture with normals=flat and is refused in one line without it."""
import json
import math

import pytest
import torch

from bayes_brdf.cli.main import main
from bayes_brdf.io import write_exr
from bayes_brdf.posterior import Posterior
from bayes_brdf.render.environment import studio


@pytest.fixture(scope="module")
def studio_map(tmp_path_factory):
    p = tmp_path_factory.mktemp("env") / "studio.exr"
    write_exr(p, studio(16).radiance.numpy())
    return p


def _capture(tmp, env, *extra, name="cap"):
    out = tmp / name
    assert main(["render", "marble", "--resolution", "16", "--env", str(env), *extra, "--out", str(out)]) == 0
    return out


def _fit_and_check(cap, out, capsys, *extra, lit="flash (power", alone=False, env="studio.exr"):
    assert main(["fit", str(cap), "--holdout", "3,4", "--steps", "40", "--particles", "4", *extra,
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "held-out views [3, 4]" in printed and "Spearman" in printed and "report.html" in printed
    s = json.loads((out / "summary.json").read_text())
    h = s["heldout"]
    assert s["heldout_views"] == [3, 4] and h["pixels"] > 100
    assert 0 <= h["coverage"]["50"] <= h["coverage"]["90"] <= 1 and math.isfinite(h["spearman"])
    assert all(math.isfinite(v) for v in s["mean_param_std"].values())
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 8                       # the held-out maps, embedded
    assert "coverage of the 90 % interval" in html and "Spearman(std, |error|)" in html
    assert f"lit by an environment light (&#x27;{env}&#x27;)" in html
    assert html.count(f"environment &#x27;{env}&#x27; 32x16, scale 1") >= 5 + 2   # the views table, per view
    assert (lit in html) and (("(alone)" in html) == alone)
    assert "held out" in html and "fitted" in html
    return s, html


def test_fit_holds_out_views_of_an_environment_and_flash_capture_and_reports_their_lighting(studio_map, tmp_path,
                                                                                            capsys):
    cap = _capture(tmp_path, studio_map, "--views", "sobol:5", "--camera", "rectified")
    _fit_and_check(cap, tmp_path / "fit", capsys)


def test_fit_on_an_environment_alone_capture(studio_map, tmp_path, capsys):
    cap = _capture(tmp_path, studio_map, "--views", "sobol:5", "--no-flash")
    s, html = _fit_and_check(cap, tmp_path / "fit", capsys, lit="environment", alone=True)
    assert "flash (power" not in html and "0 of them by the environment alone" not in html


def test_a_flash_capture_report_says_no_environment(tmp_path, capsys):
    cap = tmp_path / "flash"
    assert main(["render", "marble", "--resolution", "16", "--views", "sobol:5", "--camera", "rectified",
                 "--out", str(cap)]) == 0
    assert main(["fit", str(cap), "--holdout", "4", "--steps", "20", "--particles", "4",
                 "--out", str(tmp_path / "fit")]) == 0
    html = (tmp_path / "fit" / "report.html").read_text()
    assert "point lights only (no environment)" in html and "environment &#x27;" not in html


def test_the_latent_decoder_fits_an_environment_capture_with_flat_normals(studio_map, tmp_path, capsys):
    cap = _capture(tmp_path, studio_map, "--views", "sobol:5", "--camera", "rectified")
    common = ["--model", "latent_decoder", "--model-param", "project_steps=5", "--model-param", "noise=zero"]
    assert main(["fit", str(cap), "--holdout", "4", "--steps", "10", "--particles", "4", *common,
                 "--out", str(tmp_path / "refused")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "normals='flat'" in err
    s, _ = _fit_and_check(cap, tmp_path / "fit", capsys, *common, "--model-param", "normals=flat")
    assert s["model"]["normals"] == "flat"
    # its only site (W+ under the flat prior) is z itself: the posterior file still writes and loads
    back = Posterior.load(tmp_path / "fit" / "posterior.safetensors")
    assert back.model.normals == "flat" and torch.equal(back.particles["w_plus"].flatten(1), back.z)


@pytest.mark.needs_llvm
def test_fit_on_an_environment_lit_mesh_capture(studio_map, tmp_path, capsys):
    cap = _capture(tmp_path, studio_map, "--mesh", "sphere", "--views", "fibonacci:5")
    s, _ = _fit_and_check(cap, tmp_path / "fit", capsys, env="env.exr")    # transforms.json keeps the map as env.exr
    assert s["heldout"]["pixels"] > 100
