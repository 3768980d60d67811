"""An independent reference for mesh renders: Mitsuba 3's own ``direct`` integrator shading our maps.

:func:`render_reference` renders the same mesh, views and maps as :func:`bayes_brdf.render.shade.render`,
but everything after the camera ray is Mitsuba's: its ``direct`` integrator (emitter sampling, one
``point`` emitter per pass, visibility by its own shadow rays and offsets), its ``envmap`` emitter for an
:class:`~bayes_brdf.render.environment.EnvironmentLight`, its ``bitmap`` textures (bilinear, clamped) and
a custom Python BSDF (:data:`BSDF_NAME`) that writes the MaterialGAN microfacet BRDF of
:mod:`bayes_brdf.render.brdf` again in Dr.Jit (it calls none of our torch code). Two cameras:

* ``camera="rays"`` (default): our pixel-centre rays (:meth:`PerspectiveCamera.rays`) go into
  ``integrator.sample(scene, sampler, ray)``; this isolates shading and visibility, and one sample per
  pixel is exact for a point light (a delta emitter, and each pass holds one light). An environment pass
  averages ``spp`` independent samples per pixel ray (the ray batch repeated, up to :data:`MAX_LANES`
  lanes per launch, each launch seeded on its own).
* ``camera="sensor"``: a Mitsuba ``perspective`` sensor matching :class:`PerspectiveCamera` (``fov``
  along x, ``look_at`` with the camera's orthonormal up, the film's width and height), a box filter and
  ``spp`` random samples per pixel: pixel *areas* rather than pixel centres, so silhouettes and shadow
  edges are antialiased where ours are not.

Environment passes (``tests/render/test_mitsuba_envmap.py``): a view's environment light is one pass
with Mitsuba's ``envmap`` as the only emitter of its scene -- ``{"type": "envmap", "bitmap":
mi.Bitmap(radiance), "scale": scale, "to_world": to_world}``, which
:class:`~bayes_brdf.render.environment.EnvironmentLight` reads exactly -- in a second Mitsuba scene of the
mesh that shares the BSDF and its maps, built once per light (kept by ``light.digest``, a few per mesh,
so views under the same light share it). Its integrator is ``direct`` with one emitter sample (the
envmap's luminance x sin(theta) importance sampling, a shadow ray to infinity) and one BSDF sample per
pixel sample, combined by multiple importance sampling (Mitsuba's power heuristic), and
``hide_emitters``: a camera ray that misses the mesh is black, as in our renders, not the sky. The result
is unbiased with Monte Carlo noise ~ 1 / sqrt(spp) (a few percent per pixel at 256-1024 samples on the
bunny under a real HDR map); the passes of a view, point lights' and the environment's, are summed.

Conventions (found by test, ``tests/render/test_mitsuba_equivalence.py``):

* Mitsuba's ``bitmap`` texture reads data row ``j`` at ``v = (j + 0.5) / H`` (row 0 at ``v = 0``),
  ours reads texel row 0 at ``v = 1``: the maps go into the bitmaps flipped upside down. Texel
  centres at ``(i + 0.5) / W`` and ``wrap_mode="clamp"`` match ``grid_sample(align_corners=False,
  padding_mode="border")``; ``raw=True`` keeps the values linear (and the normal map's negative
  components).
* The BSDF builds our shading frame itself in world space from the surface interaction, as
  :mod:`.raycast` does: the geometric normal turned to the side of the shading normal (a face wound
  against its vertex normals shades as they say), then two-sided by it against the incoming
  direction (both normals flipped to face the camera), tangent = ``dp/du`` made orthogonal to the
  shading normal, bitangent ``n x t`` turned to follow ``+v`` (``dp/dv``); the tangent-space normal
  map is ``x t + y b + z n``, normalised.
* Every cosine (``n.l, n.v, n.h, v.h``, with the mapped normal) is clamped at ``eps`` as ours are, and
  ``eval`` returns ``f * (n.l)``: Mitsuba's point emitter gives ``intensity / d^2``, so ``intensity``
  = our light power.

Differences that remain, by design:

* Shadow rays: Mitsuba's ``spawn_ray_to`` leaves the surface by ``(1 + max|p|) * RayEpsilon``
  (``RayEpsilon`` ~ 8.9e-5) along the geometric normal, ours by
  :data:`~bayes_brdf.render.raycast.SHADOW_EPS` times the mesh radius. A shadow ray grazing an
  occluder's silhouette can catch it with one offset and miss it with the other, so a pixel or a few
  exactly on a shadow edge differ (lit in one render, shadowed in the other); every other pixel agrees.
* Precision: Mitsuba shades in float32 (ours: float32 hits, float64 shading), its bitmaps hold float32.
* A map with a side of one texel is doubled on that side (Mitsuba's bitmap refuses new data smaller
  than 2 x 2; clamped bilinear lookup reads the same values).
* Lights: the ``direct`` integrator with one emitter sample would pick one of several lights at random
  (weighted by their count), so each light is its own pass with the only emitter in the scene, and the
  passes are summed -- exact, where more emitter samples would only be unbiased.
* The BSDF's ``sample`` (used by environment passes only: point-light passes run with
  ``bsdf_samples=0``) draws from a mixture about the *mapped* normal: with probability :data:`P_COSINE`
  a cosine-weighted direction, else a GGX half vector ``h`` with density ``D(h) (n.h)`` (``alpha = r^2``
  from the roughness map at the hit, so specular lobes down to r = 0.05 are found) reflected about it
  (``l = 2 (v.h) h - v``; a half vector facing away from ``v`` gives no direction). ``pdf`` and
  ``eval_pdf`` return the mixture's density ``P_COSINE (n.l)/pi + (1 - P_COSINE) D(h)(n.h) / (4 |l.h|)``
  with ``h`` the half vector of ``(v, l)`` -- exactly what ``sample`` draws, which MIS needs -- and
  ``sample``'s weight is ``eval / pdf``. ``D`` is evaluated as ``alpha^2 / (pi (alpha^2 (n.h)^2 +
  |n x h|^2)^2)``, the same as ``nh^2 (alpha^2 - 1) + 1`` in the denominator but without float32's
  cancellation at the peak of a narrow lobe.
* Lights without distance falloff and rectified cameras have no Mitsuba counterpart and are refused.
* ``camera="sensor"`` integrates each pixel's area (random samples, box filter): it differs from our
  pixel centres at silhouettes, creases and shadow edges, and by Monte Carlo noise elsewhere.

PSNR (:func:`psnr`) is on linear radiance over all pixels, views and channels, with the peak the
maximum of *our* image.
"""
from __future__ import annotations

import math
import threading
from collections import OrderedDict

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from ..mitsuba_env import mitsuba_variant
from .cameras import PerspectiveCamera
from .lights import PointLight
from .maps import SVBRDF
from .raycast import MeshSceneCache, mitsuba_mesh
from .views import View

#: the name the reference BSDF is registered under (per Mitsuba variant)
BSDF_NAME = "bayes_brdf_microfacet"

#: the camera kinds of :func:`render_reference`
CAMERAS = ("rays", "sensor")
#: the integrators of :func:`render_reference`: ``direct`` (direct light, one pass per light: the reference of our
#: shading) and ``path`` (Mitsuba's path tracer: interreflections, Monte Carlo noise; captures from a renderer
#: that is not our forward model)
INTEGRATORS = ("direct", "path")

_LOCK = threading.Lock()
_REGISTERED: set[str] = set()
_MAPS = ("albedo", "roughness", "specular", "normal")

#: the BSDF's sampling mixture: the probability of its cosine lobe (the rest: GGX half vectors)
P_COSINE = 0.5
#: lanes per Mitsuba launch of an environment pass (a view's rays times the samples drawn at once)
MAX_LANES = 1 << 20
#: environment scenes kept per reference scene (by the light's digest)
MAX_ENVIRONMENTS = 3


def _register(mi) -> None:
    """Define the BSDF class for the active variant and register it (once per variant)."""
    variant = mi.variant()
    if variant in _REGISTERED:
        return
    import drjit as dr

    class MicrofacetBSDF(mi.BSDF):
        """MaterialGAN's microfacet BRDF (GGX, Smith-Schlick, spherical-Gaussian Schlick Fresnel,
        ``kd (1 - ks) / pi`` diffuse) with a tangent-space normal map, two-sided, in Dr.Jit."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.albedo = props["albedo"]
            self.roughness = props["roughness"]
            self.specular = props["specular"]
            self.normalmap = props["normal"]
            self.eps = float(props["eps"]) if "eps" in props else 1e-8
            self.ks_factor = bool(props["ks_factor"]) if "ks_factor" in props else True
            flags = (mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.GlossyReflection
                     | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide)
            self.m_components = [flags]
            self.m_flags = flags

        def _frame(self, si, active):
            """World ``(mapped normal, shading normal, direction to the camera)``, faced to the camera."""
            wi = si.to_world(si.wi)
            ng = si.n * dr.select(dr.dot(si.n, si.sh_frame.n) < 0, -1.0, 1.0)   # the vertex normals' side
            flip = dr.select(dr.dot(ng, wi) < 0, -1.0, 1.0)           # two-sided by the geometric normal
            ng, ns = ng * flip, si.sh_frame.n * flip
            ns = dr.normalize(dr.select(dr.squared_norm(ns) > 0, ns, ng))
            tu = si.dp_du - ns * dr.dot(ns, si.dp_du)
            fallback, _ = mi.coordinate_system(ns)
            t = dr.normalize(dr.select(dr.squared_norm(tu) > 1e-24, tu, fallback))
            b = dr.cross(ns, t)
            b = b * dr.select(dr.dot(b, si.dp_dv) < 0, -1.0, 1.0)       # bitangent along +v
            nt = self.normalmap.eval(si, active)
            nw = t * nt[0] + b * nt[1] + ns * nt[2]
            nw = nw * dr.rsqrt(dr.maximum(dr.squared_norm(nw), 1e-30))
            return nw, ns, wi

        def _value(self, si, wo, active, frame=None):
            nw, ns, wi = self._frame(si, active) if frame is None else frame
            lo = si.to_world(wo)
            h = wi + lo
            h = h * dr.rsqrt(dr.maximum(dr.squared_norm(h), 1e-30))
            eps = self.eps
            nl = dr.maximum(dr.dot(nw, lo), eps)
            nv = dr.maximum(dr.dot(nw, wi), eps)
            nh = dr.maximum(dr.dot(nw, h), eps)
            vh = dr.maximum(dr.dot(wi, h), eps)
            kd = self.albedo.eval(si, active)
            ks = self.specular.eval(si, active)
            r = self.roughness.eval_1(si, active)
            alpha = r * r
            a2 = alpha * alpha
            # nh^2 (a2 - 1) + 1 written as a2 nh^2 + |n x h|^2: the same, without float32's cancellation at the
            # peak of a narrow lobe (1 - nh^2 ~ 1e-7 against a2 = 6e-6 at r = 0.05)
            s2 = dr.select(dr.dot(nw, h) > eps, dr.squared_norm(dr.cross(nw, h)), 1.0 - nh * nh)
            den = a2 * nh * nh + s2
            d = a2 * dr.inv_pi / (den * den)
            k = alpha * 0.5
            g = nl / (nl * (1.0 - k) + k) * (nv / (nv * (1.0 - k) + k))
            fr = ks + (1.0 - ks) * dr.exp2(((-5.55473) * vh - 6.98316) * vh)
            diffuse = kd * (1.0 - ks) * dr.inv_pi if self.ks_factor else kd * dr.inv_pi
            f = diffuse + fr * (d * g / (4.0 * nl * nv))
            return dr.select(active, f * nl, 0.0), lo

        def _a2(self, si, active):
            r = self.roughness.eval_1(si, active)
            return dr.maximum(r * r * r * r, 1e-12)

        def _pdf(self, si, lo, active, frame):
            """The mixture's solid-angle density at world ``lo``: ``P_COSINE cos/pi + (1 - P_COSINE) D (n.h) /
            (4 |l.h|)``, both about the mapped normal (what :meth:`sample` draws, exactly)."""
            nw, _, wi = frame
            a2 = self._a2(si, active)
            cos = dr.maximum(dr.dot(nw, lo), 0.0) * dr.inv_pi
            h = wi + lo
            h = h * dr.rsqrt(dr.maximum(dr.squared_norm(h), 1e-30))
            nh = dr.dot(nw, h)
            den = a2 * nh * nh + dr.squared_norm(dr.cross(nw, h))
            lh = dr.abs(dr.dot(lo, h))
            ggx = a2 * dr.inv_pi / dr.maximum(den * den, 1e-36) * nh / (4.0 * dr.maximum(lh, 1e-30))
            ggx = dr.select((nh > 0) & (lh > 0), ggx, 0.0)
            return dr.select(active, P_COSINE * cos + (1.0 - P_COSINE) * ggx, 0.0)

        def eval(self, ctx, si, wo, active=True):
            return self._value(si, wo, active)[0]

        def pdf(self, ctx, si, wo, active=True):
            return self._pdf(si, si.to_world(wo), active, self._frame(si, active))

        def eval_pdf(self, ctx, si, wo, active=True):
            frame = self._frame(si, active)
            value, lo = self._value(si, wo, active, frame)
            return value, self._pdf(si, lo, active, frame)

        def sample(self, ctx, si, sample1, sample2, active=True):
            frame = self._frame(si, active)
            nw, _, wi = frame
            local = mi.Frame3f(nw)
            # the cosine lobe about the mapped normal
            l_cos = local.to_world(mi.warp.square_to_cosine_hemisphere(sample2))
            # GGX half vectors, density D(h) (n.h); tan^2 theta = a2 u / (1 - u), written without cancellation
            a2 = self._a2(si, active)
            u = sample2.y
            q = a2 * u + (1.0 - u)
            cos2 = dr.clip((1.0 - u) / q, 0.0, 1.0)
            sin_t, cos_t = dr.sqrt(dr.clip(a2 * u / q, 0.0, 1.0)), dr.sqrt(cos2)
            s, c = dr.sincos(dr.two_pi * sample2.x)
            h = local.to_world(mi.Vector3f(sin_t * c, sin_t * s, cos_t))
            vh = dr.dot(wi, h)
            l_ggx = 2.0 * vh * h - wi
            ggx = sample1 >= P_COSINE
            lo = dr.select(ggx, l_ggx, l_cos)
            lo = lo * dr.rsqrt(dr.maximum(dr.squared_norm(lo), 1e-30))
            ok = active & (~ggx | (vh > 0))      # a half vector facing away from wi reflects to no direction
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = si.to_local(lo)
            bs.pdf = self._pdf(si, si.to_world(bs.wo), ok, frame)     # as pdf(wo) computes it, to the last bit
            bs.eta = 1.0
            bs.sampled_type = dr.select(ggx, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                        mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
            bs.sampled_component = mi.UInt32(0)
            value = self._value(si, bs.wo, ok, frame)[0]
            ok = ok & (bs.pdf > 0)
            bs.pdf = dr.select(ok, bs.pdf, 0.0)
            return bs, dr.select(ok, value / dr.maximum(bs.pdf, 1e-30), 0.0)

        def traverse(self, callback):
            for name, tex in (("albedo", self.albedo), ("roughness", self.roughness),
                              ("specular", self.specular), ("normal", self.normalmap)):
                callback.put(name, tex, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return f"MicrofacetBSDF[eps={self.eps}, ks_factor={self.ks_factor}]"

    mi.register_bsdf(BSDF_NAME, lambda props: MicrofacetBSDF(props))
    _REGISTERED.add(variant)


def _bitmap_data(t: Tensor) -> np.ndarray:
    """A map ``[C, H, W]`` as Mitsuba bitmap data ``[H, W, C]`` float32, rows flipped (Mitsuba: row 0 at
    v = 0); a side of one texel is doubled (a bitmap whose data change must be at least 2 x 2; with clamped
    bilinear lookup the copy reads the same)."""
    a = t.detach().to("cpu", torch.float32).numpy().transpose(1, 2, 0)[::-1]
    a = np.repeat(a, 2 if a.shape[0] == 1 else 1, axis=0)
    return np.ascontiguousarray(np.repeat(a, 2 if a.shape[1] == 1 else 1, axis=1))


class ReferenceScene:
    """A mesh in Mitsuba with the reference BSDF, one point light and a ``direct`` integrator; built once
    per mesh (the Python BSDF's kernels compile on the first render), maps and light set per call; an
    environment light gets its own scene of the mesh (:meth:`env_scene`, kept by digest; ``env_builds``
    counts those built) and the MIS integrator :attr:`env_integrator`. Its
    methods other than the constructor run inside ``mitsuba_variant(self.variant)`` (as
    :func:`render_reference` calls them).

    Example:
        >>> from bayes_brdf.render.mesh import Mesh                  # doctest: +SKIP
        >>> rs = ReferenceScene(Mesh.sphere())                       # doctest: +SKIP
    """

    def __init__(self, mesh, variant: str | None = None, bsdf: str = "ours"):
        self.mesh = mesh
        self.kind = bsdf
        with mitsuba_variant(variant) as mi:
            self.variant = mi.variant()
            one = lambda c: {"type": "bitmap", "data": mi.TensorXf(np.full((2, 2, c), 0.5, np.float32)),  # noqa: E731
                             "raw": True, "filter_type": "bilinear", "wrap_mode": "clamp"}
            if bsdf == "principled":          # Mitsuba's own, with bitmaps of base colour, metallic, roughness
                bsdf = mi.load_dict({"type": "principled", "base_color": one(3), "metallic": one(1),
                                     "roughness": one(1), "specular": 0.5})
                self.textures = None
            else:
                _register(mi)
                bsdf = mi.load_dict({"type": BSDF_NAME, "albedo": one(3), "roughness": one(1), "specular": one(3),
                                     "normal": one(3)})
                self.textures = {name: getattr(bsdf, "normalmap" if name == "normal" else name) for name in _MAPS}
            m = mitsuba_mesh(mesh, mi)
            m.set_bsdf(bsdf)
            self.bsdf = bsdf
            self.scene = mi.load_dict({
                "type": "scene", "mesh": m,
                "light": {"type": "point", "position": [0.0, 0.0, 0.0], "intensity": {"type": "rgb", "value": 1.0}},
            })
            self.integrator = mi.load_dict({"type": "direct", "emitter_samples": 1, "bsdf_samples": 0})
            self.env_integrator = mi.load_dict({"type": "direct", "emitter_samples": 1, "bsdf_samples": 1,
                                                "hide_emitters": True})
            self.params = mi.traverse(self.scene)
            self._paths: dict = {}
            self._sensor = None
            self._envs: OrderedDict = OrderedDict()
            self.env_builds = 0

    # ---------------------------------------------------------------- state
    def set_maps(self, maps: SVBRDF, *, eps: float = 1e-8, ks_factor: bool = True) -> None:
        """Load ``maps`` (no particle dimension) into the bitmap textures (inside a variant block)."""
        import mitsuba as mi
        for name, t in maps.items():
            tp = mi.traverse(self.textures[name])
            tp["data"] = mi.TensorXf(_bitmap_data(t))
            tp.update()
        self.bsdf.eps, self.bsdf.ks_factor = float(eps), bool(ks_factor)

    def set_principled(self, textures: dict) -> None:
        """Load ``{"base_color": [3, R, R], "metallic": [1, R, R], "roughness": [1, R, R]}`` (our map convention)
        into the ``principled`` BSDF's bitmaps (a scene built with ``bsdf="principled"``; inside a variant block)."""
        import mitsuba as mi
        tp = mi.traverse(self.bsdf)
        for name in PRINCIPLED_MAPS:
            tp[f"{name}.data"] = mi.TensorXf(_bitmap_data(textures[name]))
        tp.update()

    def set_light(self, light) -> None:
        import mitsuba as mi
        self.params["light.position"] = mi.Point3f(*light.position)
        self.params["light.intensity.value"] = mi.Color3f(*light.power)
        self.params.update()

    def env_scene(self, light):
        """The scene of an environment pass: the mesh (a second Mitsuba mesh sharing :attr:`bsdf` and so the
        maps) and ``light`` as an ``envmap`` emitter, the only emitter; kept by ``light.digest`` (a few)."""
        import mitsuba as mi
        key = light.digest
        if key in self._envs:
            self._envs.move_to_end(key)
            return self._envs[key]
        m = mitsuba_mesh(self.mesh, mi)
        m.set_bsdf(self.bsdf)
        emitter = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(light.radiance.numpy()),
                                "scale": float(light.scale),
                                "to_world": mi.ScalarTransform4f(np.array(light.to_world))})
        scene = mi.load_dict({"type": "scene", "mesh": m, "environment": emitter})
        self._envs[key] = scene
        self.env_builds += 1
        while len(self._envs) > MAX_ENVIRONMENTS:
            self._envs.popitem(last=False)
        return scene

    def path_integrator(self, max_depth: int):
        """Mitsuba's ``path`` integrator with ``max_depth`` (2: direct light only), emitters hidden from camera rays
        (a ray that misses the mesh is black, as in our renders); one per depth, kept."""
        import mitsuba as mi
        if max_depth not in self._paths:
            self._paths[max_depth] = mi.load_dict({"type": "path", "max_depth": int(max_depth),
                                                   "hide_emitters": True})
        return self._paths[max_depth]

    def _pass(self, light, path):
        """``(scene, integrator)`` of one light's pass (``path``: the path integrator, or ``None`` for direct)."""
        if _is_environment(light):
            return self.env_scene(light), path or self.env_integrator
        self.set_light(light)
        return self.scene, path or self.integrator

    # ---------------------------------------------------------------- renders
    def render_rays(self, camera: PerspectiveCamera, lights, seed: int = 0, spp: int = 64, path=None) -> Tensor:
        """``[H, W, 3]``: the pixel-centre rays of ``camera`` through ``integrator.sample``, summed over ``lights``
        (direct light: a point light one exact sample per pixel, an environment the mean of ``spp`` independent
        samples; under a ``path`` integrator every pass is the mean of ``spp`` samples)."""
        import drjit as dr
        import mitsuba as mi
        h, w = camera.resolution
        o, d = camera.rays(dtype=torch.float64)
        d = np.ascontiguousarray(d.reshape(3, -1).float().numpy())
        n = h * w
        ray = mi.RayDifferential3f(mi.Point3f(*(mi.Float(np.full(n, float(x), np.float32)) for x in o.tolist())),
                                   mi.Vector3f(mi.Float(d[0]), mi.Float(d[1]), mi.Float(d[2])))
        sampler = mi.load_dict({"type": "independent"})
        out = np.zeros((3, n), np.float64)
        for light in lights:
            scene, integrator = self._pass(light, path)
            if path is not None or _is_environment(light):
                out += self._mean_rays(scene, integrator, o, d, int(spp), seed, sampler)
                continue
            sampler.seed(seed, n)
            spec, _, _ = integrator.sample(scene, sampler, ray, None, True)
            dr.eval(spec)
            out += np.stack([np.asarray(spec[0]), np.asarray(spec[1]), np.asarray(spec[2])]).astype(np.float64)
        return torch.from_numpy(out.reshape(3, h, w).transpose(1, 2, 0).copy())

    def _mean_rays(self, scene, integrator, o: Tensor, d: np.ndarray, spp: int, seed: int, sampler) -> np.ndarray:
        """``[3, n]``: the mean over ``spp`` samples of ``integrator`` on ``scene`` for rays from ``o`` along
        ``d [3, n]``; the rays are repeated so that one launch holds up to :data:`MAX_LANES` lanes, each launch
        its own seed."""
        import drjit as dr
        import mitsuba as mi
        n = d.shape[1]
        reps = max(1, min(spp, MAX_LANES // n))
        acc = np.zeros((3, n), np.float64)
        done = launch = 0
        while done < spp:
            k = min(reps, spp - done)
            dk = np.ascontiguousarray(np.tile(d, (1, k)))
            ray = mi.RayDifferential3f(
                mi.Point3f(*(mi.Float(np.full(n * k, float(x), np.float32)) for x in o.tolist())),
                mi.Vector3f(mi.Float(dk[0]), mi.Float(dk[1]), mi.Float(dk[2])))
            sampler.seed((seed + 7919 * launch) % 2**32, n * k)
            spec, _, _ = integrator.sample(scene, sampler, ray, None, True)
            dr.eval(spec)
            a = np.stack([np.asarray(spec[0]), np.asarray(spec[1]), np.asarray(spec[2])]).astype(np.float64)
            acc += a.reshape(3, k, n).sum(1)
            done, launch = done + k, launch + 1
        return acc / spp

    def render_sensor(self, camera: PerspectiveCamera, lights, spp: int = 64, seed: int = 0, path=None) -> Tensor:
        """``[H, W, 3]``: a Mitsuba ``perspective`` sensor like ``camera`` (box filter, ``spp`` samples per
        pixel), summed over ``lights`` (``path``: the path integrator for every pass)."""
        import mitsuba as mi
        h, w = camera.resolution
        _, u, f = camera.frame()
        pos = camera.position
        to_world = mi.ScalarTransform4f().look_at(origin=list(pos), target=[pos[i] + float(f[i]) for i in range(3)],
                                                  up=[float(x) for x in u])
        if self._sensor is None or self._sensor[0] != (h, w):
            sensor = mi.load_dict({
                "type": "perspective", "fov": float(camera.fov), "fov_axis": "x", "to_world": to_world,
                "near_clip": 1e-3 * self.mesh.radius, "far_clip": 1e4 * max(self.mesh.radius, 1.0),
                "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                         "pixel_format": "rgb", "sample_border": False},
                "sampler": {"type": "independent", "sample_count": spp}})
            self._sensor = ((h, w), sensor, mi.traverse(sensor))
        _, sensor, sp = self._sensor
        sp["to_world"] = to_world
        sp["x_fov"] = float(camera.fov)
        sp.update()
        out = torch.zeros(h, w, 3, dtype=torch.float64)
        for i, light in enumerate(lights):
            scene, integrator = self._pass(light, path)
            if path is not None or _is_environment(light):
                per = max(1, min(spp, MAX_LANES // (h * w)))          # samples per launch
                done = launch = 0
                while done < spp:
                    k = min(per, spp - done)
                    img = mi.render(scene, sensor=sensor, integrator=integrator, spp=k,
                                    seed=(seed + 7919 * i + 1000003 * launch) % 2**32)
                    out += torch.from_numpy(np.array(img, dtype=np.float64)[..., :3]) * (k / spp)
                    done, launch = done + k, launch + 1
                continue
            img = mi.render(scene, sensor=sensor, integrator=integrator, spp=spp, seed=seed + 7919 * i)
            out += torch.from_numpy(np.array(img, dtype=np.float64)[..., :3])
        return out


#: the reference scenes built so far, by mesh and variant
SCENES = MeshSceneCache(ReferenceScene, max_entries=4)
#: the scenes with Mitsuba's ``principled`` BSDF (:func:`render_principled`), by mesh and variant
PRINCIPLED_SCENES = MeshSceneCache(lambda mesh, variant: ReferenceScene(mesh, variant, bsdf="principled"),
                                   max_entries=2)
#: the maps of :func:`render_principled`
PRINCIPLED_MAPS = ("base_color", "metallic", "roughness")


def _check_request(views, camera: str, integrator: str, spp, max_depth, batches, variant) -> list:
    """The views of a Mitsuba render as a list, after one-line errors for a request that cannot be rendered:
    the camera, the integrator and its ``max_depth``, ``spp`` and ``batches``, the variant (a JIT RGB one: the
    reference BSDF is a Python BSDF), no views or views of different resolutions."""
    if camera not in CAMERAS:
        raise InputError(f"unknown reference camera {camera!r}", fix=f"use one of {', '.join(CAMERAS)}")
    if variant is not None and not (variant.startswith(("llvm_", "cuda_")) and variant.endswith("_rgb")):
        raise InputError(f"the reference needs a JIT RGB Mitsuba variant (a Python BSDF), got {variant!r}",
                         fix="use llvm_ad_rgb or cuda_ad_rgb")
    if int(spp) < 1:
        raise InputError(f"spp must be >= 1, got {spp}")
    if integrator not in INTEGRATORS:
        raise InputError(f"unknown integrator {integrator!r}", fix=f"use one of {', '.join(INTEGRATORS)}")
    if integrator == "path" and (isinstance(max_depth, bool) or int(max_depth) != max_depth or max_depth < 2):
        raise InputError(f"max_depth must be an integer >= 2 (2: direct light only), got {max_depth!r}")
    if isinstance(batches, bool) or not isinstance(batches, int) or batches < 1:
        raise InputError(f"batches must be a positive integer, got {batches!r}")
    if batches > 1 and (int(spp) % batches or int(spp) < 2 * batches):
        raise InputError(f"spp {spp} must be a multiple of batches {batches}, at least twice it",
                         fix=f"use spp = {2 * batches * max(1, -(-int(spp) // (2 * batches)))}")
    views = list(views)
    if not views:
        raise InputError("no views given", fix="pass at least one View")
    res = {tuple(v.resolution) for v in views}
    if len(res) != 1:
        raise InputError(f"views have different resolutions {sorted(res)}", fix="render them in separate calls")
    return views


def _is_environment(light) -> bool:
    return getattr(light, "kind", None) == "environment"


def _check(maps: SVBRDF, views) -> SVBRDF:
    if maps.num_particles is not None:
        if maps.num_particles != 1:
            raise InputError(f"the reference renders one set of maps, got {maps.num_particles} particles",
                             fix="pass maps.particle(i)")
        maps = maps.particle(0)
    for k, v in enumerate(views):
        if not isinstance(v.camera, PerspectiveCamera):
            raise InputError(f"view {k} has a {type(v.camera).__name__}; the Mitsuba reference needs a "
                             "PerspectiveCamera", fix="use perspective views of the mesh")
        if any(not _is_environment(l) and not l.falloff for l in v.lights):
            raise InputError(f"view {k} has a light without distance falloff, which Mitsuba's point emitter "
                             "cannot represent", fix="use PointLight(..., falloff=True)")
    return maps


def render_reference(maps: SVBRDF, views, mesh, *, camera: str = "rays", spp: int = 64, eps: float = 1e-8,
                     ks_factor: bool = True, seed: int = 0, variant: str | None = None, integrator: str = "direct",
                     max_depth: int = 8, batches: int = 1):
    """Mitsuba's render ``[V, H, W, 3]`` (float64, linear radiance) of ``maps`` on ``mesh`` under ``views``.

    The counterpart of ``shade.render(maps, views, mesh)[0]`` (see the module docstring): ``camera``
    ``"rays"`` shades our pixel-centre rays (a point light: exact with one sample; an environment light:
    the mean of ``spp`` samples per ray), ``"sensor"`` renders through a Mitsuba perspective sensor with
    ``spp`` samples per pixel and a box filter. ``eps`` and ``ks_factor`` as in
    :func:`~bayes_brdf.render.shade.shade`; ``variant`` defaults to the project's
    (:func:`~bayes_brdf.mitsuba_env.default_variant`); view ``k`` is seeded ``seed + 104729 k``. Each light
    of a view is one pass with that light the only emitter in the scene (a point light: a ``point`` emitter,
    no BSDF samples; an environment: ``envmap`` with emitter and BSDF samples under MIS), and the passes
    are summed.

    ``integrator="path"``: every pass through Mitsuba's ``path`` integrator (emitter and BSDF samples at each
    bounce under MIS, Russian roulette from depth 5, at most ``max_depth``: 2 is direct light only, 8 the
    default), ``spp`` samples per pixel for every light: light that bounced between parts of the mesh
    (interreflections), with Monte Carlo noise ~ 1 / sqrt(spp). Light transport is linear in the emitters,
    so the sum of one pass per light is the render of all of them at once.

    ``batches = B > 1`` also returns the renderer's own variance of each pixel: ``(renders, variance)``, both
    ``[V, H, W, 3]``, from ``B`` independent renders of ``spp / B`` samples (``spp`` a multiple of ``B``), the
    variance of their mean estimated from their spread (what a likelihood adds to the photo noise,
    :mod:`bayes_brdf.models.noise`).

    Example:
        >>> from bayes_brdf.render import SVBRDF, collocated_views     # doctest: +SKIP
        >>> from bayes_brdf.render.mesh import Mesh                    # doctest: +SKIP
        >>> views = collocated_views(2, 4.0, resolution=32, power=20)  # doctest: +SKIP
        >>> render_reference(SVBRDF.constant(), views, Mesh.sphere()).shape   # doctest: +SKIP
        torch.Size([2, 32, 32, 3])
    """
    views = _check_request(views, camera, integrator, spp, max_depth, batches, variant)
    maps = _check(maps, views)
    with _LOCK, mitsuba_variant(variant) as mi:
        rs = SCENES.get(mesh, mi.variant())
        rs.set_maps(maps, eps=eps, ks_factor=ks_factor)
        path = rs.path_integrator(int(max_depth)) if integrator == "path" else None
        return _render_views(rs, views, camera, int(spp), seed, path, batches)


def _render_views(rs, views, camera: str, spp: int, seed: int, path, batches: int):
    """The views' renders ``[V, H, W, 3]`` by ``rs`` (view ``k`` seeded ``seed + 104729 k``); with ``batches``
    ``B > 1``, ``(renders, variance)``: ``B`` independent renders of ``spp / B`` samples each (batch ``b`` seeded
    ``+ 7 b``), their mean, and the variance of that mean estimated from their spread (``var / B``, ``[V, H, W,
    3]``): the renderer's own Monte Carlo variance of each pixel."""
    def one(k, v, n, s):
        return rs.render_rays(v.camera, v.lights, s, n, path) if camera == "rays" else \
            rs.render_sensor(v.camera, v.lights, n, s, path)
    if batches <= 1:
        return torch.stack([one(k, v, spp, seed + 104729 * k) for k, v in enumerate(views)])
    imgs, var = [], []
    for k, v in enumerate(views):
        b = torch.stack([one(k, v, spp // batches, seed + 104729 * k + 7 * i) for i in range(batches)])
        imgs.append(b.mean(0))
        var.append(b.var(0) / batches)
    return torch.stack(imgs), torch.stack(var)


def render_principled(textures: dict, views, mesh, *, camera: str = "sensor", spp: int = 64, seed: int = 0,
                      variant: str | None = None, integrator: str = "path", max_depth: int = 8, batches: int = 1):
    """Mitsuba's render ``[V, H, W, 3]`` of a metallic-roughness material through its own ``principled`` BSDF.

    ``textures``: ``{"base_color": [3, R, R], "metallic": [1, R, R], "roughness": [1, R, R]}`` in our map
    convention (texel row 0 at ``v = 1``; each map its own resolution), loaded as Mitsuba bitmaps (bilinear,
    clamped, raw); ``specular = 0.5`` (a dielectric ``F0`` of 0.04), no sheen, clearcoat, tint or
    transmission. Everything else as :func:`render_reference` (``camera``, ``integrator``, ``spp``,
    ``max_depth``, one pass per light, view ``k`` seeded ``seed + 104729 k``). Where ``principled`` and our
    :mod:`~bayes_brdf.models.metallic` model differ: docs/models.md.
    """
    views = _check_request(views, camera, integrator, spp, max_depth, batches, variant)
    _check(SVBRDF.constant(), views)
    missing = [k for k in PRINCIPLED_MAPS if k not in textures]
    if missing:
        raise InputError(f"principled textures lack {missing}", fix=f"give {', '.join(PRINCIPLED_MAPS)}")
    for name, c in zip(PRINCIPLED_MAPS, (3, 1, 1)):
        t = torch.as_tensor(textures[name])
        if t.dim() != 3 or t.shape[0] != c:
            raise InputError(f"principled texture {name} has shape {tuple(t.shape)}, expected [{c}, H, W]")
    with _LOCK, mitsuba_variant(variant) as mi:
        rs = PRINCIPLED_SCENES.get(mesh, mi.variant())
        rs.set_principled({k: torch.as_tensor(v) for k, v in textures.items()})
        path = rs.path_integrator(int(max_depth)) if integrator == "path" else None
        return _render_views(rs, views, camera, int(spp), seed, path, batches)


def psnr(ours: Tensor, other: Tensor, peak: float | None = None) -> float:
    """PSNR in dB of ``other`` against ``ours`` on linear radiance over every element, with ``peak`` the
    maximum of ``ours`` (unless given): ``10 log10(peak^2 / mean((ours - other)^2))`` (inf when equal).

    Example:
        >>> import torch
        >>> round(psnr(torch.tensor([1.0, 0.0]), torch.tensor([0.9, 0.0])), 2)
        23.01
    """
    a, b = ours.double(), other.double()
    if a.shape != b.shape:
        raise InputError(f"images have shapes {tuple(a.shape)} and {tuple(b.shape)}")
    mse = float(((a - b) ** 2).mean())
    p = float(a.max()) if peak is None else float(peak)
    return math.inf if mse == 0 else 10 * math.log10(p * p / mse)


# ---------------------------------------------------------------------- the equivalence check's scenes
#: camera direction and its lights ``(direction, relative irradiance at the centre)`` per view, by mesh kind;
#: each set has a low light whose shadows fall on the visible surface (the box on the ground, the bowl's rim
#: into its cavity, the bunny's head and ears onto its body)
CHECK_VIEWS = {
    "block_on_plane": [((1.0, -0.8, 1.0), [((-1.0, 0.25, 0.6), 1.0), ((0.4, 1.0, 1.2), 0.4)]),
                       ((-0.4, -1.2, 0.8), [((1.0, 0.5, 0.35), 1.0)]),
                       ((0.2, 0.3, 1.0), [((-0.6, -1.0, 0.5), 1.0)])],
    "bowl": [((0.3, -0.4, 1.0), [((1.0, 0.2, 0.35), 1.0)]),
             ((-0.8, 0.6, 1.0), [((-0.3, -1.0, 0.4), 1.0), ((1.0, 1.0, 1.5), 0.3)]),
             ((0.0, 1.0, 0.7), [((0.2, -1.0, 0.6), 1.0)])],
    "bunny": [((1.0, -1.0, 0.5), [((-1.0, -1.0, 1.0), 1.0)]),
              ((-1.0, -1.0, 0.3), [((-1.0, 0.0, 1.0), 1.0), ((1.0, -1.0, 0.3), 0.3)]),
              ((0.2, -0.5, 1.0), [((-1.0, 1.0, 1.0), 1.0)]),
              ((0.3, 1.0, 0.6), [((-1.0, 0.0, 1.0), 1.0)])],
}


def check_views(mesh, kind: str, resolution=64, *, distance: float = 2.8, light_distance: float = 3.0,
                fov: float = 40.0) -> list[View]:
    """The views of the equivalence check for a mesh of ``kind`` (a key of :data:`CHECK_VIEWS`): cameras at
    ``distance`` mesh radii from its centre looking at it (up ``+z``), point lights at ``light_distance``
    radii with powers that give the listed irradiance at the centre. The fov alternates ``fov`` and
    ``fov + 5`` (so a sensor's fov is updated between views).

    Example:
        >>> from bayes_brdf.render.mesh import Mesh
        >>> [len(v.lights) for v in check_views(Mesh.block_on_plane(), "block_on_plane", 16)]
        [2, 1, 1]
    """
    if kind not in CHECK_VIEWS:
        raise InputError(f"no check views for {kind!r}", fix=f"use one of {', '.join(CHECK_VIEWS)}")
    c, r = np.asarray(mesh.center), mesh.radius

    def at(d, dist):
        d = np.asarray(d, np.float64)
        return tuple((c + dist * r * d / np.linalg.norm(d)).tolist())

    views = []
    for k, (cd, lights) in enumerate(CHECK_VIEWS[kind]):
        cam = PerspectiveCamera(at(cd, distance), target=tuple(c.tolist()), up=(0.0, 0.0, 1.0),
                                fov=fov + 5.0 * (k % 2), resolution=resolution)
        ls = tuple(PointLight(at(ld, light_distance), p * (light_distance * r) ** 2) for ld, p in lights)
        views.append(View(cam, ls, name=f"{kind}{k}"))
    return views


def sinusoid_maps(resolution: int = 48, dtype=torch.float64) -> SVBRDF:
    """Smooth spatially varying maps for the check: sinusoidal albedo, roughness in ``[0.4, 0.8]``,
    specular around 0.05 and a normal map tilted by up to ~17 degrees along both texture axes.

    Example:
        >>> m = sinusoid_maps(8)
        >>> m.albedo.shape, round(float(m.normal.norm(dim=0).max()), 6)
        (torch.Size([3, 8, 8]), 1.0)
    """
    t = torch.linspace(0, 1, resolution, dtype=dtype)
    y, x = torch.meshgrid(t, t, indexing="ij")
    albedo = torch.stack([0.5 + 0.3 * torch.sin(6.3 * x), 0.4 + 0.3 * torch.cos(5 * y),
                          0.3 + 0.2 * torch.sin(4 * (x + y))])
    roughness = (0.6 + 0.2 * torch.sin(5 * x + 3 * y))[None]
    specular = torch.stack([0.04 + 0.03 * torch.cos(3 * x), torch.full_like(x, 0.05), 0.06 + 0.03 * torch.sin(7 * y)])
    n = torch.stack([0.3 * torch.sin(8 * x), 0.25 * torch.cos(6 * y), torch.ones_like(x)])
    return SVBRDF(albedo, roughness, specular, n / n.norm(dim=0, keepdim=True))


class Unshadowed:
    """``mesh`` with its shadow tests turned off (same hits, nothing occludes a light), for showing that a
    comparison needs shadows: ``shade(maps, GBuffer.build(views, Unshadowed(mesh)))``.

    Example:
        >>> from bayes_brdf.render.mesh import Mesh
        >>> Unshadowed(Mesh.sphere()).occluded(None, None) is None
        True
    """

    def __init__(self, mesh):
        self.mesh = mesh

    def intersect(self, cameras):
        return self.mesh.intersect(cameras)

    def occluded(self, hits, light_positions):
        return None

    def occluded_directions(self, points, normals, directions):
        return None
