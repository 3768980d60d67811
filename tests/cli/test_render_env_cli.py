"""`bayes-brdf render --env MAP`: synthetic environment-lit captures (with or without the flash) that the
capture loaders read back and infer / fit run on; bad options and maps in one line."""
import json

import numpy as np
import pytest
import torch

from bayes_brdf.cli.main import main
from bayes_brdf.io import load_capture, load_svbrdf, write_exr, write_png
from bayes_brdf.posterior import Posterior
from bayes_brdf.render.environment import EnvironmentLight, z_up
from bayes_brdf.render.lights import PointLight
from bayes_brdf.render.shade import render
from bayes_brdf.render.views import View


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    p = tmp_path_factory.mktemp("env") / "sky.exr"
    a = np.random.default_rng(0).uniform(0.2, 1.5, (8, 16, 3)).astype(np.float32)
    a[0] = 3.0                                             # a bright zenith
    write_exr(p, a)
    return p, a


def _check_against_the_library(out, got):
    """The written images are the library's render of the written (flat-normal) maps at the loaded views."""
    maps = load_svbrdf(out / "maps")
    assert torch.equal(maps.normal, torch.tensor([0.0, 0.0, 1.0])[:, None, None].expand_as(maps.normal))
    again = render(maps, got.views, got.surface)[0]
    assert torch.allclose(again, got.images, rtol=1e-4, atol=1e-5)


@pytest.mark.needs_llvm
def test_render_env_on_a_mesh_then_infer_and_fit(sky, tmp_path, capsys):
    path, radiance = sky
    out = tmp_path / "cap"
    assert main(["render", "marble", "--mesh", "sphere", "--views", "fibonacci:3", "--resolution", "16",
                 "--env", str(path), "--env-rotate", "30", "--env-scale", "2", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "under environment 'sky.exr'" in said and "normal map was made flat" in said
    doc = json.loads((out / "transforms.json").read_text())
    assert [L["type"] for L in doc["lights"]] == ["collocated", "environment"] and (out / "env.exr").is_file()
    got = load_capture(out)
    want = EnvironmentLight(radiance, 2.0, z_up(30.0))
    for v in got.views:
        assert v.lights == (PointLight(v.camera.position, v.lights[0].power), want)
    assert float(got.images.mean()) > 0.05
    _check_against_the_library(out, got)
    assert main(["infer", str(out), "--steps", "10", "--particles", "4", "--out", str(tmp_path / "inf")]) == 0
    post = Posterior.load(tmp_path / "inf" / "posterior.safetensors")
    assert post.particles["albedo"].shape == (4, 3, 16, 16) and bool(torch.isfinite(post.particles["albedo"]).all())
    assert main(["fit", str(out), "--holdout", "2", "--steps", "10", "--particles", "4",
                 "--out", str(tmp_path / "fit")]) == 0
    s = json.loads((tmp_path / "fit" / "summary.json").read_text())
    assert s["heldout_views"] == [2] and 0 <= s["heldout"]["coverage"]["90"] <= 1


def test_render_env_alone_writes_a_bundle_that_loads_renders_again_and_infers(sky, tmp_path, capsys):
    path, radiance = sky
    out = tmp_path / "b"
    common = ["--views", "sobol:2", "--camera", "rectified", "--resolution", "8"]
    assert main(["render", "marble", *common, "--env", str(path), "--no-flash", "--out", str(out)]) == 0
    assert "under environment 'sky.exr' alone" in capsys.readouterr().out
    got = load_capture(out)
    assert [v.lights for v in got.views] == [(EnvironmentLight(radiance, 1.0, z_up()),)] * 2
    _check_against_the_library(out, got)
    assert main(["render", "marble", *common, "--out", str(tmp_path / "flash")]) == 0
    flash = load_capture(tmp_path / "flash")
    assert float((flash.images - got.images).abs().max()) > 0.05          # another light
    # the bundle's views (with their map) are a views file for render
    assert main(["render", "marble", "--views", str(out / "observations.json"), "--camera", "rectified",
                 "--resolution", "8", "--out", str(tmp_path / "again")]) == 0
    assert torch.equal(load_capture(tmp_path / "again").images, got.images)
    assert main(["infer", str(out), "--resolution", "8", "--steps", "10", "--particles", "4",
                 "--out", str(tmp_path / "inf")]) == 0
    assert (tmp_path / "inf" / "posterior.safetensors").is_file()


def test_bad_env_options_and_maps_are_one_line_exit_2(sky, tmp_path, capsys):
    path, _ = sky
    fake = tmp_path / "fake.exr"
    write_png(fake, np.full((4, 8, 3), 0.5, dtype=np.float32))
    base = ["render", "marble", "--views", "sobol:1", "--camera", "rectified", "--resolution", "8"]
    cases = [
        (["--env", str(tmp_path / "gone.exr")], "environment map not found"),
        (["--env", str(fake)], "not an HDR image"),
        (["--env-rotate", "10"], "--env-rotate needs --env"),
        (["--env-scale", "2"], "--env-scale needs --env"),
        (["--no-flash"], "--no-flash leaves view"),
        (["--env", str(path), "--env-scale", "0"], "expected a positive number"),
    ]
    for i, (extra, words) in enumerate(cases):
        assert main(base + extra + ["--out", str(tmp_path / f"o{i}")]) == 2, extra
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("bayes-brdf") and ": error: " in err and words in err, (extra, err)
    assert not any((tmp_path / f"o{i}" / "observations.json").exists() for i in range(len(cases)))


def test_env_replaces_a_captures_own_environment(sky, tmp_path):
    path, radiance = sky
    assert main(["render", "marble", "--views", "sobol:1", "--camera", "rectified", "--resolution", "8",
                 "--env", str(path), "--out", str(tmp_path / "a")]) == 0
    other = tmp_path / "other.exr"
    write_exr(other, radiance[::-1].copy())
    assert main(["render", "marble", "--capture", str(tmp_path / "a"), "--env", str(other), "--env-rotate", "90",
                 "--out", str(tmp_path / "b")]) == 0
    (v,) = load_capture(tmp_path / "b").views
    assert isinstance(v.lights[0], PointLight) and v.environment == EnvironmentLight(radiance[::-1].copy(), 1.0, z_up(90.0))
    assert isinstance(View(v.camera, v.lights), View) and len(v.lights) == 2
