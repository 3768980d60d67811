"""`bayes-brdf recommend` on environment-lit captures: generated and held-out candidates lit as the capture
(or as --candidate-light says), recommendations written, and the bad requests in one line (exit 2)."""
import json
import math

import numpy as np
import pytest

from bayes_brdf.cli.main import main
from bayes_brdf.io import write_exr
from bayes_brdf.render.environment import studio

CHEAP = ["--resolution", "8", "--steps", "30", "--particles", "4"]


@pytest.fixture(scope="module")
def studio_exr(tmp_path_factory):
    p = tmp_path_factory.mktemp("env") / "studio.exr"
    write_exr(p, studio(16).radiance.numpy().astype(np.float32))
    return p


@pytest.fixture(scope="module")
def env_capture(studio_exr, tmp_path_factory):
    """4 rectified 8x8 views of 'marble' under the studio map alone (no flash), and a posterior on two."""
    root = tmp_path_factory.mktemp("cap")
    assert main(["render", "marble", "--views", "sobol:4", "--camera", "rectified", "--resolution", "8",
                 "--env", str(studio_exr), "--no-flash", "--out", str(root / "cap")]) == 0
    assert main(["recommend", str(root / "cap"), "--views", "0,1", *CHEAP, "--k", "1",
                 "--out", str(root / "fit")]) == 0
    return root / "cap", root / "fit" / "posterior.safetensors"


def _read(out):
    return json.loads((out / "recommend.json").read_text())


def test_recommend_ranks_the_held_out_views_of_an_environment_lit_capture(env_capture, tmp_path, capsys):
    cap, _ = env_capture
    out = tmp_path / "rec"
    assert main(["recommend", str(cap), "--views", "0,1", *CHEAP, "--k", "2", "--radius", "0",
                 "--out", str(out)]) == 0
    r = _read(out)
    assert sorted(r["recommended"]) == [2, 3] and r["candidates_lit_by"] == "environment"
    assert all(math.isfinite(c["mi"]) and c["pixels"] == 64 for c in r["all"]) and (out / "candidates.png").is_file()
    assert "lit by environment" in capsys.readouterr().out
    assert [[L["type"] for L in v["lights"]] for v in r["views"]] == [["environment"]] * 2
    # the held-out cameras relit: the environment and a flash at each camera
    _, post = env_capture
    assert main(["recommend", str(cap), "--views", "0,1", "--resolution", "8", "--posterior", str(post), "--k", "1",
                 "--candidate-light", "both", "--flash-power", "5", "--out", str(tmp_path / "relit")]) == 0
    relit = _read(tmp_path / "relit")
    assert relit["candidates_lit_by"] == "environment + flash" and relit["recommended"][0] in (2, 3)
    (v,) = relit["views"]
    assert v["camera"] == next(w for w in r["views"] if w["camera"] == v["camera"])["camera"]
    point, envl = v["lights"]                 # View.to_dict: a point light as its fields, the environment typed
    assert point["position"] == v["camera"]["position"] and point["power"] == [5.0] * 3
    assert envl["type"] == "environment"


def test_generated_candidates_copy_the_environment_and_can_add_a_flash(env_capture, tmp_path, capsys):
    cap, post = env_capture
    base = ["recommend", str(cap), "--posterior", str(post), "--resolution", "8", "--candidates", "fibonacci:6",
            "--k", "2", "--radius", "10"]
    assert main(base + ["--out", str(tmp_path / "a")]) == 0
    a = _read(tmp_path / "a")
    lights = [[L["type"] for L in v["lights"]] for v in a["views"]]
    assert lights == [["environment"]] * 2 and a["candidate_light"] == "capture"
    assert len(a["recommended"]) == 2 and all(math.isfinite(c["mi"]) for c in a["all"])
    # the environment plus a flash at each candidate camera
    assert main(base + ["--candidate-light", "both", "--flash-power", "20", "--out", str(tmp_path / "b")]) == 0
    b = _read(tmp_path / "b")
    assert b["candidates_lit_by"] == "environment + flash"
    for v in b["views"]:
        point, envl = v["lights"]
        assert point["position"] == v["camera"]["position"] and point["power"] == [20.0] * 3
        assert envl["type"] == "environment"
    assert len(b["recommended"]) == 2 and all(math.isfinite(c["mi"]) for c in b["all"])
    # the flash lights the same cameras differently: other scores
    assert all(ca["mi"] != cb["mi"] for ca, cb in zip(a["all"], b["all"]))
    out = capsys.readouterr().out
    assert "lit by environment + flash" in out
    # a flash is the capture's to copy, or --flash-power's: this capture has none
    assert main(base + ["--candidate-light", "flash", "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no flash" in err and "--flash-power" in err


def test_asking_for_an_environment_of_a_flash_only_capture_is_one_line_exit_2(tmp_path, capsys):
    cap = tmp_path / "flash"
    assert main(["render", "marble", "--views", "sobol:3", "--camera", "rectified", "--resolution", "8",
                 "--out", str(cap)]) == 0
    for light in ("environment", "both"):
        out = tmp_path / light
        capsys.readouterr()
        assert main(["recommend", str(cap), "--views", "0,1", *CHEAP, "--candidates", "fibonacci:4",
                     "--candidate-light", light, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("bayes-brdf: error:") and "no environment map" in err, err
        assert not (out / "posterior.safetensors").exists()          # refused before any fitting
    # a JSON file of views keeps its own lights
    views = tmp_path / "views.json"
    views.write_text(json.dumps({"views": []}))
    assert main(["recommend", str(cap), "--views", "0,1", *CHEAP, "--candidates", str(views),
                 "--candidate-light", "flash", "--out", str(tmp_path / "j")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "keep their own lights" in err
