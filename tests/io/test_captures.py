"""Loading real captures (MaterialGAN and svbrdf-diff-renderer formats) as Observations."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from bayes_brdf.io import describe, load_capture, resample_observations
from bayes_brdf.observations import Observations
from bayes_brdf.render.cameras import RectifiedCamera

# folder -> (format, sample size in cm, first camera position)
CAPTURES = {
    "card_blue": ("materialgan", 6.848, (1.0125, 0.2928, 16.7058)),
    "bath_tile": ("svbrdf-diff-renderer", 9.728, (1.8028140285223273, 0.09046427145655384, 10.905497864180116)),
    "yellow_box": ("svbrdf-diff-renderer-optim", 10.88, (-2.7050102829445066, 3.435029964540017, 27.34200636225845)),
}


@pytest.fixture(scope="module")
def captures_128(shared_data):
    return {name: load_capture(shared_data / "captures" / name, resolution=128) for name in CAPTURES}


@pytest.fixture(scope="module")
def card_native(shared_data):
    return load_capture(shared_data / "captures" / "card_blue")


@pytest.mark.parametrize("name", list(CAPTURES))
def test_real_capture_at_128(captures_128, name):
    fmt, size, cam0 = CAPTURES[name]
    obs = captures_128[name]
    assert isinstance(obs, Observations) and len(obs) == 9
    assert obs.images.shape == (9, 128, 128, 3) and obs.images.dtype == torch.float32
    assert 0 <= float(obs.images.min()) and float(obs.images.max()) <= 1
    assert obs.surface.size == pytest.approx(size) and obs.surface.grid == "centers"
    v0 = obs.views[0]
    assert isinstance(v0.camera, RectifiedCamera) and v0.camera.resolution == (128, 128)
    assert v0.camera.position == pytest.approx(cam0)
    assert len(v0.lights) == 1 and v0.lights[0].position == pytest.approx(cam0)  # collocated flash
    assert all(v.lights[0].power == (1500.0, 1500.0, 1500.0) for v in obs.views)
    assert [v.name for v in obs.views] == [f"{i:02d}" for i in range(9)]
    assert obs.mask.dtype == torch.bool and bool(obs.mask.all())
    assert obs.saturated.shape == (9, 128, 128) and obs.saturated.dtype == torch.bool
    assert obs.meta["format"] == fmt and obs.meta["units"] == "cm" and obs.meta["gamma"] == 2.2
    assert obs.meta["native_resolution"] == [1024, 1024]
    assert obs.meta["images"] == [f"{i:02d}.png" for i in range(9)]
    # the flash highlight is clipped in every photo
    assert bool(obs.saturated.flatten(1).any(1).all())


@pytest.mark.parametrize("name", ["bath_tile", "yellow_box"])
def test_real_capture_native(shared_data, name):
    obs = load_capture(shared_data / "captures" / name)
    assert obs.images.shape == (9, 1024, 1024, 3) and obs.views[8].resolution == (1024, 1024)
    frac = obs.saturated.float().mean((1, 2))
    assert bool((frac > 0.003).all()) and bool((frac < 0.03).all())  # 0.35-2.9 % per the data README


def test_native_pixels_are_the_gamma_decoded_photo(shared_data, card_native):
    photo = np.asarray(Image.open(shared_data / "captures" / "card_blue" / "03.png"))
    for r, c in [(512, 300), (0, 0), (1023, 777), (100, 900)]:
        expect = (photo[r, c].astype(np.float64) / 255) ** 2.2
        assert np.allclose(card_native.images[3, r, c].numpy(), expect, rtol=1e-6, atol=1e-9)
    sat = (photo == 255).any(-1)
    assert np.array_equal(card_native.saturated[3].numpy(), sat)
    assert 0.0035 <= sat.mean() <= 0.029


def test_srgb_curve_option(shared_data):
    obs = load_capture(shared_data / "captures" / "card_blue", resolution=128, gamma="srgb")
    assert obs.meta["gamma"] == "srgb"
    photo = np.asarray(Image.open(shared_data / "captures" / "card_blue" / "00.png")).astype(np.float64) / 255
    lin = np.where(photo <= 0.04045, photo / 12.92, ((photo + 0.055) / 1.055) ** 2.4)
    block = lin.reshape(128, 8, 128, 8, 3).mean((1, 3))
    assert np.allclose(obs.images[0].numpy(), block, atol=1e-6)


def test_downsampling_is_linear_area_average_and_saturation_is_max_pooled(card_native, captures_128):
    small = captures_128["card_blue"]
    ref = card_native.images.double().reshape(9, 128, 8, 128, 8, 3).mean((2, 4))
    assert torch.allclose(small.images.double(), ref, atol=1e-6)
    sat_ref = card_native.saturated.reshape(9, 128, 8, 128, 8).any(4).any(2)
    assert torch.equal(small.saturated, sat_ref)
    # every 8x8 block that is fully clipped averages to exactly 1 in all channels it clipped
    assert float(small.images.max()) == pytest.approx(1.0)


def test_resample_observations_matches_load_at_resolution(card_native, captures_128):
    re = resample_observations(card_native, 128)
    assert torch.allclose(re.images, captures_128["card_blue"].images, atol=1e-6)
    assert torch.equal(re.saturated, captures_128["card_blue"].saturated)
    assert re.views[0].camera.resolution == (128, 128)


def test_describe_real_capture(captures_128):
    obs = captures_128["card_blue"]
    text = describe(obs)
    lines = text.splitlines()
    assert "materialgan" in lines[0] and "card_blue" in lines[0]
    assert "views: 9" in lines[1] and "128x128" in lines[1] and "native 1024x1024" in lines[1]
    assert "6.848 x 6.848 cm" in lines[1]
    per_view = [ln for ln in lines if ln.strip().startswith("[")]
    assert len(per_view) == 9
    d0 = math.dist((1.0125, 0.2928, 16.7058), (0, 0, 0))
    assert f"d={d0:.3g}cm" in per_view[0] and "power (1.5e+03, 1.5e+03, 1.5e+03)" in per_view[0]
    sat0 = 100 * float(obs.saturated[0].float().mean())
    assert f"saturated {sat0:.2f}%" in per_view[0]
    x = obs.images[0]
    assert f"{x.min():.4g}/{x.mean():.4g}/{x.max():.4g}" in per_view[0]


# ------------------------------------------------------------------ synthetic captures (no shared data)
def _photo(path, value, size=8, sat_at=None):
    a = np.full((size, size, 3), value, np.uint8)
    if sat_at is not None:
        a[sat_at][1] = 255
    Image.fromarray(a).save(path)


def test_svbrdf_diff_renderer_idx_selects_poses(tmp_path):
    cams = [[0, 0, 10], [1, 0, 10], [2, 0, 10]]
    (tmp_path / "parameters.json").write_text(json.dumps({
        "image_size": 4.0, "idx": [2, 0], "camera_pos": cams, "light_pos": [[c[0], c[1], 11] for c in cams],
        "light_pow": 100}))
    _photo(tmp_path / "00.png", 10)
    _photo(tmp_path / "02.png", 200, sat_at=(3, 4))
    obs = load_capture(tmp_path / "parameters.json")  # a file path works too
    assert [v.name for v in obs.views] == ["02", "00"]
    assert obs.views[0].camera.position == (2.0, 0.0, 10.0) and obs.views[0].lights[0].position == (2.0, 0.0, 11.0)
    assert obs.views[1].camera.position == (0.0, 0.0, 10.0)
    assert obs.views[0].lights[0].power == (100.0, 100.0, 100.0)
    assert float(obs.images[1, 0, 0, 0]) == pytest.approx((10 / 255) ** 2.2, rel=1e-6)
    assert obs.saturated[0].nonzero().tolist() == [[3, 4]] and not bool(obs.saturated[1].any())


def test_svbrdf_diff_renderer_images_in_subfolder(tmp_path):
    (tmp_path / "optim.json").write_text(json.dumps({
        "im_size": 3.0, "idx": [0], "camera_pos": [[0, 0, 5]], "light_pos": [[0, 0, 5]], "light_pow": [1, 2, 3],
        "target_dir": "target/1024"}))
    (tmp_path / "target" / "1024").mkdir(parents=True)
    _photo(tmp_path / "target" / "1024" / "00.png", 128)
    obs = load_capture(tmp_path)
    assert obs.meta["format"] == "svbrdf-diff-renderer-optim" and obs.views[0].lights[0].power == (1.0, 2.0, 3.0)


def test_materialgan_sorts_photos_numerically_and_downsamples(tmp_path):
    n = 11
    for i in range(n):
        _photo(tmp_path / f"{i}.png", 20 * i, size=8, sat_at=(1, 6) if i == 10 else None)
    lines = "\n".join(f"{i},0,20" for i in range(n))
    (tmp_path / "camera_pos.txt").write_text(lines + "\n")
    (tmp_path / "light_pos.txt").write_text(lines + "\n")
    (tmp_path / "image_size.txt").write_text("5.0\n")
    (tmp_path / "light_power.txt").write_text("900\n")
    obs = load_capture(tmp_path, resolution=4)
    assert [v.name for v in obs.views] == [str(i) for i in range(n)]  # 2 before 10
    assert [v.camera.position[0] for v in obs.views] == list(range(n))
    assert obs.images.shape == (n, 4, 4, 3) and obs.views[0].lights[0].power == (900.0,) * 3
    assert float(obs.images[5, 3, 3, 0]) == pytest.approx((100 / 255) ** 2.2, rel=1e-6)
    # downsampling: the clipped pixel marks the one output pixel whose footprint holds it
    assert obs.saturated[10].nonzero().tolist() == [[0, 3]] and not bool(obs.saturated[:10].any())
    assert obs.meta["native_resolution"] == [8, 8]
