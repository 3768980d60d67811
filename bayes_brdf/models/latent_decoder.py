"""The ``latent_decoder`` model: SVBRDF maps decoded by a StyleGAN2 generator from W+ and noise (Fig. 6).

Sites (per particle): ``w_plus [L, w_dim]`` (one ``w`` per synthesis layer; ``L = 10`` for
the 64² decoder, 14 for MaterialGAN's) and, with ``noise = "infer"``, ``noise [N]`` (the
generator's noise maps, flattened in layer order; ``N = 10 896`` at 64²). Priors:

* ``prior = "flat"`` (the paper's): W+ is unconstrained with density 1 (improper); the
  posterior is the likelihood's;
* ``prior = "gaussian"``: each entry of W+ ``Normal(w_avg, prior_scale * w_std)``, the
  mean and std of ``w = mapping(z)``, ``z ~ N(0, I)`` (stored with the weights);
* the noise maps are ``Normal(0, 1)`` as the generator was trained with.

The maps go through :func:`~bayes_brdf.models.svbrdf_channels.decode` (MaterialGAN's
decoding) into the same likelihood and renderer as ``per_texel``, so a plane or a mesh,
every sampler, Eq. 9 (in map space, :meth:`Posterior.std`), Eq. 11 and guidance work as
for the per-texel model.

**Normals** (``normals``): ``"decoded"`` (the default) renders the generator's normal map, which varies per
particle; ``"flat"`` renders the surface's own normals and leaves the generator's normal channels unused. An
environment light needs ``"flat"`` (its transfer is precomputed for fixed normals; ``"decoded"`` is refused
there in one line), as ``per_texel``'s ``normals = "flat"``.

**Start** (:meth:`LatentDecoder.initial_values`): the capture is *projected* into the
latent space as MaterialGAN does (from ``w_avg`` and zero noise, Adam with ``project_lr`` for
``project_steps``; MaterialGAN alternates 10 steps on W+ and 10 on the noise,
``project_alternate = 10``; the default 0 steps both every time, measured better here),
minimising the model's own energy (its likelihood and prior,
i.e. a MAP estimate), and the particles are that point plus ``init_spread`` (in units of
``w_std`` for W+, of 1 for the noise) of seeded Gaussian jitter. The default 0.3 is wide enough that a run of
the default length ends with the std maps a longer run gives; from 0.05 the ensemble spreads out over
thousands of steps (the W+ prior is flat) and 500 steps left the roughness std 80x too small
(docs/calibration.md).

Example:
    >>> m = latent_decoder()
    >>> m.latent_sites(), m.resolution
    (['w_plus', 'noise'], 64)
"""
from __future__ import annotations

import copy
import hashlib
from dataclasses import dataclass
from pathlib import Path

import pyro
import pyro.distributions as dist
import torch
from pyro.distributions import TorchDistribution
from torch import Tensor
from torch.distributions import constraints

from .. import checks
from ..broadcast import broadcast_shapes
from ..errors import InputError
from ..optimize import Adam
from .base import ObservedModel
from .data import ModelData
from ..render.maps import SVBRDF
from .svbrdf_channels import decode

PRIORS = ("flat", "gaussian")
NOISE = ("infer", "zero")
NORMALS = ("decoded", "flat")


class Flat(TorchDistribution):
    """The improper flat density (``log p = 0``) on ``R^shape``; ``sample`` returns ``loc`` (a reference point).

    Samplers never draw from it: :meth:`LatentDecoder.initial_values` gives their start.
    """

    arg_constraints = {}

    @constraints.dependent_property(is_discrete=False, event_dim=0)
    def support(self):
        return constraints.independent(constraints.real, len(self.event_shape))

    def __init__(self, loc: Tensor, event_dims: int, validate_args=None):
        self.loc = loc
        k = loc.dim() - event_dims
        super().__init__(loc.shape[:k], loc.shape[k:], validate_args=False)

    def expand(self, batch_shape, _instance=None):
        return Flat(self.loc.expand(torch.Size(batch_shape) + self.event_shape), len(self.event_shape))

    def sample(self, sample_shape=torch.Size()):
        return self.loc.expand(torch.Size(sample_shape) + self.loc.shape).clone()

    def log_prob(self, value):
        batch = value.shape[:value.dim() - len(self.event_shape)]
        return value.new_zeros(broadcast_shapes(batch, self.batch_shape))


def weights_path(name) -> Path:
    """A decoder weights file: an existing path, or a name in the top-level ``models/`` folder (``.safetensors``)."""
    from ..presets import preset_dirs
    p = Path(name)
    if p.is_file():
        return p
    for d in preset_dirs("models"):
        for cand in (d / f"{name}.safetensors", d / str(name)):
            if cand.is_file():
                return cand
    raise InputError(f"no decoder weights '{name}'", fix="pass weights = a .safetensors path, or a file name in models/ "
                     "(the built-in is latent_decoder_64; retrain it with 'bayes-brdf train-decoder')")


def weights_digest(name) -> str:
    """SHA-256 (16 hex characters) of the weights file ``name`` resolves to (see :func:`weights_path`)."""
    return _digest(weights_path(name))


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def load_generator(weights) -> tuple:
    """``(generator, noise maps, digest)`` from a bayes-brdf decoder file or a MaterialGAN-layout checkpoint."""
    from .decoder_file import is_decoder_file, load_decoder
    p = weights_path(weights)
    if is_decoder_file(p):
        g = load_decoder(p)
        noise = None
    else:
        from .materialgan_checkpoint import load_materialgan_checkpoint
        g, noise = load_materialgan_checkpoint(p)
        g.register_buffer("w_std", g.w_stats()[1])
        g.requires_grad_(False).eval()
    return g, noise, _digest(p)


@dataclass
class LatentDecoder(ObservedModel):
    """SVBRDF = decode(G(W+, noise)) for a trained generator ``G`` (see the module docstring)."""

    weights: str = "latent_decoder_64"
    weights_digest: object = None                     # set by to_dict: a reloaded model checks the file is the same
    prior: str = "flat"
    prior_scale: float = 1.0
    noise: str = "infer"
    project_steps: int = 300
    project_lr: float = 0.02
    project_alternate: int = 0                        # 0: every site every step; k: k steps per site in turn
    init_spread: float = 0.3                          # x w_std for W+ (0.05 before: a collapsed std map, docs)
    normals: str = "decoded"                          # "decoded" (the generator's) or "flat" (the surface's own:
    #                                                   what an environment light needs, its transfer is precomputed)

    kind = "latent_decoder"

    def __post_init__(self):
        super().__post_init__()
        if self.prior not in PRIORS:
            raise InputError(f"latent_decoder prior must be one of {', '.join(PRIORS)}, got {self.prior!r}")
        if self.noise not in NOISE:
            raise InputError(f"latent_decoder noise must be one of {', '.join(NOISE)}, got {self.noise!r}")
        if self.normals not in NORMALS:
            raise InputError(f"latent_decoder normals must be one of {', '.join(NORMALS)}, got {self.normals!r}",
                             fix="normals='flat' under an environment light, else 'decoded'")
        for k in ("prior_scale", "project_lr"):
            checks.positive(getattr(self, k), f"latent_decoder {k}")
        for k in ("project_steps", "project_alternate"):
            checks.count(getattr(self, k), f"latent_decoder {k}")
        if not (isinstance(self.init_spread, (int, float)) and self.init_spread >= 0):
            raise InputError(f"latent_decoder init_spread must be >= 0, got {self.init_spread!r}")
        g, noise, digest = load_generator(self.weights)
        if self.weights_digest not in (None, digest):
            raise InputError(f"the decoder weights '{self.weights}' changed since this model was recorded "
                             f"(digest {digest}, recorded {self.weights_digest})",
                             fix="use the weights the posterior was made with")
        self.__dict__["_g"], self.__dict__["_noise0"], self.__dict__["_digest"] = g, noise, digest

    # ------------------------------------------------------------------ the generator
    @property
    def generator(self):
        return self.__dict__["_g"]

    @property
    def resolution(self) -> int:
        return self.generator.cfg.resolution

    def _gen(self, like: Tensor):
        """The generator on ``like``'s dtype and device (one copy per pair)."""
        key = (like.dtype, str(like.device))
        cache = self.__dict__.setdefault("_gen_cache", {})
        if key not in cache:
            g = self.generator
            same = (g.w_avg.dtype, str(g.w_avg.device)) == key
            cache[key] = g if same else copy.deepcopy(g).to(dtype=like.dtype, device=like.device)
        return cache[key]

    def noise_size(self) -> int:
        return sum(h * w for h, w in self.generator.noise_shapes())

    def split_noise(self, flat: Tensor) -> list[Tensor]:
        """``[n, N]`` -> the generator's noise maps ``[n, 1, r, r]``."""
        out, i = [], 0
        for h, w in self.generator.noise_shapes():
            out.append(flat[..., i:i + h * w].reshape(*flat.shape[:-1], 1, h, w))
            i += h * w
        return out

    # ------------------------------------------------------------------ the model
    def latent_sites(self) -> list[str]:
        return ["w_plus"] + (["noise"] if self.noise == "infer" else [])

    def to_dict(self) -> dict:
        d = super().to_dict()
        d["weights_digest"] = self._digest
        if d["normals"] == "decoded":          # the default before the option existed: earlier runs keep their identity
            del d["normals"]
        return d

    def sample_sites(self, data: ModelData) -> dict:
        g = self._gen(data.images)
        L, wd = g.num_ws, g.cfg.w_dim
        loc = g.w_avg.reshape(1, wd).expand(L, wd)
        if self.prior == "flat":
            w = pyro.sample("w_plus", Flat(loc, 2))
        else:
            scale = (self.prior_scale * g.w_std).reshape(1, wd).expand(L, wd)
            w = pyro.sample("w_plus", dist.Normal(loc, scale).to_event(2))
        out = {"w_plus": w}
        if self.noise == "infer":
            z = data.images.new_zeros(self.noise_size())
            out["noise"] = pyro.sample("noise", dist.Normal(z, 1.0).to_event(1))
        return out

    def channels(self, values: dict) -> Tensor:
        """The generator's output ``[n, 9, R, R]`` for site values ``{site: [n, ...]}`` (``[9, R, R]`` unbatched)."""
        w = values["w_plus"]
        if w.dim() == 2:          # one unbatched value (a model run outside the particle plate)
            return self.channels({k: v[None] for k, v in values.items()})[0]
        g = self._gen(w)
        n = w.shape[0]
        if "noise" in values:
            noise = self.split_noise(values["noise"])
        elif self._noise0 is not None:
            noise = [t.to(w).expand(n, -1, -1, -1) for t in self._noise0]
        else:
            noise = g.zero_noise(n, like=w)
        return g(w, noise)

    def maps(self, values: dict):
        """The decoded :class:`SVBRDF` with a particle dimension ``[n, C, R, R]``; with ``normals = "flat"`` the
        normal map is the fixed flat one (the generator's normal channels are not used)."""
        m = decode(self.channels(values))
        if self.normals == "flat":
            m = SVBRDF(m.albedo, m.roughness, m.specular, self._fixed((0.0, 0.0, 1.0), 3, m.albedo))
        return m

    # ------------------------------------------------------------------ the start
    def initial_values(self, data: ModelData, n: int, seed: int = 0) -> dict:
        """``n`` starting particles: the projection of the capture (the MAP) plus seeded jitter."""
        from ..potential import Potential
        pot = Potential(self, (data,))
        z = self.project_capture(pot)
        vals = {k: v.expand(n, *v.shape[1:]).clone() for k, v in pot.to_constrained(z).items()}
        g = self._gen(data.images)
        gen = torch.Generator().manual_seed(int(seed))
        for k, v in vals.items():
            scale = self.init_spread * (g.w_std.to(v) if k == "w_plus" else 1.0)
            e = torch.randn(v.shape, generator=gen, dtype=torch.float64).to(v)
            vals[k] = v + (e * scale if n > 1 else 0 * e)
        return vals

    def starts(self, like: Tensor, k: int = 1) -> dict:
        """``k`` copies of MaterialGAN's projection start ``{site: [k, ...]}``: ``w_avg`` over W+, zero noise."""
        g = self._gen(like)
        out = {"w_plus": g.w_avg.to(like).reshape(1, 1, -1).expand(k, g.num_ws, -1).contiguous()}
        if self.noise == "infer":
            out["noise"] = like.new_zeros(k, self.noise_size())
        return out

    def project_capture(self, pot, *, log: list | None = None) -> Tensor:
        """The projection ``[1, D]`` of the capture: :meth:`project` from :meth:`starts` for ``project_steps``."""
        return self.project(pot, pot.to_unconstrained(self.starts(pot.args[0].images)), log=log)

    def project(self, pot, z0: Tensor, steps: int | None = None, *, log: list | None = None) -> Tensor:
        """Adam on the energy of the rows of ``z0 [k, D]`` (no Jacobian: a MAP), one optimiser per site; with
        ``project_alternate = a > 0`` the sites take turns every ``a`` steps (W+, then the noise: MaterialGAN's
        schedule), with 0 every site steps every time (measured better here: docs/latent_decoder.md)."""
        steps = self.project_steps if steps is None else steps
        cuts = [(s.offset, s.offset + s.size) for s in pot.sites]
        parts = [z0[:, a:b].clone() for a, b in cuts]
        opts = [Adam(p, lr=self.project_lr) for p in parts]
        for t in range(steps):
            e, grad = pot.value_and_grad(torch.cat(parts, 1), jacobian=False)
            turn = [(t // self.project_alternate) % len(parts)] if self.project_alternate else range(len(parts))
            for k in turn:
                a, b = cuts[k]
                opts[k].step(grad[:, a:b])
            if log is not None:
                log.append(float(e[0]))
        return torch.cat(parts, 1)


def latent_decoder(weights: str = "latent_decoder_64", **kw) -> LatentDecoder:
    """The latent-decoder model on ``weights`` (a bayes-brdf decoder file or a MaterialGAN-layout checkpoint).

    Example:
        >>> m = latent_decoder(prior="gaussian")
        >>> m.generator.num_ws, m.noise_size()
        (10, 10896)
    """
    return LatentDecoder(weights=weights, **kw)
