"""``bayes-brdf fit-many``: each capture gets the particles of a plain ``fit`` (serial and on a local Ray), in a
folder that resumes and refuses another run's, like ``fit``'s."""
from __future__ import annotations

import json
import sys

import pytest

from bayes_brdf.cli.fit_many import fit_many
from bayes_brdf.cli.main import main
from bayes_brdf.posterior import Posterior

FAST = ["--steps", "40", "--particles", "4", "--resolution", "8", "--holdout", "3"]


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Two small bundles, and a third capture named like the first (another folder of the same name)."""
    root = tmp_path_factory.mktemp("caps")
    for name in ("tiles", "marble", "again/tiles"):
        assert main(["render", name.split("/")[-1], "--views", "sobol:4", "--resolution", "8", "--seed",
                     str(len(name)), "--out", str(root / name)]) == 0
    return root


@pytest.fixture(scope="module")
def plain(captures, tmp_path_factory):
    """Plain ``fit`` of each capture: its particles."""
    root = tmp_path_factory.mktemp("plain")
    out = {}
    for name in ("tiles", "marble", "again/tiles"):
        assert main(["fit", str(captures / name), *FAST, "--out", str(root / name)]) == 0
        out[name] = Posterior.load(root / name / "posterior.safetensors").particles
    return out


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(bool((a[k] == b[k]).all()) for k in a)


def _particles(folder):
    return Posterior.load(folder / "posterior.safetensors").particles


def _err_line(capsys) -> str:
    err = [x for x in capsys.readouterr().err.strip().splitlines() if x.startswith("bayes-brdf: error")]
    assert len(err) == 1, err
    return err[0]


def test_each_capture_gets_the_particles_of_a_plain_fit_and_a_rerun_resumes(captures, plain, tmp_path, capsys):
    out = tmp_path / "many"
    caps = [str(captures / n) for n in ("tiles", "marble", "again/tiles")]
    assert main(["fit-many", *caps, *FAST, "--out", str(out)]) == 0
    assert "fit-many: 3 of 3 captures fitted" in capsys.readouterr().out
    for name, folder in (("tiles", "tiles"), ("marble", "marble"), ("again/tiles", "tiles-2")):
        assert _same(_particles(out / folder), plain[name]), name
        run = json.loads((out / folder / "run.json").read_text())
        assert run["label"].startswith("tiles" if "tiles" in name else "marble")
        assert json.loads((out / folder / "summary.json").read_text())["heldout_views"] == [3]
    before = (out / "marble" / "posterior.safetensors").read_bytes()
    assert main(["fit-many", *caps, *FAST, "--out", str(out)]) == 0            # a rerun resumes each
    cap = capsys.readouterr()
    assert cap.err.count("resuming from step 40 of 40") == 3 and cap.out.count("sampled earlier in") == 3
    assert (out / "marble" / "posterior.safetensors").read_bytes() == before
    log = [json.loads(x) for x in (out / "marble" / "run_log.jsonl").read_text().splitlines()]
    assert [r["resumed_from"] for r in log] == [0, 40]


def test_on_a_local_ray_each_capture_gets_the_same_particles(captures, plain, tmp_path, capsys, ray_local):
    out = tmp_path / "ray"
    assert main(["fit-many", str(captures / "tiles"), str(captures / "marble"), *FAST, "--out", str(out),
                 "--ray"]) == 0
    cap = capsys.readouterr()
    assert "2 of 2 captures fitted" in cap.out and "RayExecutor" in cap.out
    assert cap.out.count("Posterior(4 particles") == 2                  # each task's own lines, replayed here
    for name in ("tiles", "marble"):
        assert _same(_particles(out / name), plain[name]), name
    # the Python API takes the same choice
    recs = fit_many([captures / "marble"], tmp_path / "api", executor=True, steps=40, particles=4, resolution=8,
                    holdout=[3])
    assert [r["code"] for r in recs] == [0] and _same(_particles(tmp_path / "api" / "marble"), plain["marble"])


def test_a_folder_of_another_run_is_refused_in_one_line_and_the_others_still_fit(captures, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["fit", str(captures / "tiles"), *FAST, "--seed", "1", "--out", str(out / "tiles")]) == 0
    before = (out / "tiles" / "posterior.safetensors").read_bytes()
    capsys.readouterr()
    assert main(["fit-many", str(captures / "tiles"), str(captures / "marble"), *FAST, "--out", str(out)]) == 2
    line = _err_line(capsys)
    assert "holds a run of tiles" in line and "seed" in line and "--overwrite" in line
    assert (out / "tiles" / "posterior.safetensors").read_bytes() == before          # untouched
    assert (out / "marble" / "posterior.safetensors").is_file()
    assert main(["fit-many", str(captures / "tiles"), *FAST, "--out", str(out), "--overwrite"]) == 0
    assert json.loads((out / "tiles" / "summary.json").read_text())["seed"] == 0


@pytest.mark.parametrize("args, words", [
    (["missing"], "capture not found"),
    (["TILES", "TILES"], "capture given twice"),
    (["TILES", "--ray-cpus", "2"], "--ray-cpus applies to --ray"),
])
def test_bad_captures_and_options_are_one_line_exit_2_before_any_work(captures, tmp_path, capsys, args, words):
    args = [str(tmp_path / a) if a == "missing" else str(captures / "tiles") if a == "TILES" else a for a in args]
    assert main(["fit-many", *args, *FAST, "--out", str(tmp_path / "o")]) == 2
    assert words in _err_line(capsys)
    assert not (tmp_path / "o").exists()


def test_ray_without_ray_installed_says_how_to_install_it(captures, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)          # import ray -> ImportError
    for opt in (["--ray"], ["--ray-address", "127.0.0.1:6379"]):
        for cmd in (["fit-many", str(captures / "tiles"), *FAST, "--out", str(tmp_path / "o")],
                    ["compare", "--runs", "2", "--samplers", "spos"]):
            assert main([*cmd, *opt]) == 2
            line = _err_line(capsys)
            assert f"{opt[0]} needs Ray" in line and "pip install 'bayes-brdf[ray]'" in line, line
    assert not (tmp_path / "o" / "tiles" / "posterior.safetensors").exists()


def test_experiments_without_fan_out_refuse_ray(tmp_path, capsys):
    assert main(["experiment", "fig2", "--ray", "--out", str(tmp_path / "e")]) == 2
    line = _err_line(capsys)
    assert "fig2 runs in one process" in line and "fig3" in line and "fig7" in line


@pytest.mark.shared
def test_real_captures_get_the_particles_of_a_plain_fit_on_ray(shared_data, tmp_path, ray_local):
    caps = [shared_data / "captures" / n for n in ("card_blue", "bath_tile")]
    opts = ["--resolution", "16", "--steps", "40", "--particles", "4", "--views", "0,2,4,6"]
    assert main(["fit-many", *map(str, caps), *opts, "--out", str(tmp_path / "many"), "--ray"]) == 0
    for c in caps:
        assert main(["fit", str(c), *opts, "--out", str(tmp_path / "plain" / c.name)]) == 0
        assert _same(_particles(tmp_path / "many" / c.name), _particles(tmp_path / "plain" / c.name)), c.name
