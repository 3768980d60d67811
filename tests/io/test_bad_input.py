"""Every malformed capture / bundle / map folder gives ONE-line InputError naming the file."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from PIL import Image

from bayes_brdf.errors import InputError
from bayes_brdf.io import (load_capture, load_observations, load_peer_svbrdf_panel, load_svbrdf, read_image,
                           save_observations, write_exr)
from bayes_brdf.observations import Observations
from bayes_brdf.render.cameras import RectifiedCamera
from bayes_brdf.render.views import View

from .helpers import raises_one_line


def _photo(path, size=(8, 8), value=100):
    Image.fromarray(np.full((size[1], size[0], 3), value, np.uint8)).save(path)


def _materialgan(d, n=3):
    d.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        _photo(d / f"{i:02d}.png")
    pos = "\n".join(f"{i}.0,0.5,15.0" for i in range(n)) + "\n"
    (d / "camera_pos.txt").write_text(pos)
    (d / "light_pos.txt").write_text(pos)
    (d / "image_size.txt").write_text("6.0\n")
    (d / "light_power.txt").write_text("1500,1500,1500\n")
    return d


def _sdr(d, n=3, name="parameters.json", **over):
    d.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        _photo(d / f"{i:02d}.png")
    doc = {"image_size": 9.7, "idx": list(range(n)), "camera_pos": [[i, 0, 10] for i in range(n)],
           "light_pos": [[i, 0, 10] for i in range(n)], "light_pow": [1500, 1500, 1500]}
    doc.update(over)
    for k in [k for k, v in doc.items() if v is None]:
        del doc[k]
    (d / name).write_text(json.dumps(doc))
    return d


_raises = raises_one_line


def test_good_synthetic_captures_load(tmp_path):
    assert len(load_capture(_materialgan(tmp_path / "m"))) == 3
    assert len(load_capture(_sdr(tmp_path / "s"))) == 3


# ------------------------------------------------------------------ paths and formats
def test_path_does_not_exist(tmp_path):
    _raises(lambda: load_capture(tmp_path / "nope"), "nope", "does not exist")


def test_unknown_format(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    _photo(tmp_path / "00.png")
    msg = _raises(lambda: load_capture(tmp_path), str(tmp_path), "camera_pos.txt", "parameters.json")
    assert "no recognised capture files" in msg
    _raises(lambda: load_capture(tmp_path, fmt="colmap"), "colmap", "materialgan")


def test_bad_options(tmp_path):
    d = _materialgan(tmp_path / "m")
    _raises(lambda: load_capture(d, resolution=0), "resolution")
    _raises(lambda: load_capture(d, gamma="rec709"), "gamma")


# ------------------------------------------------------------------ MaterialGAN
@pytest.mark.parametrize("missing", ["camera_pos.txt", "light_pos.txt", "image_size.txt", "light_power.txt"])
def test_materialgan_missing_file(tmp_path, missing):
    d = _materialgan(tmp_path / "m")
    (d / missing).unlink()
    _raises(lambda: load_capture(d, fmt="materialgan"), missing)


def test_materialgan_pose_image_count_mismatch(tmp_path):
    d = _materialgan(tmp_path / "m")
    _photo(d / "03.png")
    msg = _raises(lambda: load_capture(d), "camera_pos.txt", "3 camera positions", "4 photos")
    assert "one x,y,z line per photo" in msg


def test_materialgan_light_count_mismatch(tmp_path):
    d = _materialgan(tmp_path / "m")
    (d / "light_pos.txt").write_text("0,0,10\n1,0,10\n")
    _raises(lambda: load_capture(d), "light_pos.txt", "2 light positions")


def test_materialgan_no_photos(tmp_path):
    d = _materialgan(tmp_path / "m")
    for p in d.glob("*.png"):
        p.unlink()
    _raises(lambda: load_capture(d), "NN.png")


@pytest.mark.parametrize("line,fragment", [("nan,0,15", "not finite"), ("inf,0,15", "not finite"),
                                           ("1,2", "three numbers"), ("a,b,c", "not a list of numbers")])
def test_materialgan_bad_pose(tmp_path, line, fragment):
    d = _materialgan(tmp_path / "m")
    (d / "camera_pos.txt").write_text(f"0,0,15\n{line}\n2,0,15\n")
    _raises(lambda: load_capture(d), "camera_pos.txt", fragment)


@pytest.mark.parametrize("text", ["-1500,1500,1500", "nan,1,1", "1,2", ""])
def test_materialgan_bad_light_power(tmp_path, text):
    d = _materialgan(tmp_path / "m")
    (d / "light_power.txt").write_text(text)
    _raises(lambda: load_capture(d), "light_power.txt")


@pytest.mark.parametrize("text", ["-6", "nan", "0", "abc"])
def test_materialgan_bad_image_size(tmp_path, text):
    d = _materialgan(tmp_path / "m")
    (d / "image_size.txt").write_text(text)
    _raises(lambda: load_capture(d), "image_size.txt")


def test_real_capture_with_a_photo_missing(shared_data, tmp_path):
    src = shared_data / "captures" / "card_blue"
    d = tmp_path / "card"
    d.mkdir()
    for name in ["camera_pos.txt", "light_pos.txt", "image_size.txt", "light_power.txt"] + [f"{i:02d}.png" for i in range(8)]:
        shutil.copy(src / name, d / name)
    _raises(lambda: load_capture(d), "camera_pos.txt", "9 camera positions but 8 photos")


# ------------------------------------------------------------------ svbrdf-diff-renderer
def test_sdr_malformed_json(tmp_path):
    d = _sdr(tmp_path / "s")
    (d / "parameters.json").write_text('{"image_size": 9.7, "idx": [0, 1,')
    _raises(lambda: load_capture(d), "parameters.json", "malformed JSON")


@pytest.mark.parametrize("key", ["camera_pos", "light_pos", "light_pow", "image_size"])
def test_sdr_missing_key(tmp_path, key):
    d = _sdr(tmp_path / "s", **{key: None})
    _raises(lambda: load_capture(d), "parameters.json", f"'{key}'")


def test_sdr_optim_missing_im_size(tmp_path):
    d = _sdr(tmp_path / "s", name="optim.json", image_size=None)
    _raises(lambda: load_capture(d), "optim.json", "'im_size'")


def test_sdr_missing_image_listed_by_idx(tmp_path):
    d = _sdr(tmp_path / "s", n=3)
    (d / "02.png").unlink()
    _raises(lambda: load_capture(d), "02.png", "missing")


def test_sdr_idx_out_of_range(tmp_path):
    d = _sdr(tmp_path / "s", idx=[0, 1, 5])
    _raises(lambda: load_capture(d), "parameters.json", "idx [5] out of range")


def test_sdr_pose_count_mismatch(tmp_path):
    d = _sdr(tmp_path / "s", light_pos=[[0, 0, 10]])
    _raises(lambda: load_capture(d), "parameters.json", "3 camera_pos entries but 1 light_pos")


@pytest.mark.parametrize("over,fragment", [
    ({"camera_pos": [[0, 0, 10], [float("nan"), 0, 10], [2, 0, 10]]}, "camera_pos[1] is not finite"),
    ({"light_pow": [1500, -1, 1500]}, "light power"),
    ({"light_pow": [float("nan")] * 3}, "light power"),
    ({"image_size": -9.7}, "sample size"),
    ({"image_size": float("nan")}, "sample size"),
    ({"idx": "all"}, "'idx'"),
])
def test_sdr_bad_values(tmp_path, over, fragment):
    d = _sdr(tmp_path / "s", **over)  # json.dumps writes NaN literally, as numpy users do
    _raises(lambda: load_capture(d), "parameters.json", fragment)


# ------------------------------------------------------------------ images
def test_corrupt_image(tmp_path):
    d = _sdr(tmp_path / "s")
    (d / "01.png").write_bytes(b"this is not a png at all")
    _raises(lambda: load_capture(d), "01.png", "cannot read image")


def test_truncated_png(tmp_path):
    d = _sdr(tmp_path / "s")
    big = np.random.default_rng(0).integers(0, 256, (64, 64, 3)).astype(np.uint8)
    Image.fromarray(big).save(d / "00.png")
    data = (d / "00.png").read_bytes()
    (d / "00.png").write_bytes(data[: len(data) // 2])
    _raises(lambda: load_capture(d), "00.png")


def test_truncated_16bit_png(tmp_path):
    p = tmp_path / "x.png"
    from bayes_brdf.io import write_png

    write_png(p, np.random.default_rng(1).random((32, 32, 3)), linear=False, bits=16)
    p.write_bytes(p.read_bytes()[:200])
    _raises(lambda: read_image(p), "x.png")


def test_non_square_image(tmp_path):
    d = _sdr(tmp_path / "s")
    _photo(d / "01.png", size=(8, 6))
    _raises(lambda: load_capture(d), "01.png", "8x6", "square")


def test_images_of_differing_sizes(tmp_path):
    d = _materialgan(tmp_path / "m")
    _photo(d / "02.png", size=(16, 16))
    _raises(lambda: load_capture(d), "02.png", "16x16", "00.png is 8x8")


def test_read_image_errors(tmp_path):
    _raises(lambda: read_image(tmp_path / "missing.png"), "missing.png", "not found")
    (tmp_path / "t.exr").write_bytes(b"v/1\x01garbage")
    _raises(lambda: read_image(tmp_path / "t.exr"), "t.exr", "EXR")


# ------------------------------------------------------------------ bundles
def _bundle(d):
    views = [View.collocated(RectifiedCamera((0, 0, 10), resolution=4), power=5.0, name=str(i)) for i in range(2)]
    obs = Observations(views, torch.rand(2, 4, 4, 3), mask=torch.ones(2, 4, 4, dtype=torch.bool))
    save_observations(obs, d)
    return d


@pytest.mark.parametrize("value,fragment", [(float("nan"), "NaN"), (-0.5, "negative")])
def test_bundle_bad_pixels(tmp_path, value, fragment):
    d = _bundle(tmp_path / "b")
    img = np.random.default_rng(0).random((4, 4, 3)).astype(np.float32)
    img[1, 2, 0] = value
    write_exr(d / "view_001.exr", img)
    _raises(lambda: load_observations(d), "view_001.exr", fragment)
    _raises(lambda: load_capture(d), "view_001.exr", fragment)


def test_bundle_missing_image_and_keys(tmp_path):
    d = _bundle(tmp_path / "b")
    (d / "mask_000.png").unlink()
    _raises(lambda: load_observations(d), "mask_000.png", "missing")
    (d / "view_000.exr").unlink()
    _raises(lambda: load_observations(d), "view_000.exr", "missing")
    doc = json.loads((d / "observations.json").read_text())
    del doc["surface"]
    (d / "observations.json").write_text(json.dumps(doc))
    _raises(lambda: load_observations(d), "observations.json", "'surface'")


def test_bundle_version_and_malformed(tmp_path):
    d = _bundle(tmp_path / "b")
    doc = json.loads((d / "observations.json").read_text())
    (d / "observations.json").write_text(json.dumps({**doc, "format_version": 99}))
    _raises(lambda: load_observations(d), "observations.json", "format_version 99")
    bad_view = {**doc, "views": [{**doc["views"][0], "view": {"lights": []}}, doc["views"][1]]}
    (d / "observations.json").write_text(json.dumps(bad_view))
    _raises(lambda: load_observations(d), "observations.json", "views[0]")
    (d / "observations.json").write_text("[1, 2")
    _raises(lambda: load_observations(d), "observations.json", "malformed JSON")
    _raises(lambda: load_observations(tmp_path / "empty_dir_missing"), "empty_dir_missing")


def test_bundle_image_size_mismatch(tmp_path):
    d = _bundle(tmp_path / "b")
    write_exr(d / "view_001.exr", np.zeros((5, 5, 3), np.float32))
    _raises(lambda: load_observations(d), "view_001.exr", "5x5")


# ------------------------------------------------------------------ maps
def test_map_folder_errors(tmp_path):
    _raises(lambda: load_svbrdf(tmp_path / "nothing"), "nothing", "does not exist")
    (tmp_path / "maps").mkdir()
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(tmp_path / "maps" / "albedo.png")
    _raises(lambda: load_svbrdf(tmp_path / "maps"), "roughness", "not found")


def test_panel_errors(tmp_path):
    Image.fromarray(np.zeros((4, 12, 3), np.uint8)).save(tmp_path / "panel.png")
    _raises(lambda: load_peer_svbrdf_panel(tmp_path / "panel.png"), "panel.png", "12x4")


def test_zero_length_normals(tmp_path):
    from bayes_brdf.io import save_svbrdf
    from bayes_brdf.render.maps import SVBRDF

    save_svbrdf(SVBRDF.constant(), tmp_path)
    write_exr(tmp_path / "normal.exr", np.zeros((2, 2, 3), np.float32))
    _raises(lambda: load_svbrdf(tmp_path), "normal.exr", "zero-length normals")
