"""Nothing silently wrong, nothing lost: an output folder belongs to one run, outputs are checked before any
work, results are written whole with mode 0644, and an interrupted run resumes to the same bytes."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bayes_brdf.cli.main import main

FAST = ["--steps", "40", "--particles", "4", "--resolution", "8"]


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Two small bundles of different materials under the same views."""
    root = tmp_path_factory.mktemp("caps")
    for name in ("tiles", "marble"):
        assert main(["render", name, "--views", "sobol:4", "--resolution", "8", "--out", str(root / name)]) == 0
    return root


def _err_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_folder_holding_another_capture_is_refused_in_one_line(captures, tmp_path, capsys):
    out = str(tmp_path / "out")
    assert main(["infer", str(captures / "tiles"), *FAST, "--out", out]) == 0
    before = (tmp_path / "out" / "posterior.safetensors").read_bytes()
    capsys.readouterr()
    assert main(["infer", str(captures / "marble"), *FAST, "--out", out]) == 2
    line = _err_line(capsys)
    assert "holds a run of tiles" in line and "--overwrite" in line and "data" in line
    assert (tmp_path / "out" / "posterior.safetensors").read_bytes() == before      # untouched
    # other views, another model option, another seed: refused too, naming what differs
    for extra, word in ((["--views", "0,2"], "views"), (["--model-param", "sigma=0.05"], "model.sigma"),
                        (["--seed", "1"], "seed")):
        assert main(["infer", str(captures / "tiles"), *FAST, "--out", out, *extra]) == 2
        assert word in _err_line(capsys)
    # --overwrite starts over with the new capture
    assert main(["infer", str(captures / "marble"), *FAST, "--out", out, "--overwrite"]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["capture"].endswith("marble") and summary["resumed_from"] == 0
    assert json.loads((tmp_path / "out" / "run.json").read_text())["label"].startswith("marble")


def test_the_default_folders_are_named_after_the_capture(captures, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for name in ("tiles", "marble"):
        assert main(["recommend", str(captures / name), "--views", "0,2", "--k", "1", *FAST]) == 0
        rec = json.loads((tmp_path / "out" / "recommend" / name / "recommend.json").read_text())
        assert rec["capture"].endswith(name)


def test_a_rerun_resumes_and_says_so_with_the_first_runs_time(captures, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["infer", str(captures / "tiles"), *FAST, "--out", str(out)]) == 0
    first = json.loads((out / "summary.json").read_text())
    capsys.readouterr()
    assert main(["infer", str(captures / "tiles"), *FAST, "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "resuming from step 40 of 40" in cap.err and "finished" in cap.err
    assert "sampled earlier in" in cap.out
    again = json.loads((out / "summary.json").read_text())
    assert again["resumed_from"] == 40 and again["sampling_seconds"] == first["sampling_seconds"]
    log = [json.loads(x) for x in (out / "run_log.jsonl").read_text().splitlines()]
    assert [r["resumed_from"] for r in log] == [0, 40]


def test_results_are_mode_0644_and_no_temporary_files_are_left(captures, tmp_path):
    out = tmp_path / "o"
    assert main(["fit", str(captures / "tiles"), "--views", "0,1,2", *FAST, "--out", str(out)]) == 0
    files = [p for p in out.rglob("*") if p.is_file()]
    assert {p.name for p in files} >= {"posterior.safetensors", "summary.json", "run.json", "checkpoint.pt"}
    mode = 0o666 & ~_umask()
    assert {oct(p.stat().st_mode & 0o777) for p in files} == {oct(mode)}
    assert not [p for p in files if ".tmp" in p.name or p.name.startswith(".")]


def _umask() -> int:
    um = os.umask(0)
    os.umask(um)
    return um


@pytest.mark.parametrize("command", ["infer", "fit", "recommend"])
def test_unwritable_outputs_fail_before_any_work(captures, tmp_path, capsys, command):
    afile = tmp_path / "a_file"
    afile.write_text("x")
    for out, word in ((afile, "is a file"), (afile / "sub", "cannot write")):
        t = time.perf_counter()
        assert main([command, str(captures / "tiles"), "--views", "0,1", *FAST, "--out", str(out)]) == 2
        line = _err_line(capsys)
        assert word in line and "--out" in line
        assert time.perf_counter() - t < 5


def test_compare_json_into_an_unwritable_place_fails_before_the_table(tmp_path, capsys):
    afile = tmp_path / "f"
    afile.write_text("x")
    t = time.perf_counter()
    assert main(["compare", "--runs", "2", "--json", str(afile / "t.json")]) == 2
    assert "--json" in _err_line(capsys) and time.perf_counter() - t < 5


@pytest.mark.parametrize("args, words", [
    (["--views=-1"], "count from 0"),
    (["--views", "0,0,2"], "listed twice"),
    (["--views", ""], "at least one view"),
    (["--views", "7"], "the capture has 4 views"),
    (["--particles", "1"], "at least 2 particles"),
])
def test_bad_views_and_particles_are_one_line_exit_2(captures, tmp_path, capsys, args, words):
    assert main(["infer", str(captures / "tiles"), "--steps", "5", "--resolution", "8", "--out",
                 str(tmp_path / "o"), *args]) == 2
    assert words in _err_line(capsys)


def test_fit_with_every_view_fitted_does_not_claim_heldout_maps(captures, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["fit", str(captures / "tiles"), *FAST, "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "nothing is held out" in said and "heldout/" not in said and not (out / "heldout").exists()


def _default_sigint():
    # as in a terminal: a shell starts background jobs (e.g. a CI script run with `&`) with SIGINT ignored, and
    # Python then never raises KeyboardInterrupt, so Ctrl-C would not reach the run this test interrupts
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _cli(*args, **kw):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-m", "bayes_brdf", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, preexec_fn=_default_sigint, **kw)


STEPS = 800
ARGS = ["--steps", str(STEPS), "--particles", "8", "--resolution", "8"]


@pytest.fixture(scope="module")
def uninterrupted(captures, tmp_path_factory):
    full = tmp_path_factory.mktemp("full")
    p = _cli("infer", str(captures / "tiles"), *ARGS, "--out", str(full))
    assert p.wait(timeout=240) == 0, p.stderr.read()
    return full


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_interrupted_and_resumed_run_writes_the_same_bytes(captures, uninterrupted, tmp_path, sig):
    """SIGTERM / Ctrl-C saves the checkpoint and says how to resume; the resumed posterior file equals an
    uninterrupted run's byte for byte (in another process), and counts the same evaluations."""
    args = ["infer", str(captures / "tiles"), *ARGS]
    cut = tmp_path / "cut"
    p = _cli(*args, "--out", str(cut))
    deadline = time.time() + 120
    while not (cut / "checkpoint.pt").exists() and time.time() < deadline and p.poll() is None:
        time.sleep(0.02)
    assert p.poll() is None, "the run ended before it could be interrupted"
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130
    line = err.strip().splitlines()[-1]
    assert "interrupted at step" in line and str(cut / "checkpoint.pt") in line and "rerun the same command" in line
    step = int(line.split("interrupted at step ")[1].split()[0])
    assert 0 < step < STEPS
    p = _cli(*args, "--out", str(cut))
    _, err = p.communicate(timeout=240)
    assert p.returncode == 0 and f"resuming from step {step} of {STEPS}" in err
    assert (cut / "posterior.safetensors").read_bytes() == (uninterrupted / "posterior.safetensors").read_bytes()
    a, b = (json.loads((d / "summary.json").read_text()) for d in (uninterrupted, cut))
    assert a["evaluations"] == b["evaluations"] > 0
    log = [json.loads(x) for x in (cut / "run_log.jsonl").read_text().splitlines()]
    assert log[0]["status"] == f"interrupted at step {step}" and log[1]["resumed_from"] == step
