"""A MaterialGAN-layout checkpoint (random, built here from the layout alone) loads and draws the same maps.

The reference forward below is written from the layout's description, one sample at a
time, with explicit zero insertion for every upsampling and no grouped convolutions:
independent of :mod:`bayes_brdf.models.stylegan`'s batched implementation.
"""
import math

import pytest
import torch
import torch.nn.functional as F

from bayes_brdf.errors import InputError
from bayes_brdf.models.materialgan_checkpoint import load_materialgan_checkpoint, materialgan_key_map


def _nf(res, base, fmax):
    return min(base // res, fmax)


def random_materialgan_state(res=16, w_dim=8, z_dim=6, n_map=3, base=64, fmax=8, out=9, seed=0):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g)  # noqa: E731
    sd = {}
    for i in range(n_map):
        d_in, d_out = (z_dim if i == 0 else fmax), (w_dim if i == n_map - 1 else fmax)
        sd[f"mapping.dense{i}.fc.weight"], sd[f"mapping.dense{i}.bias"] = r(d_out, d_in), 0.1 * r(d_out)
    sd["truncation.w_avg"] = r(w_dim)
    sd["synthesis.early_layer.const"] = r(1, _nf(4, base, fmax), 4, 4)
    fir = torch.outer(torch.tensor([1., 3, 3, 1]), torch.tensor([1., 3, 3, 1]))
    layer, resolutions = 0, [2 ** k for k in range(2, int(math.log2(res)) + 1)]
    for j, rr in enumerate(resolutions):
        for up in ([False] if rr == 4 else [True, False]):
            c_in, c_out = _nf(rr // 2 if up else rr, base, fmax), _nf(rr, base, fmax)
            p = f"synthesis.layer{layer}"
            sd[p + ".weight"], sd[p + ".bias"] = r(3, 3, c_in, c_out), 0.1 * r(c_out)
            sd[p + ".style.fc.weight"], sd[p + ".style.bias"] = r(c_in, w_dim), 0.1 * r(c_in)
            sd[p + ".noise_strength"], sd[p + ".noise"] = 0.3 * r(()), r(1, 1, rr, rr)
            if up:
                sd[p + ".filter.kernel"] = (fir / fir.sum() * 4)[:, :, None, None].permute(2, 3, 0, 1)
            layer += 1
        c = _nf(rr, base, fmax)
        p = f"synthesis.output{j}"
        sd[p + ".weight"], sd[p + ".bias"] = r(1, 1, c, out), 0.1 * r(out)
        sd[p + ".style.fc.weight"], sd[p + ".style.bias"] = r(c, w_dim), 0.1 * r(c)
    sd["synthesis.upsample.kernel"] = (fir / fir.sum() * 4)[None, None]
    return sd


def _fir(x, pad_lo, pad_hi):
    k = torch.outer(torch.tensor([1., 3, 3, 1]), torch.tensor([1., 3, 3, 1]))
    k = (k / k.sum() * 4)[None, None]
    c = x.shape[0]
    y = F.pad(x[:, None], (pad_lo, pad_hi, pad_lo, pad_hi))
    return F.conv2d(y, k)[:, 0] if c else y


def _zero_insert(x):
    c, h, w = x.shape
    y = torch.zeros(c, 2 * h, 2 * w)
    y[:, ::2, ::2] = x
    return y


def _modconv(sd, p, x, w, demod=True, up=False, noise=True, act=True):
    """One sample: x [C, H, W], w [w_dim]."""
    wt = sd[p + ".weight"]                                   # [k, k, in, out]
    k, _, c_in, c_out = wt.shape
    style = sd[p + ".style.fc.weight"] @ w / math.sqrt(w.numel()) + sd[p + ".style.bias"] + 1
    wt = wt / math.sqrt(c_in * k * k) * style[None, None, :, None]
    if demod:
        wt = wt / torch.sqrt((wt ** 2).sum((0, 1, 2), keepdim=True) + 1e-8)
    kern = wt.permute(3, 2, 0, 1)                            # [out, in, k, k]
    if up:
        # StyleGAN2's upsampling convolution: zero insertion, then the kernel correlated over the full extent
        z = _zero_insert(x)[:, :-1, :-1]                     # [C, 2H - 1, 2W - 1]
        y = F.conv2d(z[None], kern, padding=k - 1)[0]        # [out, 2H + 1, 2W + 1]
        y = _fir(y, 1, 1)
    else:
        y = F.conv2d(x[None], kern, padding=k // 2)[0]
    if noise:
        y = y + sd[p + ".noise"][0] * sd[p + ".noise_strength"]
    y = y + sd[p + ".bias"][:, None, None]
    return F.leaky_relu(y, 0.2) * math.sqrt(2) if act else y


def reference_forward(sd, ws):
    """ws [L, w_dim] -> [9, R, R] for one sample."""
    x = sd["synthesis.early_layer.const"][0]
    n_layers = sum(1 for k in sd if k.startswith("synthesis.layer") and k.endswith(".noise_strength"))
    img = None
    for i in range(n_layers):
        x = _modconv(sd, f"synthesis.layer{i}", x, ws[i], up=(i % 2 == 1))
        if i % 2 == 0:
            y = _modconv(sd, f"synthesis.output{i // 2}", x, ws[i + 1], demod=False, noise=False, act=False)
            img = y if img is None else _fir(_zero_insert(img), 2, 1) + y
    return img


def reference_mapping(sd, z):
    x = z / torch.sqrt((z ** 2).mean() + 1e-8)
    i = 0
    while f"mapping.dense{i}.fc.weight" in sd:
        wgt = sd[f"mapping.dense{i}.fc.weight"]
        x = wgt @ x / math.sqrt(wgt.shape[1]) * 0.01 + sd[f"mapping.dense{i}.bias"] * 0.01
        x = F.leaky_relu(x, 0.2) * math.sqrt(2)
        i += 1
    return x


def test_key_map_covers_the_documented_names():
    sd = random_materialgan_state()
    km = materialgan_key_map(sd)
    assert km["mapping.dense2.fc.weight"] == "mapping.layers.2.weight"
    assert km["synthesis.layer4.style.fc.weight"] == "synthesis.layers.4.style.weight"
    assert km["synthesis.output2.bias"] == "synthesis.outputs.2.bias"
    assert km["truncation.w_avg"] == "w_avg" and km["synthesis.early_layer.const"] == "synthesis.const"
    assert not any(k.endswith(("kernel", ".noise")) for k in km)


def test_loaded_checkpoint_matches_the_reference_forward():
    sd = random_materialgan_state()
    g, noise = load_materialgan_checkpoint(sd)
    assert g.cfg.resolution == 16 and g.num_ws == 6 and len(noise) == 5 and g.cfg.z_dim == 6
    assert torch.equal(g.w_avg, sd["truncation.w_avg"])
    torch.manual_seed(1)
    ws = torch.randn(2, g.num_ws, g.cfg.w_dim)
    with torch.no_grad():
        ours = g(ws, [n.expand(2, -1, -1, -1) for n in noise])
    for b in range(2):
        ref = reference_forward(sd, ws[b])
        assert ours[b].shape == ref.shape == (9, 16, 16)
        torch.testing.assert_close(ours[b], ref, rtol=1e-4, atol=1e-4)
    z = torch.randn(g.cfg.z_dim)
    torch.testing.assert_close(g.mapping(z[None])[0], reference_mapping(sd, z), rtol=1e-5, atol=1e-6)


def test_materialgan_size_reads_off_the_shapes():
    sd = random_materialgan_state(res=256, w_dim=512, z_dim=512, n_map=8, base=32 << 10, fmax=512)
    g, noise = load_materialgan_checkpoint(sd)
    assert (g.cfg.resolution, g.num_ws, len(noise), g.cfg.mapping_layers) == (256, 14, 13, 8)
    assert g.cfg == type(g.cfg)()          # exactly the "materialgan" preset


def test_bad_checkpoints_are_one_line_errors(tmp_path):
    sd = random_materialgan_state()
    del sd["synthesis.layer3.bias"]
    with pytest.raises(InputError, match="lacks 1 parameters"):
        load_materialgan_checkpoint(sd)
    with pytest.raises(InputError, match="not a MaterialGAN-layout"):
        load_materialgan_checkpoint({"foo": torch.zeros(1)})
    with pytest.raises(InputError, match="no such"):
        load_materialgan_checkpoint(tmp_path / "missing.pt")
    sd = random_materialgan_state()
    torch.save(sd, tmp_path / "ok.pt")
    g, _ = load_materialgan_checkpoint(tmp_path / "ok.pt")
    assert g.cfg.resolution == 16
