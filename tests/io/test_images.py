"""Image files, colour curves and resampling."""
from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
import torch
from PIL import Image

from bayes_brdf.errors import InputError
from bayes_brdf.io import (linear_to_srgb, read_image, resample, resample_mask, srgb_to_linear, write_exr,
                           write_png)
from bayes_brdf.io.images import read_raw, to_rgb


# ------------------------------------------------------------------ curves
def test_power_law_gamma_is_plain_power():
    x = torch.tensor([0.0, 0.1, 0.5, 1.0], dtype=torch.float64)
    assert torch.allclose(srgb_to_linear(x), x**2.2, rtol=0, atol=1e-15)
    assert torch.allclose(linear_to_srgb(x), x ** (1 / 2.2), rtol=0, atol=1e-15)
    assert torch.allclose(srgb_to_linear(x, 1.8), x**1.8)


def test_exact_srgb_curve_known_values():
    x = torch.tensor([0.0, 0.04045, 0.5, 1.0], dtype=torch.float64)
    y = srgb_to_linear(x, "srgb")
    assert y[0] == 0 and y[3] == pytest.approx(1.0, abs=1e-12)
    assert y[1] == pytest.approx(0.04045 / 12.92, rel=1e-12)  # linear toe
    assert y[2] == pytest.approx(((0.5 + 0.055) / 1.055) ** 2.4, rel=1e-12)
    assert y[2] == pytest.approx(0.214041, abs=1e-6)
    # the two pieces meet (continuity at the knee, both directions)
    lo, hi = srgb_to_linear(torch.tensor([0.04045 - 1e-9, 0.04045 + 1e-9], dtype=torch.float64), "srgb")
    assert abs(float(hi - lo)) < 1e-8
    assert float(linear_to_srgb(torch.tensor(0.0031308, dtype=torch.float64), "srgb")) == pytest.approx(0.04045, abs=1e-6)


@pytest.mark.parametrize("gamma", [2.2, "srgb", 1.0])
def test_curves_are_inverse(gamma):
    x = torch.linspace(0, 1.5, 1001, dtype=torch.float64)
    assert torch.allclose(srgb_to_linear(linear_to_srgb(x, gamma), gamma), x, atol=1e-12)


def test_curves_clamp_negatives_and_keep_numpy():
    out = srgb_to_linear(np.array([-0.5, 0.25]))
    assert isinstance(out, np.ndarray)
    assert out[0] == 0 and out[1] == pytest.approx(0.25**2.2)
    assert torch.all(linear_to_srgb(torch.tensor([-1.0, 0.0])) == 0)


@pytest.mark.parametrize("bad", ["rec709", -2.2, 0, float("nan"), None])
def test_bad_gamma(bad):
    with pytest.raises(InputError, match="gamma"):
        srgb_to_linear(torch.tensor([0.5]), bad)


# ------------------------------------------------------------------ PNG
def test_png8_roundtrip_display_values(tmp_path):
    codes = np.arange(256 * 3, dtype=np.int64).reshape(16, 16, 3) % 256
    img = codes / 255.0
    p = write_png(tmp_path / "a.png", img, linear=False)
    back = read_image(p)
    assert back.dtype == np.float32 and back.shape == (16, 16, 3)
    assert np.array_equal(np.round(back * 255).astype(np.int64), codes)
    assert np.array_equal(np.asarray(Image.open(p)), codes.astype(np.uint8))


def test_png8_linear_encoding(tmp_path):
    lin = torch.rand(8, 8, 3, generator=torch.Generator().manual_seed(0))
    p = write_png(tmp_path / "lin.png", lin)  # gamma 2.2 encoded
    raw = np.asarray(Image.open(p)).astype(np.float64)
    assert np.array_equal(raw, np.round((lin.double().numpy()) ** (1 / 2.2) * 255))
    back = srgb_to_linear(torch.from_numpy(read_image(p)).double())
    assert torch.allclose(back, lin.double(), atol=2.2 * 0.5 / 255 + 1e-9)


def test_png16_rgb_roundtrip_keeps_16_bits(tmp_path):
    rng = np.random.default_rng(1)
    codes = rng.integers(0, 65536, size=(10, 7, 3))
    p = write_png(tmp_path / "b.png", codes / 65535.0, linear=False, bits=16)
    back = read_image(p)
    assert np.array_equal(np.round(back.astype(np.float64) * 65535).astype(np.int64), codes)
    # Pillow alone would only give 8 bits for this file: make sure we did better
    assert len(np.unique(np.round(back * 65535) % 257)) > 1
    assert np.asarray(Image.open(p)).dtype == np.uint8  # (still true: why 16-bit PNGs go through OpenCV)


def test_png16_gray_written_by_pillow(tmp_path):
    a = (np.cumsum(np.random.default_rng(2).integers(0, 3000, (20, 30)), axis=1) % 65535).astype(np.uint16)
    Image.fromarray(a).save(tmp_path / "g.png")  # Pillow uses Sub/Up/Paeth row filters here
    back = read_image(tmp_path / "g.png")
    assert back.shape == (20, 30, 3)
    assert np.array_equal(np.round(back[..., 1] * 65535).astype(np.uint16), a)


def _ihdr(path):
    """(bit depth, colour type) from a PNG file's header."""
    head = path.read_bytes()[:33]
    assert head.startswith(b"\x89PNG\r\n\x1a\n") and head[12:16] == b"IHDR"
    return head[24], head[25]


@pytest.mark.parametrize("bits,chans", [(8, 1), (8, 3), (8, 4), (8, 2), (16, 1), (16, 3), (16, 4)])
def test_write_png_read_raw_roundtrip_is_lossless(tmp_path, bits, chans):
    rng = np.random.default_rng(bits + chans)
    full = 2**bits - 1
    codes = rng.integers(0, full + 1, size=(13, 17, chans))
    codes[4:7] = codes[3]  # some repetition, as in real rows
    codes[0, :4, 0] = [0, full, 1, full - 1]
    p = write_png(tmp_path / "a.png", codes / full, linear=False, bits=bits)
    assert _ihdr(p) == (bits, {1: 0, 2: 4, 3: 2, 4: 6}[chans])
    raw, fs = read_raw(p)
    assert fs == full and raw.dtype == (np.uint8 if bits == 8 else np.uint16)
    assert raw.shape == (13, 17, chans) and np.array_equal(raw, codes)
    back = read_image(p)
    assert back.dtype == np.float32 and back.shape == (13, 17, 3)
    assert np.array_equal(np.round(back.astype(np.float64) * full).astype(np.int64), to_rgb(codes))
    if bits == 8:  # Pillow, an independent decoder, agrees with what we wrote
        assert np.array_equal(np.asarray(Image.open(p)).reshape(codes.shape), codes.astype(np.uint8))


def test_png16_gray_alpha_written_as_rgba(tmp_path):
    ga = np.random.default_rng(7).integers(0, 65536, size=(5, 4, 2))
    p = write_png(tmp_path / "ga.png", ga / 65535, linear=False, bits=16)
    raw, full = read_raw(p)
    assert _ihdr(p) == (16, 6) and full == 65535.0
    assert np.array_equal(raw, ga[..., [0, 0, 0, 1]])
    assert np.array_equal(np.round(read_image(p) * 65535).astype(np.int64), ga[..., [0, 0, 0]])


def _png_by_hand(a: np.ndarray, ftype: int) -> bytes:
    """An independent, minimal PNG encoder (one filter type for every row) to feed the decoder."""
    h, w, c = a.shape
    depth = 16 if a.dtype == np.uint16 else 8
    bpp = c * depth // 8
    x = np.ascontiguousarray(a.astype(">u2") if depth == 16 else a).view(np.uint8).reshape(h, -1).astype(np.int32)
    left = np.zeros_like(x)
    left[:, bpp:] = x[:, :-bpp]
    up = np.zeros_like(x)
    up[1:] = x[:-1]
    ul = np.zeros_like(x)
    ul[1:, bpp:] = x[:-1, :-bpp]
    p = left + up - ul
    pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - ul)
    paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, ul))
    pred = [np.zeros_like(x), left, up, (left + up) >> 1, paeth][ftype]
    rows = np.concatenate([np.full((h, 1), ftype), (x - pred) & 255], axis=1).astype(np.uint8)

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, depth, {1: 0, 2: 4, 3: 2, 4: 6}[c], 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(rows.tobytes()))
            + chunk(b"IEND", b""))


@pytest.mark.parametrize("ftype", [0, 1, 2, 3, 4])
@pytest.mark.parametrize("dtype,chans", [(np.uint8, 3), (np.uint16, 3), (np.uint16, 4), (np.uint16, 1),
                                         (np.uint16, 2), (np.uint8, 2)])
def test_png_from_another_encoder_all_filters(tmp_path, ftype, dtype, chans):
    rng = np.random.default_rng(ftype)
    a = rng.integers(0, np.iinfo(dtype).max + 1, size=(6, 5, chans)).astype(dtype)
    a[2:4] = a[1]
    p = tmp_path / "x.png"
    p.write_bytes(_png_by_hand(a, ftype))
    raw, full = read_raw(p)
    assert raw.dtype == dtype and full == np.iinfo(dtype).max and np.array_equal(raw, a)
    if dtype == np.uint8 and chans == 3:  # Pillow agrees with the hand-made file
        assert np.array_equal(np.asarray(Image.open(p)), a)


def test_corrupt_png16_is_one_input_error(tmp_path, capfd):
    a = np.random.default_rng(8).integers(0, 65536, size=(16, 16, 3)).astype(np.uint16)
    data = bytearray(_png_by_hand(a, 4))
    data[60] ^= 0xFF  # inside the compressed data: the CRC no longer matches
    (tmp_path / "bad.png").write_bytes(bytes(data))
    with pytest.raises(InputError, match="bad.png.*16-bit PNG") as ei:
        read_image(tmp_path / "bad.png")
    assert ei.value.__cause__ is None and (ei.value.__context__ is None or ei.value.__suppress_context__)
    assert capfd.readouterr().err == ""  # the codec's own warnings are not printed


def test_gray_promoted_and_alpha_dropped(tmp_path):
    rgba = np.random.default_rng(3).integers(0, 256, (4, 4, 4)).astype(np.uint8)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
    Image.fromarray(rgba[..., 0], "L").save(tmp_path / "gray.png")
    assert np.array_equal(read_image(tmp_path / "rgba.png"), rgba[..., :3] / np.float32(255))
    g = read_image(tmp_path / "gray.png")
    assert g.shape == (4, 4, 3) and np.array_equal(g[..., 0], g[..., 2])
    assert np.array_equal(g[..., 1], rgba[..., 0] / np.float32(255))


# ------------------------------------------------------------------ EXR
def test_exr_roundtrip_is_exact(tmp_path):
    x = torch.rand(9, 11, 3, generator=torch.Generator().manual_seed(4)) * 50
    x[0, 0] = torch.tensor([1e-8, 0.0, 123456.0])
    back = read_image(write_exr(tmp_path / "x.exr", x))
    assert back.dtype == np.float32 and np.array_equal(back, x.numpy())


def test_exr_single_channel(tmp_path):
    y = np.linspace(0, 2, 12, dtype=np.float32).reshape(3, 4)
    back = read_image(write_exr(tmp_path / "y.exr", y))
    assert back.shape == (3, 4, 3)
    assert all(np.array_equal(back[..., c], y) for c in range(3))


def test_reads_peer_exr_textures(shared_data):
    tex = shared_data / "peer_wiersma" / "experiments" / "scenes" / "plane" / "textures"
    base = read_image(tex / "base_color.exr")
    rough = read_image(tex / "roughness.exr")
    assert base.shape == (64, 64, 3) and rough.shape == (64, 64, 3)
    assert np.isfinite(base).all() and 0 <= rough.min() and rough.max() <= 1
    assert np.array_equal(rough[..., 0], rough[..., 2])
    assert np.array_equal(read_image(tex / "ones.exr"), np.ones((64, 64, 3), np.float32))


# ------------------------------------------------------------------ resampling
def test_resample_shrink_is_block_mean():
    x = torch.rand(2, 32, 32, 3, generator=torch.Generator().manual_seed(5))
    y = resample(x, 4)
    assert y.shape == (2, 4, 4, 3)
    ref = x.reshape(2, 4, 8, 4, 8, 3).mean((2, 4))
    assert torch.allclose(y, ref, atol=1e-6)


def test_resample_non_integer_factor_keeps_mean_of_constant():
    x = torch.full((1, 10, 10, 3), 0.3)
    assert torch.allclose(resample(x, 4), torch.full((1, 4, 4, 3), 0.3))
    assert torch.allclose(resample(x, 23), torch.full((1, 23, 23, 3), 0.3))


def test_resample_grow_is_bilinear():
    x = torch.tensor([[0.0, 1.0]]).reshape(1, 1, 2, 1).expand(1, 2, 2, 1)  # columns 0, 1
    y = resample(x, (2, 4))
    assert torch.allclose(y[0, 0, :, 0], torch.tensor([0.0, 0.25, 0.75, 1.0]))
    same = torch.rand(1, 5, 5, 3)
    assert resample(same, 5) is same


def test_resample_mask_shrink_and_grow():
    m = torch.zeros(1, 8, 8, dtype=torch.bool)
    m[0, 5, 6] = True
    s = resample_mask(m, 4)
    assert s.dtype == torch.bool and s.sum() == 1 and s[0, 2, 3]
    g = resample_mask(torch.tensor([[[True, False], [False, False]]]), 4)
    # a source pixel marks every output pixel whose bilinear stencil uses it: output
    # centres sit at source coordinates -0.25 (clamped), 0.25, 0.75, 1.25 (clamped)
    row = [True, True, True, False]
    assert g[0].tolist() == [row, row, row, [False] * 4]


@pytest.mark.parametrize("bad", [0, -3, 2.5, "x", (4, 0)])
def test_resample_bad_size(bad):
    with pytest.raises(InputError, match="resolution"):
        resample(torch.zeros(1, 4, 4, 3), bad)
