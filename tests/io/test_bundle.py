"""Our observation bundle: save_observations / load_observations round trips."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from bayes_brdf.io import load_capture, load_observations, read_image, save_observations
from bayes_brdf.observations import Observations
from bayes_brdf.render.cameras import PerspectiveCamera, RectifiedCamera
from bayes_brdf.render.lights import PointLight
from bayes_brdf.render.surface import PlanarSample
from bayes_brdf.render.views import View


def _synthetic(seed=0, masks=True) -> Observations:
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(3, 6, 6, 3, generator=g) * torch.tensor([1.0, 3.0, 0.2]).reshape(3, 1, 1, 1)
    images[0, 0, 0] = torch.tensor([0.0, 1e-6, 1.0])
    views = [
        View(RectifiedCamera((0.1, -0.2, 15.0), resolution=6), (PointLight((0.1, -0.2, 15.0), power=(1500, 1400, 1300)),), "a"),
        View.collocated(PerspectiveCamera((1.0, 2.0, 3.0), target=(0, 0, 0.5), fov=40.0, resolution=(6, 6)), power=7.0, name="b"),
        View(RectifiedCamera((0.0, 0.0, 9.0), resolution=6),
             (PointLight((1.0, 0.0, 9.0), power=2.0), PointLight((-1.0, 0.0, 9.0), power=3.0, falloff=False))),
    ]
    mask = sat = None
    if masks:
        mask = torch.rand(3, 6, 6, generator=g) > 0.2
        sat = torch.rand(3, 6, 6, generator=g) > 0.8
    return Observations(views, images, PlanarSample(5.5, "endpoints"), mask=mask, saturated=sat,
                        meta={"format": "synthetic", "units": "cm", "gamma": 2.2, "native_resolution": [6, 6]})


def _assert_same_structure(a: Observations, b: Observations):
    assert b.views == a.views
    assert b.surface == a.surface
    for name in ("mask", "saturated"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None and y is None) or torch.equal(x, y)
    assert b.meta == a.meta


def test_exr_roundtrip_is_exact(tmp_path):
    obs = _synthetic()
    path = save_observations(obs, tmp_path / "b")
    assert path.name == "observations.json"
    back = load_observations(tmp_path / "b")
    assert back.images.dtype == torch.float32 and torch.equal(back.images, obs.images)
    _assert_same_structure(obs, back)


def test_png_roundtrip_within_16bit_quantisation(tmp_path):
    obs = _synthetic(1)
    save_observations(obs, tmp_path / "p", image_format="png")
    back = load_observations(tmp_path / "p")
    scale = torch.clamp(obs.images.flatten(1).amax(1), min=1.0).reshape(3, 1, 1, 1)
    err = (back.images - obs.images).abs()
    # max slope of the sRGB decode is 2.28 (at 1): half a 16-bit step is <= 1.8e-5 * scale
    assert bool((err <= 1.8e-5 * scale).all()) and float(err.max()) > 0
    _assert_same_structure(obs, back)
    # the PNG really is 16-bit sRGB-encoded
    doc = json.loads((tmp_path / "p" / "observations.json").read_text())
    e0 = doc["views"][0]
    raw = read_image(tmp_path / "p" / e0["image"])
    x = obs.images[0, 3, 2].double() / e0["scale"]
    enc = torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    assert np.allclose(raw[3, 2], enc.numpy(), atol=0.5 / 65535 + 1e-7)


def test_json_layout(tmp_path):
    obs = _synthetic(masks=False)
    save_observations(obs, tmp_path)
    doc = json.loads((tmp_path / "observations.json").read_text())
    assert doc["format_version"] == 1 and doc["units"] == "cm"
    assert doc["surface"] == {"type": "plane", "size": 5.5, "grid": "endpoints"}
    assert [e["view"] for e in doc["views"]] == [json.loads(json.dumps(v.to_dict())) for v in obs.views]
    assert [e["image"] for e in doc["views"]] == ["view_000.exr", "view_001.exr", "view_002.exr"]
    assert all("mask" not in e for e in doc["views"])
    assert doc["meta"]["format"] == "synthetic"
    back = load_observations(tmp_path / "observations.json")  # the json path works too
    assert back.mask is None and back.saturated is None


def test_masks_are_8bit_pngs(tmp_path):
    obs = _synthetic()
    save_observations(obs, tmp_path)
    m = np.asarray(Image.open(tmp_path / "saturated_001.png"))
    assert m.dtype == np.uint8 and set(np.unique(m)) <= {0, 255}
    assert np.array_equal(m == 255, obs.saturated[1].numpy())


def test_load_capture_recognises_bundle(tmp_path):
    obs = _synthetic()
    save_observations(obs, tmp_path)
    back = load_capture(tmp_path)
    assert torch.equal(back.images, obs.images)
    small = load_capture(tmp_path, resolution=3)
    assert small.images.shape == (3, 3, 3, 3) and small.views[1].camera.resolution == (3, 3)
    assert torch.allclose(small.images, obs.images.reshape(3, 3, 2, 3, 2, 3).mean((2, 4)), atol=1e-6)
    assert torch.equal(small.saturated, obs.saturated.reshape(3, 3, 2, 3, 2).any(4).any(2))
    assert torch.equal(small.mask, obs.mask.reshape(3, 3, 2, 3, 2).all(4).all(2))


def test_real_capture_roundtrip(shared_data, tmp_path):
    obs = load_capture(shared_data / "captures" / "yellow_box", resolution=32)
    save_observations(obs, tmp_path / "yb")
    back = load_capture(tmp_path / "yb")
    assert torch.equal(back.images, obs.images)
    _assert_same_structure(obs, back)
    assert back.meta["format"] == "svbrdf-diff-renderer-optim"


def test_unknown_image_format(tmp_path):
    from bayes_brdf.errors import InputError

    with pytest.raises(InputError, match="jpeg"):
        save_observations(_synthetic(), tmp_path, image_format="jpeg")
