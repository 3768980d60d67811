"""File content vs. file name, stray images in capture folders, and no silent upsampling.

Every bad input is ONE-line :class:`InputError` naming the file (or folder), what is wrong and
how to fix it; the malformed capture folders are built under ``tmp_path`` from small copies.
"""
from __future__ import annotations

import shutil
import warnings

import numpy as np
import pytest
import torch
from PIL import Image

from bayes_brdf.errors import InputError
from bayes_brdf.io import (load_capture, load_observations, load_svbrdf, read_image, save_observations, save_svbrdf,
                           write_exr, write_png)
from bayes_brdf.io.images import read_raw, sniff_format
from bayes_brdf.observations import Observations
from bayes_brdf.render.cameras import RectifiedCamera
from bayes_brdf.render.maps import SVBRDF
from bayes_brdf.render.views import View

from .helpers import raises_one_line

POSE_FILES = ("camera_pos.txt", "light_pos.txt", "image_size.txt", "light_power.txt")


_raises = raises_one_line


@pytest.fixture(scope="module")
def small_card(shared_data, tmp_path_factory):
    """card_blue (MaterialGAN) with its pose files copied and its nine photos shrunk to 16 x 16."""
    src = shared_data / "captures" / "card_blue"
    d = tmp_path_factory.mktemp("card_blue_16")
    for name in POSE_FILES:
        shutil.copy(src / name, d / name)
    for i in range(9):
        with Image.open(src / f"{i:02d}.png") as im:
            im.convert("RGB").resize((16, 16), Image.BOX).save(d / f"{i:02d}.png")
    return d


@pytest.fixture
def card(small_card, tmp_path):
    """A fresh, writable copy of the small card_blue capture for one test."""
    return shutil.copytree(small_card, tmp_path / "card")


def _exr(path, value=0.25, size=4):
    return write_exr(path, np.full((size, size, 3), value, np.float32))


# ------------------------------------------------------------------ 3. content, not name
def test_sniff_format_reads_content(tmp_path):
    write_png(tmp_path / "a.png", np.zeros((2, 2, 3)), linear=False)
    _exr(tmp_path / "b.exr")
    Image.fromarray(np.zeros((2, 2, 3), np.uint8)).save(tmp_path / "c.jpg", format="JPEG")
    Image.fromarray(np.zeros((2, 2, 3), np.uint8)).save(tmp_path / "d.tif", format="TIFF")
    (tmp_path / "e.png").write_bytes(b"hello")
    got = [sniff_format(tmp_path / n) for n in ("a.png", "b.exr", "c.jpg", "d.tif", "e.png")]
    assert got == ["PNG", "OpenEXR", "JPEG", "TIFF", None]


@pytest.mark.parametrize("bits", [8, 16])
def test_png_named_exr_is_refused(tmp_path, bits):
    p = write_png(tmp_path / "a.png", np.full((4, 4, 3), 0.5), linear=False, bits=bits)
    p.rename(tmp_path / "albedo.exr")
    _raises(lambda: read_image(tmp_path / "albedo.exr"), "albedo.exr", "PNG image", "ends in .exr",
            "rename it to albedo.png")


def test_exr_named_png_is_refused(tmp_path):
    _exr(tmp_path / "x.exr").rename(tmp_path / "00.png")
    _raises(lambda: read_image(tmp_path / "00.png"), "00.png", "OpenEXR", "ends in .png", "rename it to 00.exr")
    _raises(lambda: read_raw(tmp_path / "00.png"), "00.png", "OpenEXR")
    # linear EXR data under any other image name is refused as well (it would be taken as display codes)
    shutil.copy(tmp_path / "00.png", tmp_path / "00.jpg")
    _raises(lambda: read_image(tmp_path / "00.jpg"), "00.jpg", "OpenEXR", "rename it to 00.exr")


def test_jpeg_named_png_is_refused(tmp_path):
    Image.fromarray(np.full((4, 4, 3), 77, np.uint8)).save(tmp_path / "01.png", format="JPEG")
    _raises(lambda: read_image(tmp_path / "01.png"), "01.png", "JPEG image", "ends in .png", "01.jpg",
            "lossless PNG")


def test_not_an_exr_named_exr(tmp_path):
    (tmp_path / "r.exr").write_bytes(b"\x00" * 64)
    _raises(lambda: read_image(tmp_path / "r.exr"), "r.exr", "not an OpenEXR file", "magic number")


def test_names_without_a_checked_extension_are_read_by_content(tmp_path):
    x = np.random.default_rng(0).random((3, 5, 3)).astype(np.float32)
    write_exr(tmp_path / "a.exr", x).rename(tmp_path / "radiance")            # no extension: EXR by content
    assert np.array_equal(read_image(tmp_path / "radiance"), x)
    codes = np.arange(45, dtype=np.uint8).reshape(3, 5, 3)
    write_png(tmp_path / "b.png", codes / 255, linear=False).rename(tmp_path / "photo.jpg")  # a PNG named .jpg
    assert np.array_equal(np.round(read_image(tmp_path / "photo.jpg") * 255).astype(np.uint8), codes)
    write_png(tmp_path / "UPPER.PNG", codes / 255, linear=False)             # case of the extension is ignored
    assert np.array_equal(np.round(read_image(tmp_path / "UPPER.PNG") * 255).astype(np.uint8), codes)


def test_exr_named_png_in_a_capture(card):
    _exr(card / "x.exr", size=16).replace(card / "04.png")
    _raises(lambda: load_capture(card), "04.png", "OpenEXR", "rename it to 04.exr")


def test_exr_named_png_in_a_map_folder(tmp_path):
    save_svbrdf(SVBRDF.constant(albedo=0.5), tmp_path)
    (tmp_path / "albedo.exr").unlink()
    _exr(tmp_path / "x.exr").replace(tmp_path / "albedo.png")                  # the preview replaced by EXR data
    _raises(lambda: load_svbrdf(tmp_path), "albedo.png", "OpenEXR")


def test_png_named_exr_in_a_bundle(tmp_path):
    views = [View.collocated(RectifiedCamera((0, 0, 10), resolution=4), power=5.0, name=str(i)) for i in range(2)]
    save_observations(Observations(views, torch.rand(2, 4, 4, 3)), tmp_path)
    write_png(tmp_path / "view_001.exr", torch.rand(4, 4, 3), bits=16)
    _raises(lambda: load_observations(tmp_path), "view_001.exr", "PNG image", "rename it to view_001.png")


# ------------------------------------------------------------------ 4. stray images in a MaterialGAN folder
def test_small_card_loads_without_warnings(card):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        obs = load_capture(card)
    assert len(obs) == 9 and obs.images.shape == (9, 16, 16, 3) and obs.meta["format"] == "materialgan"


def test_numbered_exr_among_the_pngs_is_an_error(card):
    _exr(card / "09.exr", size=16)
    msg = _raises(lambda: load_capture(card), "09.exr", "an OpenEXR image numbered like the photos but not a PNG",
                  "NN.png", "09.png", "move it out")
    assert "left out" in msg


def test_numbered_exr_replacing_a_png_is_an_error(card):
    (card / "04.png").unlink()
    _exr(card / "04.exr", size=16)  # without the check this reads as "9 camera positions but 8 photos"
    _raises(lambda: load_capture(card), "04.exr", "OpenEXR", "not a PNG")


def test_several_numbered_non_png_images(card):
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(card / "10.jpg", format="JPEG")
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(card / "11.tif", format="TIFF")
    _raises(lambda: load_capture(card), str(card), "10.jpg (a JPEG image)", "11.tif (a TIFF image)",
            "are numbered like the photos but not PNGs", "move them out")


def test_two_photos_with_one_index(card):
    shutil.copy(card / "03.png", card / "3.png")
    _raises(lambda: load_capture(card), str(card), "03.png and 3.png", "same index 3")


def test_unnumbered_images_are_ignored_with_a_warning(card):
    Image.fromarray(np.zeros((16, 16, 3), np.uint8)).save(card / "preview.jpg", format="JPEG")
    _exr(card / "normal.exr")
    (card / "notes.txt").write_text("not an image: no warning for it\n")
    with pytest.warns(UserWarning, match=r"ignoring 2 image file\(s\) not named NN.png: normal.exr, preview.jpg") as w:
        obs = load_capture(card)
    assert len(w) == 1 and "notes.txt" not in str(w[0].message)
    assert len(obs) == 9 and obs.meta["images"] == [f"{i:02d}.png" for i in range(9)]


def test_sdr_missing_png_names_the_other_file(tmp_path):
    import json

    d = tmp_path / "s"
    d.mkdir()
    for i in range(3):
        Image.fromarray(np.full((8, 8, 3), 90, np.uint8)).save(d / f"{i:02d}.png")
    (d / "parameters.json").write_text(json.dumps({
        "image_size": 9.7, "idx": [0, 1, 2], "camera_pos": [[i, 0, 10] for i in range(3)],
        "light_pos": [[i, 0, 10] for i in range(3)], "light_pow": [1500, 1500, 1500]}))
    (d / "02.png").unlink()
    _exr(d / "02.exr", size=8)
    _raises(lambda: load_capture(d), "02.png", "missing", "there is 02.exr", "parameters.json")


# ------------------------------------------------------------------ 5. resolution: never upsample
def test_resolution_above_native_is_an_error(card):
    msg = _raises(lambda: load_capture(card, resolution=5000), str(card),
                  "--resolution 5000 is above the photos' native 16", "use at most 16")
    assert "upsampl" in msg
    _raises(lambda: load_capture(card, resolution=17), "native 16")
    same = load_capture(card, resolution=16)
    assert same.images.shape == (9, 16, 16, 3)
    assert torch.equal(same.images, load_capture(card).images)


def test_resolution_above_native_on_the_real_photos(shared_data):
    _raises(lambda: load_capture(shared_data / "captures" / "bath_tile", resolution=5000),
            "bath_tile", "--resolution 5000 is above the photos' native 1024", "use at most 1024")


def test_max_resolution_caps_only_the_default(card):
    assert load_capture(card, max_resolution=8).images.shape == (9, 8, 8, 3)
    native = load_capture(card, max_resolution=128)                       # above native: native size
    assert native.images.shape == (9, 16, 16, 3) and native.meta["native_resolution"] == [16, 16]
    assert load_capture(card, resolution=16, max_resolution=8).images.shape == (9, 16, 16, 3)  # explicit wins
    assert load_capture(card, resolution=4, max_resolution=8).images.shape == (9, 4, 4, 3)
    _raises(lambda: load_capture(card, resolution=32, max_resolution=8), "--resolution 32", "native 16")


@pytest.mark.parametrize("bad", [0, -4, 2.5, "x", (8, 4)])
def test_bad_max_resolution(card, bad):
    _raises(lambda: load_capture(card, max_resolution=bad), "max_resolution")


def test_non_square_resolution_is_refused(card):
    _raises(lambda: load_capture(card, resolution=(8, 4)), "resolution", "square")


def test_bundle_is_never_upsampled(tmp_path):
    views = [View.collocated(RectifiedCamera((0, 0, 10), resolution=6), power=5.0, name=str(i)) for i in range(2)]
    obs = Observations(views, torch.rand(2, 6, 6, 3))
    save_observations(obs, tmp_path)
    _raises(lambda: load_capture(tmp_path, resolution=12), "--resolution 12 is above the bundle's native 6",
            "use at most 6")
    assert load_capture(tmp_path, max_resolution=3).images.shape == (2, 3, 3, 3)
    assert load_capture(tmp_path, max_resolution=3).views[0].camera.resolution == (3, 3)
    back = load_capture(tmp_path, max_resolution=128)
    assert back.images.shape == (2, 6, 6, 3) and torch.equal(back.images, obs.images)
