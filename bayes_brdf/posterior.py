"""Posterior: the particles a sampler left, per latent site in constrained space, with summaries and files.

``mean``/``std`` are Eq. (9) (``std`` is the sample standard deviation over the
``n`` particles, with Bessel's correction); ``map`` is Eq. (7): the particle of
highest target ``f(x)`` (lowest energy), refined with Adam. ``bb.infer`` refines
it once (:meth:`Posterior.refine_map`) and the refined MAP travels in the file:
a particle is a posterior *sample*, noisy texel by texel, and shown as "the MAP"
its poorly constrained texels look like outliers. ``diagnostics`` holds the
convergence checks of the run (:mod:`bayes_brdf.samplers.diagnostics`).
Files are safetensors (tensors) with the metadata as JSON inside: no pickle.
"""
from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import Tensor

from .errors import InputError
from .models.base import MAPS, offers_maps
from .render.maps import SVBRDF

FORMAT = "bayes-brdf-posterior/1"


def _model_from_meta(meta: dict):
    """The built-in material model recorded in ``meta`` (so a loaded posterior can render), else ``None``."""
    m = meta.get("model")
    if not isinstance(m, dict) or "fixed map" in m.values():
        return None
    from .models.material import from_preset
    try:
        return from_preset(m)
    except InputError:
        return None


class Posterior:
    """Samples ``{site: [n, ...]}`` (constrained) with their energies ``[n]`` (``-log f(x)``, Eq. 3).

    Example:
        >>> post = Posterior({"roughness": torch.tensor([[0.2], [0.4]])}, torch.tensor([1.0, 0.5]))
        >>> post.mean("roughness").tolist(), post.map()["roughness"].tolist()
        ([0.30000001192092896], [0.4000000059604645])
    """

    def __init__(self, particles: dict[str, Tensor], energies: Tensor, *, z: Tensor | None = None,
                 meta: dict | None = None, potential=None, model=None, map_values: dict | None = None,
                 log: dict | None = None, surface=None):
        if not particles:
            raise InputError("a posterior needs at least one site")
        ns = {v.shape[0] for v in particles.values()}
        if len(ns) != 1 or energies.shape != (ns.copy().pop(),):
            raise InputError(f"sites and energies disagree on the particle count: {sorted(ns)} vs {tuple(energies.shape)}")
        self.particles = {k: v.detach() for k, v in particles.items()}
        self.energies = energies.detach()
        self.z = None if z is None else z.detach()
        self.meta = dict(meta or {})
        self.potential, self.model = potential, model
        self.map_values = None if map_values is None else {k: v.detach() for k, v in map_values.items()}
        #: this session's run log (wall time, the step it resumed from): not saved in the file, which holds
        #: only what determines the posterior, so a resumed run writes the same bytes as an uninterrupted one
        self.log = dict(log or {})
        self._surface = surface

    @property
    def noise_sigma(self) -> float | None:
        """The likelihood's noise scale: the model's ``sigma``, or the inferred one under ``sigma = "auto"``."""
        if "noise_sigma" in self.meta:
            return float(self.meta["noise_sigma"])
        s = getattr(self.model, "sigma", None)
        return float(s) if isinstance(s, (int, float)) and not isinstance(s, bool) else None

    @property
    def noise_level(self):
        """The signal-dependent noise level (:class:`~bayes_brdf.models.noise.NoiseLevel`) the run estimated
        (``pixel_noise = "signal"``), or ``None``: the pixel scale is then ``noise_sigma`` everywhere."""
        d = self.meta.get("noise_level")
        if not isinstance(d, dict):
            return None
        from .models.noise import NoiseLevel
        return NoiseLevel.from_dict(d)

    @property
    def render_noise(self) -> float | None:
        """The mean variance the fitted photos' renderer left in them (``Observations.variance``: photos a Monte
        Carlo renderer made), in image units squared, or ``None``: guidance adds it to the noise of a candidate's
        future photo (``noise_var = "observation"``)."""
        v = self.meta.get("render_noise")
        return float(v) if isinstance(v, (int, float)) else None

    @property
    def view_gains(self):
        """The fitted photos' gains (:class:`~bayes_brdf.models.gains.ViewGains`) the run estimated
        (``view_gain = "estimated"``), or ``None``: every photo as bright as the capture states."""
        d = self.meta.get("view_gains")
        if not isinstance(d, dict):
            return None
        from .models.gains import ViewGains
        return ViewGains.from_dict(d)

    @property
    def diagnostics(self) -> dict | None:
        """The run's convergence checks (``{"converged", "failed", "checks"}``), or ``None``."""
        return self.meta.get("diagnostics")

    # ------------------------------------------------------------------ summaries
    @property
    def sites(self) -> list[str]:
        return list(self.particles)

    @property
    def num_particles(self) -> int:
        return self.energies.shape[0]

    def _site(self, site):
        if site not in self.particles:
            raise InputError(f"no site '{site}' in the posterior", fix=f"sites: {', '.join(self.particles)}")
        return self.particles[site]

    def mean(self, site: str | None = None):
        """Posterior mean of ``site`` (``[...]``), or ``{site: mean}`` for all sites."""
        if site is None:
            return {k: self.mean(k) for k in self.particles}
        return self._site(site).mean(0)

    def std(self, site: str | None = None):
        """Uncertainty (Eq. 9): the std over the particles, Bessel-corrected, **in map space**.

        ``std()`` with a model that offers ``maps`` (every built-in): ``{map: std}`` for each of albedo,
        roughness, specular and normal that the sites decide (fixed maps are left out). Where a map is
        itself a site (``per_texel``'s albedo, roughness, specular) its std is that site's (same numbers,
        the site's own shape); otherwise it is over the decoded maps (``per_texel``'s normals from their
        slopes; all four maps of ``latent_decoder``, decoded from W+ and noise). A model whose user-facing
        maps are not the renderer's offers ``parameter_maps(values)`` (``metallic_roughness``: base colour,
        metallic, roughness): those maps then. ``std(name)``: a site's std, or a map's (the renderer's
        ``albedo``, ``specular`` included). Without a model: ``{site: std}``.
        """
        if site is None:
            if offers_maps(self.model):
                return self.map_std()
            return {k: self._std(self.particles[k]) for k in self.particles}
        if site in self.particles:
            return self._std(self.particles[site])
        if site in MAPS and offers_maps(self.model):
            out = self._renderer_map_std() if callable(getattr(self.model, "parameter_maps", None)) \
                else self.map_std()
            if site in out:
                return out[site]
            raise InputError(f"the map '{site}' is fixed in this model (no uncertainty)",
                             fix=f"maps with an uncertainty: {', '.join(out)}")
        return self._std(self._site(site))

    @staticmethod
    def _std(x: Tensor) -> Tensor:
        return x.std(0) if x.shape[0] > 1 else torch.zeros_like(x[0])

    def _varies(self, t: Tensor) -> bool:
        """Whether a decoded map ``t`` has the particle dimension (a fixed map has none)."""
        return t.dim() == 4 and t.shape[0] == self.num_particles

    def map_std(self) -> dict[str, Tensor]:
        """``{map: std over the particles}`` for the maps the sites decide (see :meth:`std`)."""
        if callable(getattr(self.model, "parameter_maps", None)):
            return {k: self._std(v) for k, v in self.model.parameter_maps(self.particles).items()}
        out = {}
        for name in MAPS:
            if name in self.particles:
                out[name] = self._std(self.particles[name])
            elif self._varies(t := getattr(self.maps("all"), name)):
                out[name] = self._std(t)
        return out

    def _renderer_map_std(self) -> dict[str, Tensor]:
        """``{map: std}`` of the renderer's maps (albedo, roughness, specular, normal) that vary."""
        m = self.maps("all")
        return {name: self._std(t) for name in MAPS if self._varies(t := getattr(m, name))}

    @property
    def surface(self):
        """The geometry the observations showed (a plane or a mesh; saved in the file), or ``None``."""
        if self._surface is None and isinstance(self.meta.get("surface"), dict):
            from .render.scene import surface_from_state
            self._surface = surface_from_state(self.meta["surface"])
        return self._surface

    @surface.setter
    def surface(self, value):
        self._surface = value

    def best(self) -> int:
        """Index of the particle with the highest target ``f(x)``."""
        return int(torch.argmin(self.energies))

    def map(self, refine_steps: int | None = None, lr: float = 0.01) -> dict[str, Tensor]:
        """MAP estimate (Eq. 7): the best particle, then ``refine_steps`` of Adam on ``-log f``.

        ``refine_steps=None``: the refined MAP stored by :meth:`refine_map` (``bb.infer`` does it) when
        there is one, else the best particle; ``0``: the best particle itself.
        """
        i = self.best()
        if refine_steps is None:
            if self.map_values is not None:
                return dict(self.map_values)
            refine_steps = 0
        if refine_steps <= 0:
            return {k: v[i] for k, v in self.particles.items()}
        if self.potential is None or self.z is None:
            raise InputError("MAP refinement needs the model: this posterior was loaded from a file",
                             fix="use refine_steps=0, or refine with bb.infer(...) in the same session")
        z = self._adam(self.z[i:i + 1], refine_steps, lr)
        return {k: v[0] for k, v in self.potential.to_constrained(z).items()}

    def _adam(self, z0: Tensor, steps: int, lr: float) -> Tensor:
        """``steps`` of Adam on ``-log f`` (no Jacobian) from the rows of ``z0`` (each row independently)."""
        from .optimize import Adam

        z = z0.clone()
        opt = Adam(z, lr=lr)
        for _ in range(steps):
            opt.step(self.potential.value_and_grad(z, jacobian=False)[1])
        return z

    #: refined optima within this many nats of -log f of each other count as equally good (see refine_map)
    MAP_TIE_NATS = 1.0

    def refine_map(self, steps: int = 300, lr: float = 0.02) -> dict[str, Tensor]:
        """Refine the MAP (Eq. 7) with ``steps`` of Adam, keep it (it is saved with the posterior) and return it.

        Two starts are refined together: the best particle (Eq. 7) and the posterior mean. Where the
        photos do not pin a parameter down (roughness away from the highlights) the posterior is flat
        and any value is a maximum; from the best particle the MAP keeps that one particle's random
        values there (salt and pepper), from the mean it does not. The mean's optimum is kept unless
        it is more than ``MAP_TIE_NATS`` worse in ``-log f`` than the best particle's (a mean between
        two modes is); a refinement that ends worse than the best particle itself keeps the particle.
        """
        if self.potential is None or self.z is None:
            raise InputError("MAP refinement needs the model: this posterior was loaded from a file",
                             fix="use refine_steps=0, or refine with bb.infer(...) in the same session")
        pot, i = self.potential, self.best()
        with torch.no_grad():
            mean = pot.to_unconstrained({k: v.mean(0, keepdim=True) for k, v in self.particles.items()})
        z = self._adam(torch.cat([self.z[i:i + 1], mean.to(self.z)]), steps, lr)
        with torch.no_grad():
            e_best, e_mean = pot.energy(z, jacobian=False).tolist()
            e0 = float(pot.energy(self.z[i][None], jacobian=False)[0])
        row, start = (1, "mean") if e_mean <= e_best + self.MAP_TIE_NATS else (0, "best particle")
        e = (e_best, e_mean)[row]
        if e <= e0:
            self.map_values = {k: v[row] for k, v in pot.to_constrained(z).items()}
        else:
            self.map_values, start, e = self.map(refine_steps=0), "best particle, unrefined", e0
        self.meta["map"] = {"refine_steps": steps, "lr": lr, "energy": e, "start": start,
                            "energy_from_best_particle": e_best, "energy_from_mean": e_mean,
                            "best_particle_energy": e0}
        return dict(self.map_values)

    def maps(self, which="mean"):
        """The model's SVBRDF for ``which``: ``"mean"`` (the mean over the particles of their maps, normals
        renormalised: Eq. 9's mean in map space), ``"map"``, a particle index, or ``"all"`` (``[n, ...]`` maps)."""
        if not offers_maps(self.model):
            raise InputError("this posterior has no material model attached", fix="pass model= or use bb.infer")
        if which == "all":
            return self._decoded()
        if which == "mean":
            m = self._decoded()
            avg = lambda t: t.mean(0) if self._varies(t) else t  # noqa: E731
            n = avg(m.normal)
            return SVBRDF(avg(m.albedo), avg(m.roughness), avg(m.specular), n / n.norm(dim=0, keepdim=True))
        vals = self.map() if which == "map" else {k: v[int(which)] for k, v in self.particles.items()}
        return self.model.maps({k: v[None] for k, v in vals.items()}).particle(0)

    def _decoded(self):
        """Every particle's maps, decoded once per (model, particles): through a generator that is the
        costly part of ``std()`` and ``maps("mean")``, which the CLI calls in turn."""
        key = (id(self.model), id(self.particles))
        hit = self.__dict__.get("_decoded_cache")
        if hit is None or hit[0] != key:
            with torch.no_grad():
                hit = self.__dict__["_decoded_cache"] = (key, self.model.maps(self.particles))
        return hit[1]

    # ------------------------------------------------------------------ files
    def save(self, path) -> Path:
        """Write ``path`` (``.safetensors``): particles, energies, unconstrained ``z`` and the metadata as JSON.

        The file holds only what determines the posterior (no wall times: those are in :attr:`log`), so
        the same run gives the same bytes, interrupted and resumed or not.
        """
        from safetensors.torch import save_file
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        seen = set()

        def own(v):
            """``v`` contiguous on the CPU, copied when its memory is another entry's (safetensors refuses shared
            memory: a site whose transform is the identity, e.g. the latent decoder's flat W+, is a view of ``z``)."""
            v = v.contiguous().cpu()
            ptr = v.untyped_storage().data_ptr()
            if ptr in seen:
                return v.clone()
            seen.add(ptr)
            return v

        t = {f"site/{k}": own(v) for k, v in self.particles.items()}
        t["energies"] = own(self.energies)
        if self.z is not None:
            t["z"] = own(self.z)
        for k, v in (self.map_values or {}).items():
            t[f"map/{k}"] = own(v)
        meta = self.meta
        if self._surface is not None:      # the geometry travels in the file (a mesh with its arrays)
            from .render.scene import surface_state
            smeta, st = surface_state(self._surface)
            meta = {**meta, "surface": smeta}
            t.update({k: v.contiguous().cpu() for k, v in st.items()})
        from .io.outputs import atomic_path
        with atomic_path(path) as tmp:     # a complete file or none, mode 0644 (safetensors alone writes 0600)
            # one metadata entry: safetensors keeps metadata in a hash map, so with two entries their order
            # in the header (and the file's bytes) would change from one process to the next
            save_file(t, str(tmp), metadata={"bayes-brdf": json.dumps({"format": FORMAT, "meta": meta},
                                                                      default=str, sort_keys=True)})
        return path

    @classmethod
    def load(cls, path) -> "Posterior":
        """Read a file written by :meth:`save` (one-line error when it is not one)."""
        from safetensors import safe_open
        path = Path(path)
        if not path.is_file():
            raise InputError("no such posterior file", where=path)
        try:
            with safe_open(str(path), framework="pt") as f:
                md = f.metadata() or {}
                t = {k: f.get_tensor(k) for k in f.keys()}
        except Exception as e:  # noqa: BLE001
            raise InputError(f"unreadable posterior file ({type(e).__name__})", where=path) from None
        try:   # since 0.1 one JSON entry {"format", "meta"}; before, two entries with the meta as JSON text
            md = json.loads(md["bayes-brdf"]) if "bayes-brdf" in md else {**md, "meta": json.loads(md.get("meta", "{}"))}
        except (TypeError, ValueError):
            md = {}
        if not isinstance(md, dict) or md.get("format") != FORMAT:
            raise InputError("not a bayes-brdf posterior file", where=path)
        parts = {k[5:]: v for k, v in t.items() if k.startswith("site/")}
        mp = {k[4:]: v for k, v in t.items() if k.startswith("map/")} or None
        meta = md.get("meta") or {}
        surface = None
        if isinstance(meta.get("surface"), dict):
            from .render.scene import surface_from_state
            surface = surface_from_state(meta["surface"], t, where=path)
        return cls(parts, t["energies"], z=t.get("z"), meta=meta, model=_model_from_meta(meta), map_values=mp,
                   surface=surface)

    def to_arviz(self):
        """An ``arviz.InferenceData`` with one chain whose draws are the particles (and ``energy`` in sample_stats)."""
        try:
            import arviz as az
        except ImportError:
            raise InputError("ArviZ export needs the arviz package", fix="pip install 'bayes-brdf[arviz]'") from None
        post = {k: v.cpu().numpy()[None] for k, v in self.particles.items()}
        return az.from_dict(posterior=post, sample_stats={"energy": self.energies.cpu().numpy()[None]},
                            attrs={k: json.dumps(v, default=str) for k, v in self.meta.items()})

    def __repr__(self):
        shapes = ", ".join(f"{k}{list(v.shape[1:])}" for k, v in self.particles.items())
        return f"Posterior({self.num_particles} particles: {shapes})"
