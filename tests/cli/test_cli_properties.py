"""Property-based checks of the command line (hypothesis): whatever options or capture folder a user gives,
the CLI ends with exit 0 or with ONE line ``bayes-brdf...: error: ...`` and exit 2: never a traceback."""
from __future__ import annotations

import contextlib
import io
import shutil
import warnings

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayes_brdf.cli.main import main

HOSTILE = ["", "-1", "0", "1", "2", "abc", "1e9", "nan", "inf", "-inf", ",", "0,0", "0,,1", "99999999999",
           "3.5", "x=1", "sigma=", "=1", "step_size=-1", "sigma=nan", "sigma=-0.1", "beta=true", "🙂", "../", "/"]
CHEAP = {"infer": ["--steps", "2", "--particles", "2", "--resolution", "8"],
         "fit": ["--steps", "2", "--particles", "2", "--resolution", "8"],
         "recommend": ["--steps", "2", "--particles", "2", "--resolution", "8", "--k", "1"],
         "inspect": ["--resolution", "8"]}
OPTIONS = {"infer": ["--views", "--resolution", "--particles", "--steps", "--param", "--model-param", "--seed",
                     "--model", "--sampler", "--device"],
           "fit": ["--views", "--holdout", "--resolution", "--particles", "--steps", "--model-param"],
           "recommend": ["--views", "--k", "--radius", "--candidates", "--noise-var", "--method", "--estimator",
                         "--posterior"],
           "inspect": ["--resolution", "--format"]}


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    root = tmp_path_factory.mktemp("prop")
    assert main(["render", "tiles", "--views", "sobol:3", "--resolution", "8", "--format", "png",
                 "--out", str(root / "cap")]) == 0
    return root / "cap"


def _run(argv) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        code = main(argv)
    return code, err.getvalue()


def _assert_clean(code: int, err: str, argv):
    assert code in (0, 2), (code, argv, err)
    assert "Traceback" not in err, argv
    if code == 2:
        lines = [x for x in err.strip().splitlines() if x.strip()]
        assert len(lines) == 1 and "error:" in lines[0], (argv, err)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(command=st.sampled_from(sorted(OPTIONS)), data=st.data())
def test_any_option_value_ends_cleanly(bundle, tmp_path_factory, command, data):
    option = data.draw(st.sampled_from(OPTIONS[command]), label="option")
    value = data.draw(st.sampled_from(HOSTILE) | st.text(max_size=6), label="value")
    out = [] if command == "inspect" else ["--out", str(tmp_path_factory.mktemp("o")), "--overwrite"]
    argv = [command, str(bundle), *CHEAP[command], *out, f"{option}={value}"]
    _assert_clean(*_run(argv), argv)


def _mutate(folder, how: str, target: str, payload: bytes):
    files = sorted(p for p in folder.iterdir() if p.is_file())
    victim = next((p for p in files if target in p.name), files[0])
    if how == "delete":
        victim.unlink()
    elif how == "truncate":
        victim.write_bytes(victim.read_bytes()[: len(payload)])
    elif how == "garbage":
        victim.write_bytes(payload)
    elif how == "rename":
        victim.rename(victim.with_suffix(".exr" if victim.suffix == ".png" else ".png"))
    elif how == "extra":
        (folder / f"07{victim.suffix}").write_bytes(payload)
    elif how == "empty":
        victim.write_bytes(b"")


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(how=st.sampled_from(["delete", "truncate", "garbage", "rename", "extra", "empty"]),
       target=st.sampled_from(["observations.json", "view_00", "view_01", ".png", "preview"]),
       payload=st.binary(max_size=40) | st.sampled_from([b"{", b"[]", b'{"views": 3}', b"\x89PNG\r\n\x1a\n"]),
       command=st.sampled_from(["inspect", "infer"]))
def test_any_broken_capture_folder_ends_cleanly(bundle, tmp_path_factory, how, target, payload, command):
    cap = tmp_path_factory.mktemp("broken") / "cap"
    shutil.copytree(bundle, cap, ignore=shutil.ignore_patterns("maps"))
    _mutate(cap, how, target, payload)
    out = [] if command == "inspect" else ["--out", str(cap.parent / "out")]
    argv = [command, str(cap), *CHEAP[command], *out]
    _assert_clean(*_run(argv), argv)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(photo=st.sampled_from(["00.png", "03.png", "08.png"]),
       payload=st.binary(min_size=0, max_size=64) | st.sampled_from([b"\x76\x2f\x31\x01", b"\x89PNG\r\n\x1a\n"]),
       extra=st.sampled_from([None, "09.exr", "3.png", "notes.txt", "preview.jpg"]))
def test_any_broken_materialgan_capture_ends_cleanly(shared_data, tmp_path_factory, photo, payload, extra):
    cap = tmp_path_factory.mktemp("mg") / "card"
    shutil.copytree(shared_data / "captures" / "card_blue", cap)
    (cap / photo).write_bytes(payload)
    if extra:
        (cap / extra).write_bytes(payload)
    argv = ["inspect", str(cap), "--resolution", "16"]
    _assert_clean(*_run(argv), argv)


@pytest.mark.parametrize("steps", ["99999999999", "10000001"])
def test_an_absurd_run_length_is_one_line_before_any_sampling(bundle, tmp_path, steps):
    """hypothesis once drew --steps=99999999999: the energy trace's allocation (320 GB) was a traceback."""
    code, err = _run(["fit", str(bundle), "--particles", "2", "--resolution", "8", "--out", str(tmp_path / "o"),
                      f"--steps={steps}"])
    _assert_clean(code, err, steps)
    assert code == 2 and f"got {int(steps):,}" in err
