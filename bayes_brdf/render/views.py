"""Views (a camera plus its lights) and generators of view configurations.

A :class:`View` is one observation configuration ``theta`` of the paper: where
the camera is, how it images the sample, and which lights are on. Generators:

* :func:`hemisphere_directions` -- Fibonacci, Sobol or random unit directions on
  the upper hemisphere (uniform in solid angle within ``max_zenith``).
* :func:`collocated_views` -- a camera (perspective or rectified) at each
  direction with a flash at the camera ("collocated").
* :func:`orbit_views` -- collocated views on a ring at fixed zenith angle.
* :func:`light_stage_views` -- every camera paired with every light.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch

from .. import checks
from ..errors import InputError
from .cameras import PerspectiveCamera, RectifiedCamera
from .environment import EnvironmentLight
from .lights import PointLight

Camera = PerspectiveCamera | RectifiedCamera


@dataclass(frozen=True)
class View:
    """A camera and the lights that are on for this observation: any mix of
    :class:`~bayes_brdf.render.lights.PointLight` (a flash, a lamp) and at most one
    :class:`~bayes_brdf.render.environment.EnvironmentLight` (the room around it).

    Example:
        >>> v = View.collocated(PerspectiveCamera(position=(0, 0, 3)), power=10)
        >>> v.lights[0].position == v.camera.position
        True
    """

    camera: Camera
    lights: tuple
    name: str = ""

    def __post_init__(self):
        single = isinstance(self.lights, (PointLight, EnvironmentLight))
        lights = (self.lights,) if single else tuple(self.lights)
        if not lights:
            raise InputError(f"view {self.name or ''} has no light", fix="give at least one PointLight")
        bad = [type(l).__name__ for l in lights if not isinstance(l, (PointLight, EnvironmentLight))]
        if bad:
            raise InputError(f"view {self.name or ''} has a light of unknown kind ({bad[0]})",
                             fix="use PointLight or EnvironmentLight")
        if sum(isinstance(l, EnvironmentLight) for l in lights) > 1:
            raise InputError(f"view {self.name or ''} has more than one environment light",
                             fix="merge the environment maps into one")
        object.__setattr__(self, "lights", lights)

    @property
    def point_lights(self) -> tuple:
        """The view's point lights (flashes, lamps), in order."""
        return tuple(l for l in self.lights if isinstance(l, PointLight))

    @property
    def environment(self) -> EnvironmentLight | None:
        """The view's environment light, or ``None``."""
        return next((l for l in self.lights if isinstance(l, EnvironmentLight)), None)

    @classmethod
    def collocated(cls, camera: Camera, power=1.0, falloff: bool = True, name: str = "") -> "View":
        """A flash next to the lens: one point light at the camera position."""
        return cls(camera, (PointLight(camera.position, power, falloff),), name)

    @property
    def resolution(self) -> tuple[int, int]:
        return self.camera.resolution

    # -------------------------------------------------------------- (de)serialise
    def to_dict(self) -> dict:
        cam = asdict(self.camera)
        cam["type"] = "rectified" if isinstance(self.camera, RectifiedCamera) else "perspective"
        return {"name": self.name, "camera": cam,
                "lights": [l.to_dict() if isinstance(l, EnvironmentLight) else asdict(l) for l in self.lights]}

    @classmethod
    def from_dict(cls, d: dict, where: str = "view", environments: dict | None = None) -> "View":
        """The view of :meth:`to_dict`; an environment light's map is looked up by its digest in
        ``environments`` (``{digest: radiance [H, W, 3]}``, as :class:`~bayes_brdf.render.scene.Scene` saves)."""
        try:
            cam = dict(d["camera"])
            kind = cam.pop("type", "perspective")
            cam_cls = {"rectified": RectifiedCamera, "perspective": PerspectiveCamera}[kind]
            lights = []
            for l in d["lights"]:
                l = dict(l)
                if l.pop("type", "point") == "environment":
                    dg = l.pop("digest")
                    if dg not in (environments or {}):
                        raise InputError(f"the environment map {dg} of this view is missing from the file",
                                         fix="re-save the file with its environment maps")
                    env = EnvironmentLight(environments[dg], l.get("scale", 1.0), l.get("to_world"), l.get("name", ""))
                    if env.digest != dg:
                        raise InputError(f"the environment map {dg} does not match its stored digest",
                                         fix="the file is damaged: re-save it")
                    lights.append(env)
                else:
                    lights.append(PointLight(**l))
            return cls(cam_cls(**cam), tuple(lights), d.get("name", ""))
        except InputError as e:
            raise InputError(str(e), where=where) from None
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"malformed view entry ({e})", where=where,
                             fix="each view needs 'camera' {type, position, ...} and 'lights' [{position, power}]") from None


# ---------------------------------------------------------------- direction sets
def hemisphere_directions(n: int, method: str = "fibonacci", max_zenith: float = 90.0,
                          seed: int = 0) -> torch.Tensor:
    """``n`` unit directions ``[n, 3]`` (float64) on the upper hemisphere.

    Uniform in solid angle over zenith angles ``[0, max_zenith]`` degrees.
    ``method``: ``"fibonacci"`` (deterministic spiral), ``"sobol"`` (scrambled,
    by ``seed``) or ``"random"`` (i.i.d., by ``seed``).

    Example:
        >>> hemisphere_directions(100, "sobol", max_zenith=60).shape
        torch.Size([100, 3])
    """
    checks.count(n, "number of directions", least=1)
    if not 0 < max_zenith <= 90:
        raise InputError(f"max_zenith must be in (0, 90] degrees, got {max_zenith}")
    if method == "fibonacci":
        i = torch.arange(n, dtype=torch.float64)
        u = (i + 0.5) / n
        v = (i * (math.sqrt(5) - 1) / 2) % 1.0  # golden-ratio increments
    elif method == "sobol":
        s = torch.quasirandom.SobolEngine(2, scramble=True, seed=seed).draw(n, dtype=torch.float64)
        u, v = s[:, 0], s[:, 1]
    elif method == "random":
        g = torch.Generator().manual_seed(seed)
        u, v = torch.rand(2, n, generator=g, dtype=torch.float64)
    else:
        raise InputError(f"unknown direction method '{method}'", fix="use fibonacci, sobol or random")
    cmin = math.cos(math.radians(max_zenith))
    cos_t = 1 - u * (1 - cmin)
    sin_t = (1 - cos_t**2).clamp_min(0).sqrt()
    phi = 2 * math.pi * v
    return torch.stack([sin_t * phi.cos(), sin_t * phi.sin(), cos_t], dim=-1)


def _cameras(dirs, radius, camera, resolution, fov, target):
    tgt = torch.tensor(target, dtype=torch.float64)
    out = []
    for d in dirs:
        pos = tuple((tgt + radius * d).tolist())
        if camera == "perspective":
            out.append(PerspectiveCamera(pos, target=target, fov=fov, resolution=resolution))
        elif camera == "rectified":
            out.append(RectifiedCamera(pos, resolution=resolution))
        else:
            raise InputError(f"unknown camera kind '{camera}'", fix="use perspective or rectified")
    return out


def collocated_views(n: int, radius: float, *, method: str = "fibonacci", max_zenith: float = 60.0,
                     seed: int = 0, camera: str = "perspective", resolution=(128, 128), fov: float = 45.0,
                     power=1.0, falloff: bool = True, target=(0.0, 0.0, 0.0)) -> list[View]:
    """``n`` collocated (flash) views at distance ``radius`` from ``target``.

    Example:
        >>> vs = collocated_views(10, radius=3.0, method="sobol", resolution=32)
        >>> len(vs), vs[0].resolution
        (10, (32, 32))
    """
    dirs = hemisphere_directions(n, method, max_zenith, seed)
    cams = _cameras(dirs, radius, camera, resolution, fov, target)
    return [View.collocated(c, power, falloff, name=f"{method}{i}") for i, c in enumerate(cams)]


def orbit_views(n: int, radius: float, zenith: float = 30.0, *, camera: str = "perspective",
                resolution=(128, 128), fov: float = 45.0, power=1.0, falloff: bool = True,
                target=(0.0, 0.0, 0.0)) -> list[View]:
    """``n`` collocated views evenly spaced in azimuth at fixed ``zenith`` (degrees).

    Example:
        >>> [round(v.camera.position[2], 3) for v in orbit_views(2, 2.0, zenith=60)]
        [1.0, 1.0]
    """
    t = math.radians(zenith)
    phi = torch.arange(n, dtype=torch.float64) * 2 * math.pi / n
    dirs = torch.stack([math.sin(t) * phi.cos(), math.sin(t) * phi.sin(), torch.full_like(phi, math.cos(t))], -1)
    cams = _cameras(dirs, radius, camera, resolution, fov, target)
    return [View.collocated(c, power, falloff, name=f"orbit{i}") for i, c in enumerate(cams)]


def light_stage_views(camera_dirs, light_dirs, camera_radius: float, light_radius: float, *,
                      camera: str = "perspective", resolution=(128, 128), fov: float = 45.0,
                      power=1.0, falloff: bool = True, target=(0.0, 0.0, 0.0)) -> list[View]:
    """Light-stage configurations: every camera paired with every light (one light on per view).

    ``camera_dirs`` ``[C, 3]`` and ``light_dirs`` ``[L, 3]`` are unit directions
    (e.g. from :func:`hemisphere_directions`); returns ``C * L`` views ordered
    camera-major.

    Example:
        >>> cams = hemisphere_directions(3); lights = hemisphere_directions(4, "sobol")
        >>> len(light_stage_views(cams, lights, 3.0, 5.0))
        12
    """
    cams = _cameras(torch.as_tensor(camera_dirs, dtype=torch.float64), camera_radius, camera, resolution, fov, target)
    tgt = torch.tensor(target, dtype=torch.float64)
    lights = [PointLight(tuple((tgt + light_radius * torch.as_tensor(d, dtype=torch.float64)).tolist()), power, falloff)
              for d in light_dirs]
    return [View(c, (l,), name=f"cam{i}_light{j}") for i, c in enumerate(cams) for j, l in enumerate(lights)]
