"""`bayes-brdf recommend --from RUN`: the next view from an earlier posterior warm-started on the new photos,
against a cold run on the same photos; its run folder, and the bad requests in one line (exit 2)."""
import json

import pytest

from bayes_brdf.cli.main import main

SMALL = ["--resolution", "16", "--particles", "8"]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """8 rectified 16x16 flash views of 'tiles'; a first fit on four of them (what the user had)."""
    root = tmp_path_factory.mktemp("session")
    assert main(["render", "tiles", "--views", "sobol:8", "--camera", "rectified", "--resolution", "16",
                 "--out", str(root / "cap")]) == 0
    assert main(["recommend", str(root / "cap"), "--views", "0,2,4,6", *SMALL, "--steps", "400", "--k", "1",
                 "--out", str(root / "first")]) == 0
    return root


def _read(out):
    return json.loads((out / "recommend.json").read_text())


def test_warm_start_recommends_what_a_cold_run_recommends(session, tmp_path, capsys):
    cap, first = session / "cap", session / "first"
    taken = _read(first)["recommended"][0]          # the user photographs the recommended view
    views = ",".join(str(v) for v in (0, 2, 4, 6, taken))
    assert main(["recommend", str(cap), "--views", views, *SMALL, "--from", str(first), "--warm-steps", "150",
                 "--k", "2", "--radius", "0", "--out", str(tmp_path / "warm")]) == 0
    assert main(["recommend", str(cap), "--views", views, *SMALL, "--steps", "400", "--k", "2", "--radius", "0",
                 "--out", str(tmp_path / "cold")]) == 0
    warm, cold = _read(tmp_path / "warm"), _read(tmp_path / "cold")
    assert warm["recommended"][0] == cold["recommended"][0]
    assert taken not in warm["recommended"] and len(warm["all"]) == 3
    ws = warm["warm_start"]
    assert ws["steps"] == 150 and ws["fitted_views_before"] == [0, 2, 4, 6]
    summary = json.loads((tmp_path / "warm" / "run.json").read_text())["fingerprint"]
    assert summary["start"]["particles"] and summary["sampler"]["params"]["anneal"] is False
    # the same command again is the same run (resumed, not refused); another start is another run
    assert main(["recommend", str(cap), "--views", views, *SMALL, "--from", str(first), "--warm-steps", "150",
                 "--k", "2", "--radius", "0", "--out", str(tmp_path / "warm")]) == 0
    capsys.readouterr()
    assert main(["recommend", str(cap), "--views", views, *SMALL, "--from", str(tmp_path / "cold"),
                 "--warm-steps", "150", "--out", str(tmp_path / "warm")]) == 2
    err = capsys.readouterr().err
    assert "holds a run of" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("extra, words", [
    (["--from", "nowhere"], "no posterior.safetensors"),
    (["--from", "FIRST", "--posterior", "FIRST/posterior.safetensors"], "--from and --posterior"),
    (["--from", "FIRST", "--warm-steps", "10", "--steps", "20"], "disagree"),
    (["--from", "FIRST", "--model", "homogeneous"], "z0 has shape"),
])
def test_bad_warm_starts_are_one_line(session, tmp_path, capsys, extra, words):
    extra = [e.replace("FIRST", str(session / "first")) for e in extra]
    code = main(["recommend", str(session / "cap"), "--views", "0,2,4,6,1", *SMALL, *extra,
                 "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_candidates_scored_on_ray_give_the_serial_scores(session, tmp_path, ray_local):
    """`recommend --ray`: the candidates scored in shards as Ray tasks, the particles sent once; the same numbers."""
    post = session / "first" / "posterior.safetensors"
    args = ["recommend", str(session / "cap"), "--views", "0,2,4,6", "--resolution", "16", "--posterior", str(post),
            "--candidates", "fibonacci:300", "--k", "3"]
    assert main([*args, "--out", str(tmp_path / "serial")]) == 0
    assert main([*args, "--ray", "--out", str(tmp_path / "ray")]) == 0
    serial, ray = _read(tmp_path / "serial"), _read(tmp_path / "ray")
    assert serial["recommended"] == ray["recommended"] and len(ray["all"]) == 300
    assert [c["mi"] for c in serial["all"]] == [c["mi"] for c in ray["all"]]
