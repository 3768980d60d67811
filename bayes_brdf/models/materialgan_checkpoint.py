"""Load a MaterialGAN-layout generator checkpoint (a user's own file; nothing is ever downloaded).

MaterialGAN's generator (a port of the higan StyleGAN2 generator) names its
parameters as below; :func:`materialgan_key_map` maps each onto
:class:`~bayes_brdf.models.stylegan.Generator`:

======================================================  =============================================
MaterialGAN key                                         bayes-brdf key (and layout change)
======================================================  =============================================
``mapping.dense{i}.fc.weight`` ``[out, in]``            ``mapping.layers.{i}.weight`` (same)
``mapping.dense{i}.bias``                               ``mapping.layers.{i}.bias``
``truncation.w_avg``                                    ``w_avg``
``synthesis.early_layer.const`` ``[1, C, 4, 4]``        ``synthesis.const``
``synthesis.layer{i}.weight`` ``[k, k, in, out]``       ``synthesis.layers.{i}.weight`` ``[out, in, k, k]``
``synthesis.layer{i}.bias``                             ``synthesis.layers.{i}.bias``
``synthesis.layer{i}.style.fc.weight`` / ``.style.bias``  ``synthesis.layers.{i}.style.weight`` / ``.bias``
``synthesis.layer{i}.noise_strength``                   ``synthesis.layers.{i}.noise_strength``
``synthesis.layer{i}.noise`` ``[1, 1, r, r]``           returned as the checkpoint's noise maps
``synthesis.output{j}.*`` (1×1, no noise)               ``synthesis.outputs.{j}.*`` (as the layers)
``*.filter.kernel``, ``synthesis.upsample.kernel``      checked to be the [1, 3, 3, 1] FIR, not stored
======================================================  =============================================

Both sides store weights at unit scale and apply the same run-time scales
(``1/sqrt(fan in)``, the mapping's learning-rate factor 0.01, the style bias ``+1``),
so the values are copied as they are. The generator's size (resolution, latent
widths, mapping depth, channels per resolution) is read off the shapes.

Example: see ``tests/models/test_materialgan_checkpoint.py`` (a random state dict in this layout).
"""
from __future__ import annotations

import re
from pathlib import Path

import torch
from torch import Tensor

from ..errors import InputError
from .stylegan import Generator, GeneratorConfig

_FIR = torch.tensor([1.0, 3.0, 3.0, 1.0])


def materialgan_key_map(keys) -> dict[str, str]:
    """``{materialgan key: bayes-brdf key}`` for the parameter keys in ``keys`` (buffers and kernels left out)."""
    out = {}
    for k in keys:
        m = re.fullmatch(r"mapping\.dense(\d+)\.(fc\.weight|bias)", k)
        if m:
            out[k] = f"mapping.layers.{m[1]}.{'weight' if m[2] == 'fc.weight' else 'bias'}"
            continue
        m = re.fullmatch(r"synthesis\.(layer|output)(\d+)\.(weight|bias|style\.fc\.weight|style\.bias|noise_strength)", k)
        if m:
            part = {"style.fc.weight": "style.weight"}.get(m[3], m[3])
            out[k] = f"synthesis.{'layers' if m[1] == 'layer' else 'outputs'}.{m[2]}.{part}"
            continue
        if k == "truncation.w_avg":
            out[k] = "w_avg"
        elif k == "synthesis.early_layer.const":
            out[k] = "synthesis.const"
    return out


def _read(src) -> dict[str, Tensor]:
    if isinstance(src, dict):
        return src
    p = Path(src)
    if not p.is_file():
        raise InputError("no such MaterialGAN checkpoint", where=p)
    try:
        if p.suffix == ".safetensors":
            from safetensors.torch import load_file
            sd = load_file(str(p))
        else:   # a torch file: tensors only (weights_only refuses code), never a pickle that runs code
            sd = torch.load(str(p), map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001
        raise InputError(f"unreadable MaterialGAN checkpoint ({type(e).__name__}: {e})".split("\n")[0], where=p) from None
    for key in ("generator", "generator_smooth", "state_dict"):
        if isinstance(sd, dict) and isinstance(sd.get(key), dict):
            sd = sd[key]
    if not isinstance(sd, dict):
        raise InputError("a MaterialGAN checkpoint must hold a state dict", where=p)
    return sd


def _config(sd: dict[str, Tensor]) -> GeneratorConfig:
    need = ("mapping.dense0.fc.weight", "synthesis.early_layer.const", "synthesis.output0.weight")
    missing = [k for k in need if k not in sd]
    if missing:
        raise InputError(f"not a MaterialGAN-layout checkpoint: no {missing[0]}",
                         fix="expected keys mapping.dense{0-7}.*, synthesis.early_layer.const, synthesis.layer{i}.*")
    n_map = 1 + max(int(m[1]) for k in sd if (m := re.fullmatch(r"mapping\.dense(\d+)\.fc\.weight", k)))
    n_out = 1 + max(int(m[1]) for k in sd if (m := re.fullmatch(r"synthesis\.output(\d+)\.weight", k)))
    res = 4 * 2 ** (n_out - 1)
    ch = {4 * 2 ** j: int(sd[f"synthesis.output{j}.weight"].shape[2]) for j in range(n_out)}
    fmax = max(ch.values())
    below = [r for r, c in ch.items() if c < fmax]
    fbase = ch[min(below)] * min(below) if below else fmax * res
    w_dim = int(sd[f"mapping.dense{n_map - 1}.fc.weight"].shape[0])
    cfg = GeneratorConfig(resolution=res, w_dim=w_dim, z_dim=int(sd["mapping.dense0.fc.weight"].shape[1]),
                          mapping_layers=n_map, fmaps_base=fbase, fmaps_max=fmax,
                          out_channels=int(sd["synthesis.output0.weight"].shape[3]))
    bad = [r for r in ch if cfg.channels(r) != ch[r]]
    if bad:
        raise InputError(f"channel counts of the checkpoint ({ch}) follow no min(base / res, max) rule")
    return cfg


def load_materialgan_checkpoint(src) -> tuple[Generator, list[Tensor]]:
    """A :class:`Generator` and the checkpoint's noise maps (``[1, 1, r, r]`` each; zeros where absent).

    ``src`` is a state dict or a file (``.safetensors``, or a torch file of tensors only).
    """
    sd = _read(src)
    cfg = _config(sd)
    for k, v in sd.items():
        if k.endswith("kernel"):
            ref = torch.outer(_FIR, _FIR)
            v = v.detach().to(torch.float32)
            if v.numel() != 16 or not torch.allclose(v.reshape(4, 4) / v.sum(), ref / ref.sum(), atol=1e-6):
                raise InputError(f"checkpoint kernel {k} {list(v.shape)} is not the [1, 3, 3, 1] FIR filter")
    g = Generator(cfg)
    mine = g.state_dict()
    kmap = materialgan_key_map(sd)
    new = {}
    for src_key, dst in kmap.items():
        v = sd[src_key].detach().to(torch.float32)
        if src_key.endswith(".weight") and ".style." not in src_key and src_key.startswith("synthesis.") and v.dim() == 4:
            v = v.permute(3, 2, 0, 1)        # [k, k, in, out] -> [out, in, k, k]
        if dst not in mine or mine[dst].shape != v.shape:
            raise InputError(f"checkpoint key {src_key} {list(v.shape)} does not fit {dst} "
                             f"{list(mine[dst].shape) if dst in mine else '(none)'}")
        new[dst] = v
    absent = sorted(set(mine) - set(new) - {"w_avg"})
    if absent:
        raise InputError(f"the checkpoint lacks {len(absent)} parameters, e.g. {absent[0]}")
    new.setdefault("w_avg", torch.zeros(cfg.w_dim))
    g.load_state_dict(new)
    noise = [sd.get(f"synthesis.layer{i}.noise", torch.zeros(1, 1, *s)).to(torch.float32).reshape(1, 1, *s)
             for i, s in enumerate(cfg.noise_shapes())]
    return g, noise
