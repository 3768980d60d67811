"""SVBRDF map folders and the DeepInverseRendering 4-panel PNG."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from bayes_brdf.errors import InputError
from bayes_brdf.io import load_peer_svbrdf_panel, load_svbrdf, save_svbrdf
from bayes_brdf.render.maps import SVBRDF


def _maps(seed=0) -> SVBRDF:
    g = torch.Generator().manual_seed(seed)
    n = torch.randn(3, 8, 8, generator=g) * 0.3
    n[2] = 1.0
    return SVBRDF(albedo=torch.rand(3, 8, 8, generator=g), roughness=torch.rand(1, 4, 4, generator=g) * 0.9 + 0.05,
                  specular=torch.rand(3, 8, 8, generator=g) * 0.1, normal=n / n.norm(dim=0, keepdim=True))


def test_exr_roundtrip_exact_and_previews(tmp_path):
    m = _maps()
    save_svbrdf(m, tmp_path)
    for name in ("albedo", "roughness", "specular", "normal"):
        assert (tmp_path / f"{name}.exr").is_file() and (tmp_path / f"{name}.png").is_file()
    back = load_svbrdf(tmp_path)
    for name, t in m.items():
        got = getattr(back, name)
        assert got.dtype == torch.float32 and torch.equal(got, t), name
    # previews: albedo gamma 2.2, roughness linear, normal n*0.5+0.5
    alb = np.asarray(Image.open(tmp_path / "albedo.png")).astype(np.float64)
    assert np.array_equal(alb, np.round(m.albedo.permute(1, 2, 0).double().numpy() ** (1 / 2.2) * 255))
    rgh = np.asarray(Image.open(tmp_path / "roughness.png")).astype(np.float64)
    assert rgh.shape == (4, 4) and np.array_equal(rgh, np.round(m.roughness[0].double().numpy() * 255))
    nrm = np.asarray(Image.open(tmp_path / "normal.png")).astype(np.float64)
    assert np.array_equal(nrm, np.round((m.normal.permute(1, 2, 0).double().numpy() * 0.5 + 0.5) * 255))


def test_png_fallback(tmp_path):
    m = _maps(1)
    save_svbrdf(m, tmp_path)
    for p in tmp_path.glob("*.exr"):
        p.unlink()
    back = load_svbrdf(tmp_path)
    assert back.roughness.shape == (1, 4, 4) and back.albedo.shape == (3, 8, 8)
    assert torch.allclose(back.albedo, m.albedo, atol=2.2 * 0.5 / 255)
    assert torch.allclose(back.specular, m.specular, atol=2.2 * 0.5 / 255)
    assert torch.allclose(back.roughness, m.roughness, atol=0.5 / 255 + 1e-7)
    assert torch.allclose(back.normal.norm(dim=0), torch.ones(8, 8), atol=1e-5)
    assert float((back.normal * m.normal).sum(0).min()) > 0.9999  # within ~1 degree


def test_svbrdf_diff_renderer_texture_names(tmp_path):
    Image.fromarray(np.full((4, 4, 3), 128, np.uint8)).save(tmp_path / "dif.png")
    Image.fromarray(np.full((4, 4, 3), 10, np.uint8)).save(tmp_path / "spe.png")
    Image.fromarray(np.full((4, 4), 51, np.uint8)).save(tmp_path / "rgh.png")
    Image.fromarray(np.tile(np.array([128, 128, 255], np.uint8), (4, 4, 1))).save(tmp_path / "nom.png")
    m = load_svbrdf(tmp_path)
    assert torch.allclose(m.albedo, torch.full((3, 4, 4), (128 / 255) ** 2.2))
    assert torch.allclose(m.specular, torch.full((3, 4, 4), (10 / 255) ** 2.2))
    assert torch.allclose(m.roughness, torch.full((1, 4, 4), 0.2))
    assert torch.allclose(m.normal[:, 0, 0], torch.tensor([1 / 255, 1 / 255, 1.0]) / np.sqrt(2 / 255**2 + 1), atol=1e-6)


def test_particle_maps(tmp_path):
    one = SVBRDF(*(t[None] for _, t in _maps().items()))
    save_svbrdf(one, tmp_path)
    assert load_svbrdf(tmp_path).albedo.shape == (3, 8, 8)
    many = SVBRDF(*(t[None].expand(2, *t.shape) for _, t in _maps().items()))
    with pytest.raises(InputError, match="particle"):
        save_svbrdf(many, tmp_path / "x")


def test_synthetic_panel(tmp_path):
    h = 4
    panel = np.zeros((h, 4 * h, 3), np.uint8)
    panel[:, 0:h] = (128, 128, 255)          # flat-ish normal
    panel[:, h:2 * h] = (200, 100, 50)       # diffuse, gamma 2.2
    panel[:, 2 * h:3 * h] = (60, 90, 120)    # roughness, channels averaged
    panel[:, 3 * h:] = (10, 20, 30)          # specular, linear
    Image.fromarray(panel).save(tmp_path / "panel.png")
    m = load_peer_svbrdf_panel(tmp_path / "panel.png")
    assert m.albedo.shape == (3, h, h) and m.roughness.shape == (1, h, h) and m.albedo.dtype == torch.float32
    assert torch.allclose(m.albedo[:, 0, 0], (torch.tensor([200, 100, 50]) / 255.0) ** 2.2)
    assert float(m.roughness[0, 1, 1]) == pytest.approx(90 / 255, rel=1e-6)
    assert torch.allclose(m.specular[:, 2, 3], torch.tensor([10, 20, 30]) / 255.0)
    n = torch.tensor([128, 128, 255]) / 255.0 * 2 - 1
    assert torch.allclose(m.normal[:, 3, 3], n / n.norm(), atol=1e-6)


def test_real_peer_panel(shared_data):
    d = shared_data / "peer_synthetic" / "example_data" / "example_svbrdf"
    path = sorted(d.glob("0000066*.png"))[0]
    m = load_peer_svbrdf_panel(path)
    assert m.normal.shape == (3, 256, 256) and m.roughness.shape == (1, 256, 256)
    assert torch.allclose(m.normal.norm(dim=0), torch.ones(256, 256), atol=1e-5)
    assert float(m.normal[2].min()) > 0  # normals point out of the surface
    raw = np.asarray(Image.open(path)).astype(np.float64) / 255
    assert np.allclose(m.albedo[:, 100, 37].numpy(), raw[100, 256 + 37] ** 2.2, rtol=1e-6)
    assert np.allclose(m.specular[:, 5, 200].numpy(), raw[5, 768 + 200], rtol=1e-6)
    assert float(m.roughness[0, 17, 19]) == pytest.approx(raw[17, 512 + 19].mean(), rel=1e-6)
    assert 0 <= float(m.roughness.min()) and float(m.roughness.max()) <= 1
