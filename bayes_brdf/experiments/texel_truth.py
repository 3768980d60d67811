"""Each texel's exact roughness posterior on real photos, by quadrature: the truth the sampler is checked on.

For a ``per_texel`` model on rectified photos (pixels are texels) with fixed specular and flat normals, the
texels are independent given the noise scale (:mod:`bayes_brdf.models.texel_energy`), and within a texel the
colour channels are independent given the roughness: each channel's pixels depend on its own albedo and the
shared roughness only. So a texel's roughness marginal is::

    p(r | y) ∝ prod_c  int_0^1 exp(-E_c(a, r)) da          (uniform priors)

with ``E_c`` the channel's share of the texel energy (its residuals times ``kappa``, less its saturated pixels'
censored terms at ``sigma``). :func:`roughness_marginals` evaluates it on a midpoint grid of ``albedo_cells x
roughness_cells`` values, every texel at once (one render of all texels per grid point). Measured on card_blue
at 64², 64 x 48 and 256 x 64 cells agree to 0.001 in the mean and std of each quarter of the texels.

It is what showed that half of a default run's roughness std map on real photos came from particles stranded
in a texel's weak second mode (docs/calibration.md, "Stranded particles"); ``benchmarks/bench_texel_truth.py``
prints the comparison.
"""
from __future__ import annotations

import torch
from torch import Tensor

from ..errors import InputError
from ..models.texel_energy import offers_texel_energy, texel_channel_energies


def roughness_marginals(model, data, sigma: float, kappa: float, *, albedo_cells: int = 128,
                        roughness_cells: int = 64, chunk: int = 64) -> dict:
    """``{"mean", "std": [T], "p": [roughness_cells, T], "grid": [roughness_cells]}``: each texel's roughness
    posterior at noise scale ``sigma`` with residual weight ``kappa`` (``texel_energies``' scale of a
    posterior's particles, e.g. their medians: :func:`bayes_brdf.samplers.texel_moves.texel_energy`)."""
    if not offers_texel_energy(model, data) or model.specular == "infer" or model.normals != "flat" \
            or model.likelihood != "laplace":
        raise InputError("the quadrature needs a per_texel model with fixed specular, flat normals and the "
                         "Laplace likelihood on rectified photos, without a smoothness prior")
    for site in ("albedo", "roughness"):
        if model._prior(site).kind != "uniform":
            raise InputError(f"the quadrature assumes a uniform prior on {site}")
    R = model.resolution
    lo, hi = model.roughness_range
    ag = (torch.arange(albedo_cells, dtype=torch.float64) + 0.5) / albedo_cells
    rg = lo + (hi - lo) * (torch.arange(roughness_cells, dtype=torch.float64) + 0.5) / roughness_cells
    A, Rr = (t.flatten() for t in torch.meshgrid(ag, rg, indexing="ij"))
    C = 3 if model.albedo == "rgb" else 1
    E = torch.empty(len(A), R * R, 3, dtype=torch.float64)
    for i in range(0, len(A), chunk):
        a, r = A[i:i + chunk], Rr[i:i + chunk]
        m = len(a)
        vals = {"albedo": a.reshape(m, 1, 1, 1).expand(m, C, R, R).to(data.dtype),
                "roughness": r.reshape(m, 1, 1, 1).expand(m, 1, R, R).to(data.dtype)}
        full = lambda v: torch.full((m,), float(v), dtype=torch.float64)     # noqa: E731
        E[i:i + m] = texel_channel_energies(model, data, vals, full(sigma), full(kappa))
    E = E.reshape(albedo_cells, roughness_cells, R * R, 3)
    if C == 1:                                   # one gray albedo for the three channels: integrate it jointly
        lm = torch.logsumexp(-E.sum(-1), 0)
    else:
        lm = torch.logsumexp(-E, 0).sum(-1)                                          # [roughness_cells, T]
    p = torch.softmax(lm, 0)
    mean = (p * rg[:, None]).sum(0)
    std = ((p * rg[:, None] ** 2).sum(0) - mean ** 2).clamp_min(0).sqrt()
    return {"mean": mean, "std": std, "p": p, "grid": rg}
