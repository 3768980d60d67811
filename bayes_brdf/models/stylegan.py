"""A StyleGAN2 "skip" generator for SVBRDF maps: mapping network, W+, per-layer noise, modulated convolutions.

The architecture is MaterialGAN's (a StyleGAN2 config-F generator with skip
outputs, 9 output channels in ``[-1, 1]``) at any size: a 4² learned constant,
then per resolution ``4, 8, ..., R`` one upsampling and one plain modulated 3×3
convolution (the 4² block has only the plain one), each with its own noise map
and its own ``w`` (that is W+), and a 1×1 modulated "to-maps" output per
resolution whose results are upsampled and summed. With ``L = 2 log2(R/4) + 2``
(14 at 256²) there are ``L`` entries of W+ and ``L - 1`` noise maps; layer ``i``
reads ``w[i]``, output ``j`` reads ``w[2j + 1]``.

Parameters are stored at unit scale and scaled at run time ("equalised learning
rate", as StyleGAN2 does): a weight of fan-in ``f`` is multiplied by ``1/sqrt(f)``,
the mapping network's by a further learning-rate factor ``0.01`` (its biases too),
and a style's bias gets ``+1``. Our convolution weights are ``[out, in, k, k]``;
:mod:`bayes_brdf.models.materialgan_checkpoint` maps MaterialGAN's ``[k, k, in, out]``
checkpoint layout onto these modules.

Example:
    >>> g = Generator(GeneratorConfig(resolution=16, w_dim=8, z_dim=8, mapping_layers=2, fmaps_max=8))
    >>> w = g.mapping(torch.randn(2, 8))[:, None].expand(2, g.num_ws, 8)
    >>> g.synthesis(w, g.zero_noise(2)).shape
    torch.Size([2, 9, 16, 16])
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .. import checks
from ..errors import InputError


@dataclass(frozen=True)
class GeneratorConfig:
    """The size of a generator. ``channels(res) = min(fmaps_base // res, fmaps_max)``."""

    resolution: int = 256
    w_dim: int = 512
    z_dim: int = 512
    mapping_layers: int = 8
    fmaps_base: int = 32 << 10
    fmaps_max: int = 512
    out_channels: int = 9
    mapping_lr_mul: float = 0.01

    def __post_init__(self):
        r = self.resolution
        if not (isinstance(r, int) and r >= 8 and r & (r - 1) == 0):
            raise InputError(f"generator resolution must be a power of two >= 8, got {r!r}")
        for k in ("w_dim", "z_dim", "mapping_layers", "fmaps_base", "fmaps_max", "out_channels"):
            checks.count(getattr(self, k), f"generator {k}", least=1)

    @property
    def resolutions(self) -> list[int]:
        return [2 ** k for k in range(2, int(math.log2(self.resolution)) + 1)]

    @property
    def num_ws(self) -> int:
        """Entries of W+ (14 at 256²)."""
        return 2 * len(self.resolutions)

    def channels(self, res: int) -> int:
        return min(self.fmaps_base // res, self.fmaps_max)

    def noise_shapes(self) -> list[tuple[int, int]]:
        """``(res, res)`` of each synthesis layer's noise map, in layer order (13 at 256²)."""
        out = []
        for r in self.resolutions:
            out += [(r, r)] if r == 4 else [(r, r), (r, r)]
        return out

    def to_dict(self) -> dict:
        return asdict(self)


#: MaterialGAN's own size (its checkpoints fit) and the CPU presets of this project
PRESETS = {
    "materialgan": GeneratorConfig(),
    "cpu64": GeneratorConfig(resolution=64, w_dim=128, z_dim=128, mapping_layers=4, fmaps_base=2048, fmaps_max=128),
    "cpu128": GeneratorConfig(resolution=128, w_dim=128, z_dim=128, mapping_layers=4, fmaps_base=2048,
                              fmaps_max=128),
}


def _blur(x: Tensor, pad: tuple[int, int], gain: float) -> Tensor:
    """The [1, 3, 3, 1]² FIR filter (normalised, times ``gain``) per channel, zero padding ``(before, after)``
    on both axes: separable, as two depthwise 1-D convolutions (one 2-D convolution per channel map is ten
    times slower on a CPU, forward and backward)."""
    c = x.shape[1]
    k = torch.tensor([1.0, 3.0, 3.0, 1.0], dtype=x.dtype, device=x.device) / 8
    y = F.pad(x, (pad[0], pad[1], pad[0], pad[1]))
    y = F.conv2d(y, k.reshape(1, 1, 1, 4).expand(c, 1, 1, 4), groups=c)
    y = F.conv2d(y, k.reshape(1, 1, 4, 1).expand(c, 1, 4, 1), groups=c)
    return y * gain


def upsample_maps(x: Tensor) -> Tensor:
    """2× upsampling of the skip outputs: zero insertion, then the FIR filter with gain 4 (``[n, C, 2H, 2W]``)."""
    n, c, h, w = x.shape
    up = torch.zeros(n, c, h, 2, w, 2, dtype=x.dtype, device=x.device)
    up[:, :, :, 0, :, 0] = x
    return _blur(up.reshape(n, c, 2 * h, 2 * w), (2, 1), 4.0)


_KERNELS: dict = {}


def _fir_kernel(c: int, like: Tensor) -> Tensor:
    """The 2-D [1, 3, 3, 1]² filter, normalised (sum 1), as a depthwise weight ``[c, 1, 4, 4]`` (cached)."""
    key = (c, like.dtype, str(like.device))
    k = _KERNELS.get(key)
    if k is None:
        f = torch.tensor([1.0, 3.0, 3.0, 1.0], dtype=torch.float64) / 8
        k = _KERNELS[key] = torch.outer(f, f).to(like).reshape(1, 1, 4, 4).expand(c, 1, 4, 4).contiguous()
    return k


def _upsample_maps_fast(x: Tensor) -> Tensor:
    """:func:`upsample_maps` as one depthwise stride-2 transposed convolution (zero insertion, padding ``(2, 1)``
    and the symmetric 4-tap filter are the transposed convolution's ``padding = 1``); gain 4 on the kernel."""
    return F.conv_transpose2d(x, _fir_kernel(x.shape[1], x) * 4.0, stride=2, padding=1, groups=x.shape[1])


class _Epilogue(torch.autograd.Function):
    """``lrelu(y d + noise + b)`` (``act``; else without the lrelu) with ``d [n, C, 1, 1]``, ``noise [n, 1, H, W]``
    or None, ``b [1, C, 1, 1]``: three passes over ``y``'s size forward (the result written once, then updated in
    place), and a backward that computes only the gradients asked for (autograd's chain of ``mul``, ``add``
    and ``leaky_relu`` allocates a tensor per step each way)."""

    @staticmethod
    def forward(ctx, y, d, noise, b, act):
        out = torch.empty_like(y)
        if noise is None:
            torch.mul(y, d, out=out)
        else:
            torch.addcmul(noise, y, d, out=out)
        out.add_(b)
        if act:
            F.leaky_relu_(out, 0.2)
        ctx.act = act
        ctx.save_for_backward(y, d, out if act else None)
        return out

    @staticmethod
    def backward(ctx, g):
        y, d, out = ctx.saved_tensors
        gp = torch.ops.aten.leaky_relu_backward(g, out, 0.2, True) if ctx.act else g
        need = ctx.needs_input_grad
        gy = gp * d if need[0] else None
        gd = (gp * y).sum((2, 3), keepdim=True) if need[1] else None
        if gd is not None and gd.shape != d.shape:
            gd = gd.sum(0, keepdim=True)
        gn = gp.sum(1, keepdim=True) if need[2] else None
        gb = gp.sum((0, 2, 3), keepdim=True) if need[3] else None
        return gy, gd, gn, gb, None


class Dense(nn.Module):
    """A fully connected layer with run-time weight scaling: ``(x W^T / sqrt(in)) lr + b lr + bias_init``."""

    def __init__(self, n_in: int, n_out: int, *, lr_mul: float = 1.0, bias_init: float = 0.0, act: bool = True):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(n_out, n_in) / lr_mul)
        self.bias = nn.Parameter(torch.zeros(n_out))
        self.scale, self.lr_mul, self.bias_init, self.act = 1 / math.sqrt(n_in), lr_mul, bias_init, act

    def forward(self, x: Tensor) -> Tensor:
        y = F.linear(x, self.weight * (self.scale * self.lr_mul), self.bias * self.lr_mul + self.bias_init)
        return F.leaky_relu(y, 0.2) * math.sqrt(2) if self.act else y


class Mapping(nn.Module):
    """``z [n, z_dim] -> w [n, w_dim]``: pixel norm, then ``mapping_layers`` leaky-ReLU dense layers."""

    def __init__(self, cfg: GeneratorConfig):
        super().__init__()
        dims = [cfg.z_dim] + [cfg.fmaps_max] * (cfg.mapping_layers - 1) + [cfg.w_dim]
        self.layers = nn.ModuleList(Dense(a, b, lr_mul=cfg.mapping_lr_mul) for a, b in zip(dims[:-1], dims[1:]))

    def forward(self, z: Tensor) -> Tensor:
        x = z * torch.rsqrt(z.pow(2).mean(-1, keepdim=True) + 1e-8)
        for layer in self.layers:
            x = layer(x)
        return x


class ModConv(nn.Module):
    """A modulated convolution (per-sample weights scaled by a style from ``w``, optionally demodulated).

    ``up=True``: a transposed stride-2 convolution then the FIR filter (the output is 2× the input);
    with ``noise=True``, ``noise [n, 1, H, W] * noise_strength`` is added before the bias and the
    leaky ReLU (``act``).
    """

    def __init__(self, c_in: int, c_out: int, w_dim: int, k: int = 3, *, up: bool = False, demod: bool = True,
                 noise: bool = True, act: bool = True):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(c_out, c_in, k, k))
        self.bias = nn.Parameter(torch.zeros(c_out))
        self.style = Dense(w_dim, c_in, bias_init=1.0, act=False)
        self.noise_strength = nn.Parameter(torch.zeros(())) if noise else None
        self.k, self.up, self.demod, self.act = k, up, demod, act
        self.scale = 1 / math.sqrt(c_in * k * k)

    def forward(self, x: Tensor, w: Tensor, noise: Tensor | None = None) -> Tensor:
        """The layer on a channels-last ``x``, with as few passes over the activations as the algebra allows.

        The same linear map as :meth:`reference` (StyleGAN2's modulation and demodulation, computed unfused:
        scaling the input channels by the style, convolving with the shared weight, then scaling the output
        channels by the demodulation factor; one batched convolution is several times faster on a CPU than
        n grouped ones), regrouped: the demodulation, the FIR filter's gain and the activation's ``sqrt 2``
        (``lrelu(a y) = a lrelu(y)`` for ``a > 0``) are one per-channel factor applied with the noise and the
        bias in one pass (:class:`_Epilogue`); the FIR filter after the upsampling is one depthwise 4×4
        convolution with its padding (on channels-last memory that is faster than two 1-D ones).
        """
        s = self.style(w)                                                         # [n, in]
        wt = self.weight * self.scale                                             # [out, in, k, k]
        gain = 2.0 ** 0.5 if self.act else 1.0
        y = x * s[:, :, None, None]
        if self.up:
            y = F.conv_transpose2d(y, wt.flip(2, 3).transpose(0, 1), stride=2)
            y = F.conv2d(y, _fir_kernel(y.shape[1], y), padding=1, groups=y.shape[1])
        else:
            y = F.conv2d(y, wt, padding=self.k // 2)
        y_gain = gain * 4.0 if self.up else gain                                 # the FIR filter's gain too
        if self.demod:    # 1 / |modulated weight| per sample and output channel
            d = torch.rsqrt((s * s) @ wt.pow(2).sum((2, 3)).T + 1e-8) * y_gain   # [n, out]
        else:
            d = s.new_full((1, wt.shape[0]), y_gain)
        nz = noise * (self.noise_strength * gain) if self.noise_strength is not None and noise is not None else None
        return _Epilogue.apply(y, d[:, :, None, None], nz, (self.bias * gain)[None, :, None, None], self.act)

    def reference(self, x: Tensor, w: Tensor, noise: Tensor | None = None) -> Tensor:
        """The layer written straightforwardly (the definition :meth:`forward` is tested against)."""
        s = self.style(w)                                                         # [n, in]
        wt = self.weight * self.scale                                             # [out, in, k, k]
        y_in = x * s[:, :, None, None]
        if self.up:
            y = F.conv_transpose2d(y_in, wt.flip(2, 3).transpose(0, 1), stride=2)
        else:
            y = F.conv2d(y_in, wt, padding=self.k // 2)
        if self.demod:    # 1 / |modulated weight| per sample and output channel
            d = torch.rsqrt((s * s) @ wt.pow(2).sum((2, 3)).T + 1e-8)            # [n, out]
            y = y * d[:, :, None, None]
        if self.up:
            y = _blur(y, (1, 1), 4.0)
        if self.noise_strength is not None and noise is not None:
            y = y + noise * self.noise_strength
        y = y + self.bias[None, :, None, None]
        return F.leaky_relu(y, 0.2) * math.sqrt(2) if self.act else y


class Synthesis(nn.Module):
    """``(W+ [n, L, w_dim], noise: list of [n, 1, r, r]) -> maps [n, 9, R, R]`` in channel space."""

    def __init__(self, cfg: GeneratorConfig):
        super().__init__()
        self.cfg = cfg
        res = cfg.resolutions
        self.const = nn.Parameter(torch.randn(1, cfg.channels(4), 4, 4))
        layers, outputs = [], []
        for r in res:
            if r > 4:
                layers.append(ModConv(cfg.channels(r // 2), cfg.channels(r), cfg.w_dim, up=True))
            layers.append(ModConv(cfg.channels(r), cfg.channels(r), cfg.w_dim))
            outputs.append(ModConv(cfg.channels(r), cfg.out_channels, cfg.w_dim, k=1, demod=False, noise=False,
                                   act=False))
        self.layers, self.outputs = nn.ModuleList(layers), nn.ModuleList(outputs)

    def forward(self, ws: Tensor, noise: list[Tensor]) -> Tensor:
        """Computed channels-last (what the CPU's convolutions are fastest on); returns a contiguous tensor."""
        n = ws.shape[0]
        x = self.const.expand(n, -1, -1, -1).contiguous(memory_format=torch.channels_last)
        img = None
        for i, layer in enumerate(self.layers):
            x = layer(x, ws[:, i], noise[i])
            if i % 2 == 0:                    # the end of a resolution block: its to-maps output
                y = self.outputs[i // 2](x, ws[:, i + 1])
                if img is None:
                    img = y
                else:
                    img = _upsample_maps_fast(img) + y
        return img.contiguous()

    def reference(self, ws: Tensor, noise: list[Tensor]) -> Tensor:
        """The synthesis written straightforwardly (:meth:`ModConv.reference`, :func:`upsample_maps`)."""
        n = ws.shape[0]
        x = self.const.expand(n, -1, -1, -1)
        img = None
        for i, layer in enumerate(self.layers):
            x = layer.reference(x, ws[:, i], noise[i])
            if i % 2 == 0:                    # the end of a resolution block: its to-maps output
                y = self.outputs[i // 2].reference(x, ws[:, i + 1])
                img = y if img is None else upsample_maps(img) + y
        return img


class Generator(nn.Module):
    """The whole generator: :class:`Mapping` and :class:`Synthesis`, plus ``w_avg`` (the mean ``w``)."""

    def __init__(self, cfg: GeneratorConfig | str = "cpu64"):
        super().__init__()
        if isinstance(cfg, str):
            if cfg not in PRESETS:
                raise InputError(f"unknown generator preset {cfg!r}", fix=f"use one of {', '.join(PRESETS)}")
            cfg = PRESETS[cfg]
        self.cfg = cfg
        self.mapping = Mapping(cfg)
        self.synthesis = Synthesis(cfg)
        self.register_buffer("w_avg", torch.zeros(cfg.w_dim))

    @property
    def num_ws(self) -> int:
        return self.cfg.num_ws

    def noise_shapes(self) -> list[tuple[int, int]]:
        return self.cfg.noise_shapes()

    def zero_noise(self, n: int, like: Tensor | None = None) -> list[Tensor]:
        """Zero noise maps ``[n, 1, r, r]`` on ``like``'s dtype and device (default: the generator's)."""
        p = self.synthesis.const if like is None else like
        return [torch.zeros(n, 1, *s, dtype=p.dtype, device=p.device) for s in self.noise_shapes()]

    def forward(self, ws: Tensor, noise: list[Tensor]) -> Tensor:
        """Channel-space maps ``[n, 9, R, R]`` from W+ ``[n, L, w_dim]`` and noise maps ``[n, 1, r, r]``."""
        if ws.dim() != 3 or ws.shape[1:] != (self.num_ws, self.cfg.w_dim):
            raise InputError(f"W+ must be [n, {self.num_ws}, {self.cfg.w_dim}], got {list(ws.shape)}")
        return self.synthesis(ws, noise)

    @torch.no_grad()
    def w_stats(self, samples: int = 8192, seed: int = 0) -> tuple[Tensor, Tensor]:
        """Mean and std ``[w_dim]`` of ``mapping(z)`` over ``samples`` standard-normal ``z`` (seeded)."""
        g = torch.Generator().manual_seed(seed + 7)
        z = torch.randn(samples, self.cfg.z_dim, generator=g).to(self.w_avg)
        w = self.mapping(z)
        return w.mean(0), w.std(0)
