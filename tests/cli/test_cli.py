"""The bayes-brdf command line as a user runs it: output, files, and one-line errors with exit code 2."""
import json
import shutil
import subprocess
import sys

import pytest

from bayes_brdf.cli.main import main
from bayes_brdf.io import load_observations


def run(*args):
    p = subprocess.run([sys.executable, "-m", "bayes_brdf", *args], capture_output=True, text=True, timeout=300)
    return p.returncode, p.stdout, p.stderr


@pytest.mark.parametrize("cmd", [[], ["render"], ["inspect"]])
def test_help_on_every_command(cmd):
    code, out, err = run(*cmd, "--help")
    assert code == 0 and "usage: bayes-brdf" in out


def test_render_writes_a_loadable_bundle(tmp_path, capsys):
    assert main(["render", "marble", "--views", "sobol:3", "--resolution", "16", "--out", str(tmp_path)]) == 0
    obs = load_observations(tmp_path)
    assert len(obs) == 3 and obs.resolution == (16, 16)
    assert obs.images.max() > 0 and (tmp_path / "preview_00.png").exists() and (tmp_path / "maps" / "albedo.exr").exists()
    assert str(tmp_path) in capsys.readouterr().out


def test_render_at_a_json_view_list_and_from_a_maps_folder(tmp_path):
    assert main(["render", "tiles", "--views", "orbit:2", "--resolution", "8", "--out", str(tmp_path / "a")]) == 0
    views = json.loads((tmp_path / "a" / "observations.json").read_text())["views"]
    (tmp_path / "views.json").write_text(json.dumps([v["view"] for v in views]))  # a plain list of views
    assert main(["render", str(tmp_path / "a" / "maps"), "--views", str(tmp_path / "views.json"),
                 "--resolution", "8", "--out", str(tmp_path / "b")]) == 0
    a, b = load_observations(tmp_path / "a"), load_observations(tmp_path / "b")
    assert (a.images - b.images).abs().max() < 1e-5


@pytest.mark.parametrize("capture", ["card_blue", "bath_tile", "yellow_box"])
def test_inspect_real_captures(shared_data, capture, capsys):
    assert main(["inspect", str(shared_data / "captures" / capture), "--resolution", "64"]) == 0
    out = capsys.readouterr().out
    assert "views: 9" in out and "64x64" in out and "saturated" in out


def test_render_at_a_capture_views(shared_data, tmp_path):
    assert main(["render", "leather", "--capture", str(shared_data / "captures" / "bath_tile"), "--resolution", "16",
                 "--out", str(tmp_path)]) == 0
    obs = load_observations(tmp_path)
    assert len(obs) == 9 and obs.surface.size == pytest.approx(9.728)


@pytest.mark.parametrize("args, words", [
    (["render", "plywood"], "plywood"),
    (["render", "wood", "--views", "spiral:4"], "--views"),
    (["render", "wood", "--views", "missing.json"], "missing.json"),
    (["render", "wood", "--resolution", "-3"], "--resolution"),
    (["render", "wood", "--format", "tiff"], "--format"),
    (["inspect", "/nonexistent/capture"], "/nonexistent/capture"),
    (["frobnicate"], "frobnicate"),
])
def test_bad_input_is_one_line_exit_2(args, words, tmp_path):
    code, out, err = run(*args, "--out", str(tmp_path)) if args[0] == "render" else run(*args)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "error" in lines[0] and words in lines[0], err
    assert "Traceback" not in err


def test_malformed_capture_is_one_line_exit_2(shared_data, tmp_path):
    cap = tmp_path / "cap"
    shutil.copytree(shared_data / "captures" / "card_blue", cap)
    (cap / "light_pos.txt").write_text("1,2,3\n")  # 1 pose for 9 photos
    code, out, err = run("inspect", str(cap))
    assert code == 2 and len(err.strip().splitlines()) == 1 and "light_pos.txt" in err, err


def test_help_loads_neither_torch_nor_the_library():
    """`bayes-brdf --help` and every command's --help start fast: no torch, Pyro or Mitsuba import
    (benchmarks/bench_import.py has the times)."""
    code = ("import sys, contextlib, io\n"
            "from bayes_brdf.cli.main import main\n"
            "for c in ([], ['render'], ['inspect'], ['infer'], ['fit'], ['recommend'], ['demo'], ['compare'],"
            " ['experiment']):\n"
            "    with contextlib.redirect_stdout(io.StringIO()):\n"
            "        assert main([*c, '--help']) == 0, c\n"
            "heavy = [m for m in ('torch', 'pyro', 'mitsuba', 'matplotlib', 'cv2') if m in sys.modules]\n"
            "assert not heavy, heavy\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
