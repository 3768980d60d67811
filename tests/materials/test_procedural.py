"""Procedural SVBRDF materials: shapes, ranges, normals, determinism, variation, registry."""
from __future__ import annotations

from functools import lru_cache

import pytest
import torch
import torch.nn.functional as F

from bayes_brdf.errors import InputError
from bayes_brdf.materials import MATERIALS, make_material
from bayes_brdf.materials.noise import fbm, make_generator, texel_grid, voronoi
from bayes_brdf.materials.procedural import height_to_normal
from bayes_brdf.render.maps import SVBRDF

NAMES = sorted(MATERIALS)
METALS = {"scratched_metal"}
CHANNELS = {"albedo": 3, "roughness": 1, "specular": 3, "normal": 3}


@lru_cache(maxsize=None)
def _make(name: str, resolution: int = 64, seed: int = 0, dtype: torch.dtype = torch.float32) -> SVBRDF:
    """Cached: callers must not modify the maps."""
    return MATERIALS[name](resolution, seed, dtype=dtype)


def _check_maps(m: SVBRDF, name: str, resolution: int, dtype: torch.dtype) -> None:
    for key, t in m.items():
        assert t.shape == (CHANNELS[key], resolution, resolution), (key, t.shape)
        assert t.dtype == dtype, (key, t.dtype)
        assert torch.isfinite(t).all(), key
    assert m.albedo.min() >= 0.02 and m.albedo.max() <= 0.95
    assert m.roughness.min() >= 0.05 and m.roughness.max() <= 1.0
    assert m.specular.min() >= 0.02 and m.specular.max() <= 1.0
    n = m.normal.double()
    assert torch.allclose(n.norm(dim=0), torch.ones_like(n[0]), atol=1e-5)
    assert (n[2] > 0).all()
    if name in METALS:
        assert m.specular.amax(0).min() > 0.5 and m.specular.mean() > 0.5, "metal F0 should be high"
        assert m.albedo.max() < 0.1, "metal should have (almost) no diffuse albedo"
    else:
        assert m.specular.min() >= 0.03 and m.specular.max() <= 0.06, "dielectric F0 ~ 0.04"


# ----------------------------------------------------------------------------- per material
@pytest.mark.parametrize("name", NAMES)
def test_shapes_dtypes_and_ranges_float32(name):
    _check_maps(_make(name, 64), name, 64, torch.float32)


@pytest.mark.parametrize("name", NAMES)
def test_float64_when_asked(name):
    m = _make(name, 64, 0, torch.float64)
    _check_maps(m, name, 64, torch.float64)
    # computed in float64 internally: float32 is the same maps, rounded
    m32 = _make(name, 64)
    for key, t in m.items():
        assert torch.allclose(t.float(), getattr(m32, key), atol=1e-6), key


@pytest.mark.parametrize("name", NAMES)
def test_resolution_256_and_scale_independence(name):
    big = _make(name, 256)
    _check_maps(big, name, 256, torch.float32)
    # features are sized in fractions of the sample: 256^2 box-filtered to 64^2 ~ the 64^2 maps
    small = _make(name, 64)
    diff = (F.avg_pool2d(big.albedo[None], 4)[0] - small.albedo).abs().mean()
    assert diff < 0.4 * small.albedo.std() + 1e-3


@pytest.mark.parametrize("name", NAMES)
def test_deterministic_and_independent_of_global_rng(name):
    torch.manual_seed(1)
    a = MATERIALS[name](64, 7)
    torch.manual_seed(12345)
    torch.rand(10)
    state = torch.random.get_rng_state()
    b = MATERIALS[name](64, 7)
    assert torch.equal(torch.random.get_rng_state(), state), "must not advance the global RNG"
    for key, t in a.items():
        assert torch.equal(t, getattr(b, key)), key


@pytest.mark.parametrize("name", NAMES)
def test_different_seeds_differ(name):
    a, b = _make(name, 64, 0), _make(name, 64, 1)
    assert any(not torch.equal(t, getattr(b, k)) for k, t in a.items())
    assert (a.albedo - b.albedo).abs().mean() + (a.roughness - b.roughness).abs().mean() > 1e-3


@pytest.mark.parametrize("name", NAMES)
def test_real_spatial_variation(name):
    m = _make(name, 64)
    assert m.roughness.std() > 0.01 or m.albedo.std() > 0.02
    assert m.roughness.amax() - m.roughness.amin() > 0.08, "roughness should vary spatially"
    tilt = m.normal[:2].norm(dim=0)  # sin of the angle to the macro normal
    assert tilt.max() > 5e-3, "the height field should give non-flat normals"


@pytest.mark.parametrize("name", NAMES)
def test_maps_tile(name):
    """Opposite edges continue each other: the wrap-around step is like an ordinary texel step."""
    m = _make(name, 64)
    for t in (m.albedo, m.roughness):
        for dim in (-1, -2):
            wrap = (t.select(dim, 0) - t.select(dim, -1)).abs().mean()
            inner = (t.narrow(dim, 1, t.shape[dim] - 1) - t.narrow(dim, 0, t.shape[dim] - 1)).abs().mean()
            assert wrap <= 4 * inner + 1e-3, (dim, float(wrap), float(inner))


def test_metal_is_coloured_for_some_seed():
    spreads = [float(_make("scratched_metal", 64, s).specular.mean((1, 2)).std()) for s in range(4)]
    assert max(spreads) > 0.05


def test_roughness_contrast_matches_material_structure():
    # tiles: rough grout (lines) vs glossy faces; metal: glossy base with rough scratches
    r = _make("tiles", 64).roughness[0]
    assert r.quantile(0.1) < 0.3 and r.max() > 0.8
    r = _make("scratched_metal", 64).roughness[0]
    assert r.median() < 0.35 and r.max() > 0.5
    r = _make("marble", 64).roughness[0]
    assert r.median() < 0.15


@pytest.mark.needs_cuda
def test_device_argument_cuda():
    m = make_material("wood", 32, 0, device="cuda")
    assert all(t.device.type == "cuda" for _, t in m.items())
    ref = make_material("wood", 32, 0)
    assert torch.equal(m.albedo.cpu(), ref.albedo)


def test_device_argument_cpu():
    m = make_material("leather", 32, 0, device="cpu")
    assert all(t.device.type == "cpu" for _, t in m.items())


# ----------------------------------------------------------------------------- registry
def test_registry_and_make_material():
    assert {"wood", "tiles", "marble", "scratched_metal", "leather"} <= set(MATERIALS)
    m = make_material("marble", resolution=32, seed=3, dtype=torch.float64)
    assert m.albedo.shape == (3, 32, 32) and m.albedo.dtype == torch.float64
    assert torch.equal(make_material("marble", 32, 3).albedo, MATERIALS["marble"](32, 3).albedo)


def test_unknown_material_is_input_error():
    with pytest.raises(InputError) as e:
        make_material("velvet")
    msg = str(e.value)
    assert "\n" not in msg and "velvet" in msg
    assert all(n in msg for n in MATERIALS)


@pytest.mark.parametrize("bad", [0, 4, 64.0, "64", True])
def test_bad_resolution_is_input_error(bad):
    with pytest.raises(InputError):
        make_material("wood", resolution=bad)


def test_bad_seed_is_input_error():
    with pytest.raises(InputError):
        make_material("wood", 32, seed=1.5)


# ----------------------------------------------------------------------------- building blocks
def test_height_to_normal_orientation():
    """A hill's normals point away from its top: +x right of it, +y above it (row 0 = +y)."""
    u, v = texel_grid(33)
    h = 0.05 * torch.exp(-((u - 0.5) ** 2 + (v - 0.5) ** 2) / 0.02)
    n = height_to_normal(h)
    c = 16
    assert n[0, c, c + 4] > 0.05 and n[0, c, c - 4] < -0.05
    assert n[1, c - 4, c] > 0.05 and n[1, c + 4, c] < -0.05
    assert abs(n[0, c, c]) < 1e-9 and abs(n[1, c, c]) < 1e-9
    # slope is per unit of texture space: a ramp h = s * u has n ~ (-s, 0, 1)/norm in the interior
    n = height_to_normal(0.3 * u)
    assert torch.allclose(n[0, 10, 10], torch.tensor(-0.3 / (1 + 0.09) ** 0.5, dtype=n.dtype), atol=1e-9)


def test_noise_is_periodic_and_seeded():
    u, v = texel_grid(16)
    a = fbm(u, v, make_generator("t", 0), (2, 3), 4)
    b = fbm(u + 1, v - 2, make_generator("t", 0), (2, 3), 4)
    assert torch.allclose(a, b, atol=1e-12)
    assert not torch.equal(a, fbm(u, v, make_generator("t", 1), (2, 3), 4))
    vo, vo2 = voronoi(u, v, 5, make_generator("c", 0)), voronoi(u + 1, v + 1, 5, make_generator("c", 0))
    assert torch.allclose(vo.f1, vo2.f1, atol=1e-12) and torch.equal(vo.cell, vo2.cell)
    assert (vo.f2 >= vo.f1).all() and (vo.cell >= 0).all() and (vo.cell < 25).all()
