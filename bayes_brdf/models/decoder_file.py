"""Decoder weights as safetensors (no pickle): the generator's state, ``w_avg``/``w_std`` and a JSON header.

The header (one metadata entry ``bayes-brdf``) holds ``{"format", "config", "training"}``:
the :class:`~bayes_brdf.models.stylegan.GeneratorConfig` and how the weights were made.
``w_std`` is the per-dimension std of ``mapping(z)``, ``z ~ N(0, I)`` (the Gaussian W+ prior).
A MaterialGAN-layout checkpoint is read by :mod:`bayes_brdf.models.materialgan_checkpoint` instead.

Example:
    >>> import tempfile, os
    >>> from bayes_brdf.models.stylegan import Generator, GeneratorConfig
    >>> g = Generator(GeneratorConfig(resolution=8, w_dim=4, z_dim=4, mapping_layers=1, fmaps_max=4))
    >>> p = os.path.join(tempfile.mkdtemp(), "d.safetensors")
    >>> _ = save_decoder(g, p, training={"steps": 0})
    >>> load_decoder(p).cfg.resolution
    8
"""
from __future__ import annotations

import json
from pathlib import Path

import torch

from ..errors import InputError
from .stylegan import Generator, GeneratorConfig

FORMAT = "bayes-brdf-decoder/1"


def save_decoder(g: Generator, path, *, training: dict | None = None, w_std: torch.Tensor | None = None) -> Path:
    """Write ``g`` to ``path`` (atomically, mode 0644)."""
    from safetensors.torch import save_file

    from ..io.outputs import atomic_path
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    t = {k: v.detach().contiguous().cpu() for k, v in g.state_dict().items()}
    t["w_std"] = (w_std if w_std is not None else getattr(g, "w_std", torch.ones(g.cfg.w_dim))).detach().cpu()
    head = {"format": FORMAT, "config": g.cfg.to_dict(), "training": training or {}}
    with atomic_path(path) as tmp:
        save_file(t, str(tmp), metadata={"bayes-brdf": json.dumps(head, sort_keys=True, default=str)})
    return path


def read_header(path) -> dict:
    """The JSON header of a decoder file (one-line error when it is not one)."""
    from safetensors import safe_open
    path = Path(path)
    if not path.is_file():
        raise InputError("no such decoder weights file", where=path, fix="pass weights = a .safetensors path")
    try:
        with safe_open(str(path), framework="pt") as f:
            md = f.metadata() or {}
        head = json.loads(md.get("bayes-brdf", "{}"))
    except Exception as e:  # noqa: BLE001
        raise InputError(f"unreadable decoder weights ({type(e).__name__})", where=path) from None
    if not isinstance(head, dict) or head.get("format") != FORMAT:
        raise InputError("not a bayes-brdf decoder file", where=path,
                         fix="a MaterialGAN checkpoint loads with bb.models.load_materialgan_checkpoint")
    return head


def is_decoder_file(path) -> bool:
    """Whether ``path`` is a bayes-brdf decoder file (else it may be a MaterialGAN-layout checkpoint)."""
    if Path(path).suffix != ".safetensors":
        return False
    try:
        read_header(path)
    except InputError:
        return False
    return True


def load_decoder(path, *, device=None, dtype=torch.float32) -> Generator:
    """The :class:`Generator` in ``path``, in eval mode with gradients off, with ``w_std`` set."""
    from safetensors.torch import load_file
    head = read_header(path)
    try:
        cfg = GeneratorConfig(**head["config"])
    except TypeError as e:
        raise InputError(f"bad generator config in the decoder file ({e})", where=path) from None
    t = load_file(str(path))
    w_std = t.pop("w_std", torch.ones(cfg.w_dim))
    g = Generator(cfg)
    missing, unexpected = g.load_state_dict(t, strict=False)
    if missing or unexpected:
        raise InputError(f"decoder file does not match its config (missing {missing[:3]}, unexpected {unexpected[:3]})",
                         where=path)
    g.register_buffer("w_std", w_std)
    g.header = head
    g.requires_grad_(False).eval()
    return g.to(device=device, dtype=dtype)
