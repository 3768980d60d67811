"""What a sampling run samples, and its fingerprint: a model preset with overrides, the sampler, the seed.

The fingerprint (:func:`~bayes_brdf.identity.fingerprint`) is what an output folder records in
``run.json``: a rerun with an equal fingerprint resumes, any other is another run. It is built from
plain values and the observations' digest, which the caller computes once per run
(:func:`~bayes_brdf.identity.observations_digest`) and hands on to :func:`bayes_brdf.infer` as well.

Example:
    >>> model_table("per_texel", {"sigma": 0.02}, resolution=64)["resolution"]
    64
    >>> fp = run_fingerprint("ab12", model={"model": "per_texel"}, sampler=None, params={}, particles=8,
    ...                      steps=100, seed=0, views=None, resolution=[64, 64])
    >>> fp["sampler"]["particles"], fp["data"]
    (8, 'ab12')
"""
from __future__ import annotations

from pathlib import Path


def model_table(model: str, overrides: dict, resolution: int) -> dict:
    """The model preset ``model`` (a name or a TOML path) with ``overrides`` applied: what a run samples
    and what its fingerprint records.

    A per-texel model (``per_texel``, ``metallic_roughness``) gets ``resolution`` texels per side unless
    ``overrides`` set it; a ``latent_decoder`` records the digest of its weights (other weights, another run).
    """
    from ..presets import load_preset

    table = dict(load_preset("models", model))
    table.update(dict(overrides))
    if table.get("model") in ("per_texel", "metallic_roughness") and "resolution" not in dict(overrides):
        table["resolution"] = resolution
    if table.get("model") == "latent_decoder" and "weights_digest" not in table:
        from ..models.latent_decoder import weights_digest
        table["weights_digest"] = weights_digest(table.get("weights", "latent_decoder_64"))
    return table


def sampler_identity(sampler) -> "dict | str":
    """What a fingerprint records of a sampler spec: a preset name or TOML path (``None``: ``spos``) as its whole
    table, so that a preset edited between two runs makes them two runs; a table as given; a sampler object as its
    repr (its class and every hyper-parameter).

    Example:
        >>> sampler_identity("spos")["params"]["texel_bandwidth"]
        2.5
    """
    from ..presets import load_preset

    if sampler is None or isinstance(sampler, (str, Path)):
        return dict(load_preset("samplers", sampler or "spos"))
    if isinstance(sampler, dict):
        return dict(sampler)
    return repr(sampler)


def run_fingerprint(data: str, *, model: dict, sampler: str | None, params: dict, particles: int | None,
                    steps: "int | str | None", seed: int, views: list[int] | None, resolution: list[int],
                    start: dict | None = None) -> dict:
    """The fingerprint of a run on observations with digest ``data``: the model table (:func:`model_table`),
    the sampler preset (``None``: ``spos``) with its ``params`` overrides, ``particles`` and ``steps``
    (``None``: the preset's), the seed, the fitted ``views`` (``None``: all) and the photos' resolution."""
    from ..identity import fingerprint

    preset = sampler_identity(sampler)
    extra = {} if start is None else {"start": start}
    return fingerprint(data=data, model=model, seed=seed, views=views, resolution=list(resolution),
                       sampler={"preset": preset, "params": dict(params), "particles": particles, "steps": steps},
                       **extra)
