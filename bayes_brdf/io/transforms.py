"""NeRF / nerfstudio ``transforms.json`` captures of an object with a known mesh.

A ``transforms.json`` (the layout of NeRF's Blender scenes, instant-ngp and
nerfstudio), extended with the mesh, the length unit and the light::

    {"mesh": "mesh.obj", "units": "cm", "up": "z",
     "light": {"type": "collocated", "power": [1500, 1500, 1500]},
     "w": 64, "h": 48, "camera_angle_x": 0.785398,
     "frames": [{"file_path": "images/frame_000.exr",
                 "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 30], [0, 0, 0, 1]]}]}

* ``frames[].transform_matrix`` -- 4 x 4 camera-to-world, OpenGL convention:
  the camera looks along its ``-z`` column, ``+y`` is up in the image and
  ``+x`` to the right. It must be rigid (orthonormal rotation within 1e-4,
  determinant +1, last row ``0 0 0 1``).
* ``frames[].file_path`` -- the photo, relative to the JSON's folder; as in
  nerfstudio the extension may be left out (``.png``, ``.exr``, ``.jpg`` are
  tried). 8-bit (or 16-bit) PNG / JPEG photos are decoded to linear with
  ``gamma`` and pixels at the maximum code are flagged saturated; EXR images are
  linear radiance. Optional ``frames[].mask`` (or nerfstudio's ``mask_path``):
  a PNG, white = usable; optional ``frames[].saturated``: a PNG of pixels known
  to be clipped (written by :func:`save_transforms`).
* Intrinsics, at the top level or per frame (a frame's value wins): ``w``,
  ``h`` (pixels; the photos must have this size), and either
  ``camera_angle_x`` (the full horizontal field of view, radians) or
  ``fl_x`` / ``fl_y`` / ``cx`` / ``cy`` (pixels). Only a symmetric pinhole with
  square pixels is supported (what :class:`~bayes_brdf.render.cameras.PerspectiveCamera`
  models): ``cx = w/2`` and ``cy = h/2`` within half a pixel, ``fl_x = fl_y``
  within 0.1%, and no lens distortion (``k1 k2 k3 k4 p1 p2`` zero, no fisheye
  ``camera_model``). Anything else is an :class:`~bayes_brdf.errors.InputError`:
  undistort / crop the photos first.
* ``mesh`` -- the object's mesh file (OBJ, PLY, GLB, glTF), relative to the JSON.
* ``units`` (required) -- the length unit of the poses, light positions AND the
  mesh file: ``mm``, ``cm``, ``m``, ``in`` or ``ft``. Everything is converted to
  cm (the scene unit): lengths are multiplied by ``s`` (e.g. 100 for ``m``) and
  light powers by ``s**2``, because a power is given in the convention
  ``radiance = f (n.l) power / d**2`` with ``d`` in the file's unit: the
  radiance, hence every pixel, is unchanged.
* ``up`` (default ``"z"``) -- the world up axis of poses and mesh: ``"z"``,
  ``"y"`` (``(x, y, z) -> (x, -z, y)``), ``"-y"`` or ``"-z"``; poses, lights
  and mesh are rotated to z-up together.
* The lights: ``"light"`` (one light object) or ``"lights"`` (a list of them), at the top level (every
  frame) or per frame (a frame's own ``light`` / ``lights`` replace the top level's). Light objects:
  ``{"type": "collocated", "power": [r, g, b]}`` (a flash at the frame's camera; ``type`` defaults to
  collocated), ``{"type": "point", "position": [x, y, z], "power": ...}`` (a fixed light) and
  ``{"type": "environment", "map": "env.exr", "scale": 1.0, "to_world": [[4 x 4]]}`` (an equirectangular
  OpenEXR or Radiance ``.hdr`` map at infinity, read as Mitsuba's ``envmap``: see
  :class:`~bayes_brdf.render.environment.EnvironmentLight`; ``map`` relative to the JSON, each map read
  once; ``scale`` default 1; ``to_world`` default the identity, a rotation (a mirror allowed) in the file's
  world frame, turned with the poses by the ``up`` conversion; radiance is not changed by ``units``). At
  most one environment per frame. The older per-frame ``light_position`` (+ ``light_power``, else the
  top-level point light's power) is a point light that takes the place of the top-level point or collocated
  light(s), keeping a top-level environment; a frame's ``light_power`` alone changes the power of the
  top-level point or collocated light for that frame.

Unknown keys (nerfstudio's ``applied_transform``, ``camera_model: "OPENCV"``
with zero distortion, ...) are ignored.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import torch

from .. import checks
from ..errors import InputError
from ..observations import Observations
from ..render.cameras import PerspectiveCamera
from ..render.lights import PointLight
from ..render.views import View
from .images import check_gamma, parse_resolution, read_raw, resample, resample_mask, srgb_to_linear, to_rgb
from .jsonfile import read_json_object

__all__ = ["load_transforms", "save_transforms", "TRANSFORMS_FILE", "is_transforms_file"]

TRANSFORMS_FILE = "transforms.json"
_EXTENSIONS = (".png", ".exr", ".jpg", ".jpeg")
_INTRINSICS = ("w", "h", "fl_x", "fl_y", "cx", "cy", "camera_angle_x", "camera_angle_y")
_DISTORTION = ("k1", "k2", "k3", "k4", "p1", "p2")
_PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL")
_FIX = "undistort / crop the photos to a centred pinhole first (e.g. nerfstudio's or COLMAP's image_undistorter)"


def is_transforms_file(p: Path) -> bool:
    """Whether ``p`` is named like a transforms file (``transforms.json``, ``transforms_train.json``, ...)."""
    return re.fullmatch(r"transforms(_\w+)?\.json", p.name, re.IGNORECASE) is not None


# ------------------------------------------------------------------ small parsers
def _matrix(v, where, key: str, *, mirror: bool = False, fix: str | None = None) -> np.ndarray:
    """A finite rigid 4 x 4 at ``key``: orthonormal 3 x 3 within 1e-4 (a proper rotation unless ``mirror``), last
    row ``0 0 0 1``."""
    ok = isinstance(v, (list, tuple)) and len(v) == 4 and all(isinstance(r, (list, tuple)) and len(r) == 4 for r in v)
    if not ok:
        shape = (f"{len(v)} rows" if isinstance(v, (list, tuple)) else type(v).__name__)
        raise InputError(f"{key} must be a 4x4 list of rows, got {shape}", where=where,
                         fix=fix or "give the 4x4 camera-to-world matrix [[r00, r01, r02, tx], ..., [0, 0, 0, 1]]")
    m = np.array([[checks.finite(x, key, where=where) for x in r] for r in v])
    if np.abs(m[3] - (0, 0, 0, 1)).max() > 1e-6:
        raise InputError(f"{key} is not rigid (last row {m[3].tolist()}, expected [0, 0, 0, 1])", where=where,
                         fix=fix or "give a camera-to-world rotation + translation")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    det = float(np.linalg.det(r))
    if err > 1e-4 or (det < 0 and not mirror):
        why = (f"column norms {', '.join(f'{x:.4g}' for x in np.linalg.norm(r, axis=0))}" if err > 1e-4 else "")
        why = ", ".join(x for x in (why, f"max |R^T R - I| = {err:.2g}", f"det = {det:.4g}") if x)
        raise InputError(f"{key} is not rigid ({why})", where=where,
                         fix=fix or "give an orthonormal right-handed rotation (no scale, no mirror) and put the "
                                    "scale into 'units'")
    return m


# ------------------------------------------------------------------ intrinsics
def _intrinsics(top: dict, frame: dict, i: int, where) -> dict:
    """The frame's intrinsics (frame values win), validated numbers; ``"w"``/``"h"`` may be missing."""
    out = {}
    for k in _INTRINSICS:
        src = frame if k in frame else top if k in top else None
        if src is None:
            continue
        key = f"frames[{i}].{k}" if src is frame else k
        out[k] = (checks.finite if k in ("cx", "cy") else checks.positive)(src[k], key, where=where)
        out[k + "@"] = key
    for k in _DISTORTION:
        v = frame.get(k, top.get(k, 0.0))
        key = f"frames[{i}].{k}" if k in frame else k
        if checks.finite(v, key, where=where) != 0:
            raise InputError(f"{key} = {v!r}: lens distortion is not supported yet", where=where, fix=_FIX)
    model = frame.get("camera_model", top.get("camera_model"))
    if model is not None and (not isinstance(model, str) or model.upper() not in _PINHOLE_MODELS):
        raise InputError(f"camera_model {model!r} is not supported (only pinhole cameras)", where=where, fix=_FIX)
    for k in ("w", "h"):
        if k in out and out[k] != int(out[k]):
            raise InputError(f"{out[k + '@']} must be a whole number of pixels, got {out[k]}", where=where)
    return out


def _fov(intr: dict, h: int, w: int, i: int, where) -> float:
    """Full horizontal field of view in degrees of frame ``i`` with ``h x w`` photos."""
    fx, fy = intr.get("fl_x"), intr.get("fl_y")
    if fx is not None and fy is not None and abs(fx - fy) > 1e-3 * max(fx, fy):
        raise InputError(f"{intr['fl_x@']} = {fx:g} and {intr['fl_y@']} = {fy:g} differ by more than 0.1%: "
                         "non-square pixels are not supported yet", where=where, fix=_FIX)
    for c, size, name in (("cx", w, "w"), ("cy", h, "h")):
        if c in intr and abs(intr[c] - size / 2) > 0.5:
            raise InputError(f"{intr[c + '@']} = {intr[c]:g} is not the image centre {name}/2 = {size / 2:g} "
                             "(within half a pixel): off-centre principal points are not supported yet",
                             where=where, fix=_FIX)
    ax = intr.get("camera_angle_x")
    if ax is not None and not ax < math.pi:
        raise InputError(f"{intr['camera_angle_x@']} = {ax:g} must be below pi (radians)", where=where)
    f = fx if fx is not None else fy
    if f is not None:
        from_f = 2 * math.atan(w / (2 * f))
        if ax is not None and abs(math.tan(ax / 2) - math.tan(from_f / 2)) > 1e-3 * math.tan(from_f / 2):
            raise InputError(f"{intr['camera_angle_x@']} = {ax:g} disagrees with the focal length "
                             f"{f:g} px (which gives {from_f:.6g} for w = {w})", where=where,
                             fix="give one of them, or consistent values")
        ax = from_f
    if ax is None:
        raise InputError(f"frames[{i}] has no field of view", where=where,
                         fix="give 'camera_angle_x' (radians) or 'fl_x' (pixels), at the top level or per frame")
    ay = intr.get("camera_angle_y")
    if ay is not None:
        want = math.tan(ax / 2) * h / w
        if not ay < math.pi or abs(math.tan(ay / 2) - want) > 1e-3 * want:
            raise InputError(f"{intr['camera_angle_y@']} = {ay:g} does not match camera_angle_x = {ax:g} for "
                             f"{w}x{h} photos: non-square pixels are not supported yet", where=where, fix=_FIX)
    return math.degrees(ax)


# ------------------------------------------------------------------ resolution
def _target(native: tuple[int, int], resolution, max_resolution, where) -> tuple[int, int] | None:
    """The ``(H, W)`` to resample to (None: keep ``native``), keeping the aspect ratio; never upsamples."""
    h, w = native

    def scaled(side: int) -> tuple[int, int]:
        f = side / max(h, w)
        return max(1, round(h * f)), max(1, round(w * f))

    if resolution is not None:
        if isinstance(resolution, (tuple, list)):
            rh, rw = parse_resolution(resolution)
            if abs(rh - rw * h / w) > 0.5 and abs(rw - rh * w / h) > 0.5:
                raise InputError(f"resolution {rh}x{rw} (HxW) changes the photos' aspect ratio ({h}x{w})",
                                 where=where, fix="give one number (the longer side) to keep the aspect ratio")
            target = (rh, rw)
        else:
            rh, _ = parse_resolution(resolution)
            target = scaled(rh)
        if target[0] > h or target[1] > w:
            raise InputError(f"--resolution {resolution} is above the photos' native {h}x{w}", where=where,
                             fix=f"use at most {max(h, w)} (the longer side; upsampling adds no information), "
                                 "or leave it unset for the native size")
        return None if target == native else target
    if max_resolution is not None:
        m, _ = parse_resolution(max_resolution)
        if m < max(h, w):
            return scaled(m)
    return None


# ------------------------------------------------------------------ images
def _find(folder: Path, rel: str) -> Path | None:
    p = folder / rel
    if p.is_file():
        return p
    for ext in _EXTENSIONS:
        for q in (p.with_name(p.name + ext), p.with_name(p.name + ext.upper())):
            if q.is_file():
                return q
    return None


class _Decoder:
    def __init__(self, gamma):
        self.g = check_gamma(gamma)
        self.luts: dict[float, torch.Tensor] = {}

    def __call__(self, p: Path):
        """``(linear [H, W, 3] float32, saturated [H, W] bool)``."""
        raw, full = read_raw(p)
        rgb = to_rgb(raw)
        h, w = rgb.shape[:2]
        if full is None:
            if not np.isfinite(rgb).all():
                raise InputError("image has NaN or infinite pixel values", where=p, fix="re-export it with finite values")
            if (rgb < 0).any():
                raise InputError(f"image has negative pixel values (min {float(rgb.min()):.3g})", where=p,
                                 fix="radiance must be >= 0; clamp or re-export it")
            return torch.from_numpy(np.ascontiguousarray(rgb, dtype=np.float32)), torch.zeros(h, w, dtype=torch.bool)
        if full not in self.luts:
            codes = torch.arange(int(full) + 1, dtype=torch.float64) / full
            self.luts[full] = srgb_to_linear(codes, self.g).to(torch.float32)
        codes = torch.from_numpy(np.ascontiguousarray(rgb.astype(np.int64)))
        return self.luts[full][codes], codes.amax(dim=-1) >= int(full)


def _read_mask(p: Path, shape, what: str, where) -> torch.Tensor:
    raw, full = read_raw(p)
    if raw.shape[:2] != tuple(shape):
        raise InputError(f"{what} image is {raw.shape[1]}x{raw.shape[0]} but its photo is {shape[1]}x{shape[0]}",
                         where=p, fix="give the mask at the photo's size")
    return torch.from_numpy(np.ascontiguousarray(raw[..., 0] > (full or 1.0) / 2))


# ------------------------------------------------------------------ lights
LIGHT_TYPES = ("collocated", "point", "environment")
_LIGHT_FIX = ('use {"type": "collocated", "power": [r, g, b]}, {"type": "point", "position": [x, y, z], '
              '"power": [r, g, b]} or {"type": "environment", "map": "env.exr"}')


class _Lights:
    """Reads the light objects of one transforms file: converted to cm and z-up, environment maps read once."""

    def __init__(self, folder: Path, rot: np.ndarray, s: float, where):
        self.folder, self.rot, self.s, self.where = folder, rot, s, where
        self.maps: dict[Path, np.ndarray] = {}            # resolved map path -> radiance [H, W, 3]
        self.envs: dict[tuple, object] = {}               # (path, scale, to_world) -> EnvironmentLight
        self.used: list[str] = []                         # the maps' paths as written, in order of first use

    def one(self, L, key: str):
        """One light object at ``key`` as ``("collocated", power)``, ``("point", position, power)`` (cm, z-up,
        power times s^2) or ``("environment", EnvironmentLight)``."""
        if not isinstance(L, dict):
            raise InputError(f"{key} must be an object, got {L!r}", where=self.where, fix=_LIGHT_FIX)
        kind = L.get("type", "collocated")
        if kind not in LIGHT_TYPES:
            raise InputError(f"unknown {key}.type {kind!r}", where=self.where,
                             fix=f"use one of {', '.join(LIGHT_TYPES)}")
        if kind == "environment":
            return ("environment", self._environment(L, key))
        if "power" not in L:
            raise InputError(f"{key}.power is missing", where=self.where, fix="give the light power [r, g, b]")
        power = np.array(checks.rgb(L["power"], f"{key}.power", where=self.where)) * self.s ** 2
        if kind == "collocated":
            return ("collocated", power)
        if "position" not in L:
            raise InputError(f"{key}.position is missing for a point light", where=self.where,
                             fix=f"give {key}.position [x, y, z] (in 'units'), or use type collocated")
        pos = self.s * (self.rot @ np.array(checks.vec3(L["position"], f"{key}.position", where=self.where)))
        return ("point", pos, power)

    def _environment(self, L: dict, key: str):
        from ..render.environment import EnvironmentLight

        rel = L.get("map")
        if not isinstance(rel, str) or not rel:
            raise InputError(f"{key}.map must be the path of the environment map, got {rel!r}", where=self.where,
                             fix=f'give {key}.map, e.g. "env.exr" (an OpenEXR or Radiance .hdr file, relative to '
                                 "the transforms file)")
        scale = checks.finite(L.get("scale", 1.0), f"{key}.scale", where=self.where)
        if scale < 0:
            raise InputError(f"{key}.scale must be >= 0, got {scale:g}", where=self.where)
        m = np.eye(4)
        if L.get("to_world") is not None:
            m = _matrix(L["to_world"], self.where, f"{key}.to_world", mirror=True,
                        fix="give the environment's to_world as a rotation (Mitsuba's envmap to_world, in the "
                            "file's world frame), without scale or shear")
        t = np.eye(4)                                     # file frame -> cm, z-up (as the poses)
        t[:3, :3] = self.rot
        m = t @ m
        m[:3, 3] *= self.s
        path = (self.folder / rel).resolve()
        tw = tuple(tuple(float(x) for x in r) for r in m)
        k = (path, scale, tw)
        if k not in self.envs:
            if path not in self.maps:
                try:
                    env = EnvironmentLight.from_file(path)
                except InputError as e:
                    raise InputError(f"{key}.map {rel!r}: {e.problem} ({path})", where=self.where, fix=e.fix) from None
                self.maps[path] = env.radiance
            self.envs[k] = EnvironmentLight(self.maps[path], scale, tw, name=Path(rel).name)
            if rel not in self.used:
                self.used.append(rel)
        return self.envs[k]

    def of(self, obj: dict, prefix: str):
        """The lights an object (the file or one frame) gives with ``light`` / ``lights``, or ``None``."""
        if "light" in obj and "lights" in obj:
            raise InputError(f"{prefix}light and {prefix}lights are both given", where=self.where,
                             fix="give one light object as 'light' or a list of them as 'lights'")
        if "lights" in obj:
            ls = obj["lights"]
            if not isinstance(ls, list) or not ls:
                raise InputError(f"{prefix}lights must be a non-empty list of light objects, got {ls!r}",
                                 where=self.where, fix=_LIGHT_FIX)
            out = [self.one(L, f"{prefix}lights[{j}]") for j, L in enumerate(ls)]
        elif "light" in obj:
            out = [self.one(obj["light"], f"{prefix}light")]
        else:
            return None
        if sum(x[0] == "environment" for x in out) > 1:
            raise InputError(f"{prefix}lights has more than one environment light", where=self.where,
                             fix="merge the environment maps into one")
        return out


def _frame_lights(lights: _Lights, top, frame: dict, i: int, cam_pos: np.ndarray) -> tuple:
    """Frame ``i``'s lights (``cam_pos`` already in cm): PointLights and at most one EnvironmentLight."""
    where, s = lights.where, lights.s
    own = lights.of(frame, f"frames[{i}].")
    legacy = [k for k in ("light_position", "light_power") if k in frame]
    if own is not None and legacy:
        raise InputError(f"frames[{i}] gives both {'light' if 'light' in frame else 'lights'} and {legacy[0]}",
                         where=where, fix=f"describe frames[{i}]'s lights one way: as light objects, or with "
                                          "light_position / light_power")
    specs = own if own is not None else list(top or [])
    fpow = None
    if "light_power" in frame:
        fpow = np.array(checks.rgb(frame["light_power"], f"frames[{i}].light_power", where=where)) * s * s
    points = [j for j, x in enumerate(specs) if x[0] != "environment"]
    if legacy:
        if "light_position" not in frame and not points:
            raise InputError(f"frames[{i}] has a light_power but no light_position, and the top-level lights hold "
                             "no point or collocated light", where=where,
                             fix=f"add frames[{i}].light_position [x, y, z], or a top-level collocated light")
        if fpow is None and len(points) != 1:
            raise InputError(f"frames[{i}] has a light_position but no light power", where=where,
                             fix=f"add frames[{i}].light_power [r, g, b], or a top-level light with a power")
        if fpow is not None and "light_position" not in frame and len(points) > 1:
            raise InputError(f"frames[{i}].light_power is ambiguous: the top-level lights hold {len(points)} point "
                             "or collocated lights", where=where,
                             fix=f"give frames[{i}] its own 'lights' list instead")
        power = fpow if fpow is not None else specs[points[0]][-1]
        if "light_position" in frame:
            pos = s * (lights.rot @ np.array(checks.vec3(frame["light_position"], f"frames[{i}].light_position",
                                                         where=where)))
            new = ("point", pos, power)
        else:
            new = specs[points[0]][:-1] + (power,)
        at = points[0] if points else 0                  # in the place of the top-level point light(s), else first
        specs = [x for j, x in enumerate(specs) if j not in points]
        specs.insert(min(at, len(specs)), new)
    if not specs:
        raise InputError(f"no light for frames[{i}]", where=where,
                         fix='add "light": {"type": "collocated", "power": [r, g, b]} (a flash at each camera), '
                             '"lights": [...], or per-frame light_position and light_power')
    out = []
    for x in specs:
        if x[0] == "environment":
            out.append(x[1])
        else:
            pos = cam_pos if x[0] == "collocated" else x[1]
            out.append(PointLight(tuple(np.asarray(pos).tolist()), tuple(np.asarray(x[-1]).tolist())))
    return tuple(out)


# ------------------------------------------------------------------ loading
def load_transforms(path, resolution=None, gamma=2.2, *, max_resolution=None) -> Observations:
    """Load a ``transforms.json`` capture (the file, or its folder) as :class:`~bayes_brdf.observations.Observations`.

    See the module docstring for the format. Returns one view per frame: a
    :class:`~bayes_brdf.render.cameras.PerspectiveCamera` (position = the
    matrix's translation, looking along its ``-z`` column with its ``+y``
    column up; ``target`` one cm ahead) and its lights (:class:`~bayes_brdf.render.lights.PointLight` s and at
    most one :class:`~bayes_brdf.render.environment.EnvironmentLight`), all in cm and z-up; the surface is the :class:`~bayes_brdf.render.mesh.Mesh`
    (loaded with the file's ``units`` and ``up``); ``images [V, H, W, 3]``
    linear float32; ``mask`` (the frames' masks, else all True); ``saturated``;
    ``meta`` (format ``"transforms"``, source, units ``"cm"``, file units, up,
    gamma, mesh, native resolution, image names, and ``environment_maps``: the maps' paths as the file gives
    them, when there are any).

    ``resolution``: an int ``R`` resamples every photo so that its LONGER side
    is ``R`` (the aspect ratio kept, sides rounded), an ``(H, W)`` pair to that
    size (same aspect ratio only); ``None`` keeps the native size, or shrinks the
    longer side to ``max_resolution`` when given and smaller. Photos are never
    upsampled. The field of view is kept. ``gamma`` decodes integer photos
    (``2.2``, ``"srgb"`` or any positive exponent), as in :func:`~bayes_brdf.io.captures.load_capture`.

    Example:
        >>> obs = load_transforms("captures/mug/transforms.json", resolution=128)   # doctest: +SKIP
        >>> obs.surface.num_faces, obs.resolution   # doctest: +SKIP
        (5120, (96, 128))
    """
    from ..render.mesh import Mesh
    from ..render.mesh_io import UNITS, UP_AXES

    p = Path(path)
    jf = p / TRANSFORMS_FILE if p.is_dir() else p
    if not jf.is_file():
        raise InputError(f"no {TRANSFORMS_FILE} here" if p.is_dir() else "file not found", where=jf if p.is_dir() else p,
                         fix="point to a folder with a transforms.json, or to the file")
    folder = jf.parent
    check_gamma(gamma)
    d = read_json_object(jf, fix="fix the JSON syntax of the transforms file")
    # units and up axis
    if "units" not in d:
        raise InputError("missing key 'units' (the length unit of the poses and the mesh)", where=jf,
                         fix=f'add e.g. "units": "cm" (one of {", ".join(UNITS)})')
    units = d["units"]
    if not isinstance(units, str) or units not in UNITS:
        raise InputError(f"unknown units {units!r}", where=jf, fix=f"use one of {', '.join(UNITS)}")
    up = d.get("up", "z")
    if not isinstance(up, str) or up not in UP_AXES:
        raise InputError(f"unknown up axis {up!r}", where=jf, fix=f"use one of {', '.join(UP_AXES)}")
    s = UNITS[units] / UNITS["cm"]
    rot = UP_AXES[up]
    # mesh
    if "mesh" not in d:
        raise InputError("missing key 'mesh' (the object's mesh file)", where=jf,
                         fix='add "mesh": "mesh.obj" (a path relative to the transforms file)')
    if not isinstance(d["mesh"], str) or not d["mesh"]:
        raise InputError(f"'mesh' must be a file path, got {d['mesh']!r}", where=jf)
    mesh_file = folder / d["mesh"]
    if not mesh_file.is_file():
        raise InputError(f"the mesh file named by 'mesh' ({d['mesh']}) is missing", where=mesh_file,
                         fix="put the mesh there or fix the 'mesh' path (relative to the transforms file)")
    frames = d.get("frames")
    if not isinstance(frames, list) or not frames:
        raise InputError("'frames' must be a non-empty list", where=jf,
                         fix="give one {file_path, transform_matrix} per photo")
    lights = _Lights(folder, rot, s, jf)
    top = lights.of(d, "")
    # pass 1: everything but the pixels (fails before decoding any photo)
    parsed = []
    for i, f in enumerate(frames):
        if not isinstance(f, dict):
            raise InputError(f"frames[{i}] must be an object, got {type(f).__name__}", where=jf)
        for k in ("file_path", "transform_matrix"):
            if k not in f:
                raise InputError(f"frames[{i}] has no '{k}'", where=jf, fix="give each frame file_path and transform_matrix")
        if not isinstance(f["file_path"], str) or not f["file_path"]:
            raise InputError(f"frames[{i}].file_path must be a path, got {f['file_path']!r}", where=jf)
        img = _find(folder, f["file_path"])
        if img is None:
            raise InputError(f"frames[{i}]: image {f['file_path']} is missing", where=jf,
                             fix=f"put it at {folder / f['file_path']} (tried also {', '.join(_EXTENSIONS)})")
        masks = {}
        for key, what in (("mask", "mask"), ("mask_path", "mask"), ("saturated", "saturated")):
            if f.get(key) is None:
                continue
            if not isinstance(f[key], str):
                raise InputError(f"frames[{i}].{key} must be a path, got {f[key]!r}", where=jf)
            mp = _find(folder, f[key])
            if mp is None:
                raise InputError(f"frames[{i}]: {what} image {f[key]} is missing", where=jf,
                                 fix=f"put it at {folder / f[key]} or remove frames[{i}].{key}")
            masks[what] = mp
        if f.get("variance") is not None:      # the renderer's own variance per pixel (a linear EXR)
            vp = _find(folder, f["variance"]) if isinstance(f["variance"], str) else None
            if vp is None:
                raise InputError(f"frames[{i}]: variance image {f['variance']!r} is missing", where=jf,
                                 fix=f"put it at {folder / str(f['variance'])} or remove frames[{i}].variance")
            masks["variance"] = vp
        m = _matrix(f["transform_matrix"], jf, f"frames[{i}].transform_matrix")
        r = rot @ m[:3, :3]
        pos = s * (rot @ m[:3, 3])
        intr = _intrinsics(d, f, i, jf)
        parsed.append({"image": img, "masks": masks, "R": r, "pos": pos, "intr": intr,
                       "lights": _frame_lights(lights, top, f, i, pos)})
    # pass 2: photos
    decode = _Decoder(gamma)
    images, sats, usable, native, target, views, variances = [], [], [], None, None, [], []
    for i, fr in enumerate(parsed):
        lin, sat = decode(fr["image"])
        h, w = lin.shape[:2]
        intr = fr["intr"]
        for k, size in (("w", w), ("h", h)):
            if k in intr and int(intr[k]) != size:
                raise InputError(f"frames[{i}]: image {fr['image'].name} is {w}x{h} but {intr[k + '@']} = "
                                 f"{int(intr[k])}", where=jf, fix="give the photos' own size (or resize the photos)")
        if native is None:
            native = (h, w)
            target = _target(native, resolution, max_resolution, jf)
        elif (h, w) != native:
            raise InputError(f"frames[{i}]: image {fr['image'].name} is {w}x{h} but frames[0]'s is "
                             f"{native[1]}x{native[0]}", where=jf, fix="all photos of a capture must have one size")
        fov = _fov(intr, h, w, i, jf)
        mask = torch.ones(h, w, dtype=torch.bool)
        if "mask" in fr["masks"]:
            mask = _read_mask(fr["masks"]["mask"], (h, w), "mask", jf)
        if "saturated" in fr["masks"]:
            sat = sat | _read_mask(fr["masks"]["saturated"], (h, w), "saturated", jf)
        var = None
        if "variance" in fr["masks"]:
            var = torch.from_numpy(np.ascontiguousarray(to_rgb(read_raw(fr["masks"]["variance"])[0]),
                                                        dtype=np.float32))
            if tuple(var.shape[:2]) != (h, w):
                raise InputError(f"frames[{i}]: the variance image is {var.shape[1]}x{var.shape[0]}, the photo "
                                 f"{w}x{h}", where=jf)
        if target is not None:
            lin = resample(lin[None], target)[0]
            sat = resample_mask(sat[None], target)[0]
            mask = ~resample_mask(~mask[None], target)[0]
            if var is not None:                  # a mean of independent pixels: the variance over their count
                var = (resample(var[None], target)[0] * (target[0] * target[1] / (h * w))).clamp_min(0)
        if var is not None:
            variances.append(var)
        images.append(lin)
        sats.append(sat)
        usable.append(mask)
        r, pos = fr["R"], fr["pos"]
        forward, cam_up = -r[:, 2], r[:, 1]
        cam = PerspectiveCamera(position=tuple(pos.tolist()), target=tuple((pos + forward).tolist()),
                                up=tuple(cam_up.tolist()), fov=fov, resolution=target or native)
        views.append(View(cam, fr["lights"], name=fr["image"].stem))
    mesh = Mesh.load(mesh_file, units=units, scene_units="cm", up=up)
    meta = {"format": "transforms", "source": str(folder if jf.name == TRANSFORMS_FILE else jf), "units": "cm",
            "file_units": units, "up": up, "gamma": gamma if isinstance(gamma, str) else float(gamma),
            "mesh": str(mesh_file), "native_resolution": list(native),
            "images": [str(fr["image"].relative_to(folder)) if fr["image"].is_relative_to(folder) else str(fr["image"])
                       for fr in parsed]}
    if lights.used:
        meta["environment_maps"] = list(lights.used)
    if variances and len(variances) != len(parsed):
        raise InputError(f"only {len(variances)} of {len(parsed)} frames give a variance image", where=jf,
                         fix="give every frame a variance image or none")
    return Observations(views, torch.stack(images).contiguous(), mesh, mask=torch.stack(usable),
                        saturated=torch.stack(sats), meta=meta,
                        variance=torch.stack(variances).contiguous() if variances else None)


# ------------------------------------------------------------------ writing
def _dumps(doc) -> str:
    """JSON with indent 2, but each innermost list of numbers on one line (matrix rows, colours)."""
    import json

    text = json.dumps(doc, indent=2, allow_nan=False)
    return re.sub(r"\[\s*(-?[\d.eE+-]+(?:,\s*-?[\d.eE+-]+)*)\s*\]",
                  lambda mt: "[" + ", ".join(x.strip() for x in mt.group(1).split(",")) + "]", text) + "\n"


def _map_key(env) -> str:
    """The content of an environment's map alone (not its scale or rotation): views sharing a map write it once."""
    import hashlib

    return hashlib.sha256(env.radiance.contiguous().numpy().tobytes()
                          + repr(tuple(env.radiance.shape)).encode()).hexdigest()[:16]


def _environment_files(views) -> dict:
    """``{environment digest: (file name, EnvironmentLight)}`` of the views' environment lights, a map written
    once however many views (and rotations, scales) use it: ``env.exr`` when there is one map,
    ``env_<content hash>.exr`` each when there are several."""
    by_digest, maps = {}, {}
    for v in views:
        e = v.environment
        if e is not None and e.digest not in by_digest:
            by_digest[e.digest] = k = _map_key(e)
            maps.setdefault(k, e)
    names = {k: "env.exr" if len(maps) == 1 else f"env_{k[:8]}.exr" for k in maps}
    return {dg: (names[k], maps[k]) for dg, k in by_digest.items()}


def _light_object(light, cam, env_files) -> dict:
    """The transforms.json object of one light of a view (cm, z-up)."""
    if isinstance(light, PointLight):
        if light.position == cam.position:
            return {"type": "collocated", "power": list(light.power)}
        return {"type": "point", "position": list(light.position), "power": list(light.power)}
    return {"type": "environment", "map": env_files[light.digest][0], "scale": light.scale,
            "to_world": [list(r) for r in light.to_world]}


def save_transforms(obs, folder, image_format: str = "exr", *, mesh_path: str | None = None, gamma=2.2) -> Path:
    """Write observations of a mesh as a ``transforms.json`` capture; returns the path of ``transforms.json``.

    ``obs`` is an :class:`~bayes_brdf.observations.Observations` (or a
    ``(views, images, mesh)`` tuple) whose surface is a
    :class:`~bayes_brdf.render.mesh.Mesh`, whose cameras are
    :class:`~bayes_brdf.render.cameras.PerspectiveCamera` s and whose views' point lights have
    distance falloff, all in cm. Writes ``transforms.json``
    (``units: "cm"``, ``up: "z"``; ``w``, ``h``, and per frame
    ``camera_angle_x`` plus the equivalent ``fl_x = fl_y``, ``cx = w/2``,
    ``cy = h/2``; the lights: with one point light per view as before, a top-level collocated light when every
    view has a flash of one power at its camera, else per-frame ``light_position`` / ``light_power``; with an
    environment or several lights, the light objects (``collocated`` for a point light at the camera,
    ``point``, ``environment``) once at the top level as ``light`` / ``lights`` when every view has the same,
    else per frame), each environment map once as a float32 EXR next to the JSON (``env.exr``, or
    ``env_<content hash>.exr`` when there are several maps), ``images/frame_NNN.exr`` (linear float32, exact) or
    ``.png`` (8-bit, encoded with ``gamma``: load it back with the same gamma;
    values above 1 clip and come back flagged saturated), the mesh as OBJ at
    ``mesh_path`` (relative to ``folder``; default ``<mesh name>.obj``; full
    float64 precision), and, when
    the observations have them, ``masks/frame_NNN.png`` (``mask``) and
    ``saturated/frame_NNN.png``.

    :func:`~bayes_brdf.io.captures.load_capture` of the folder gives the same
    observations back: images exact (EXR) or within 8-bit quantisation (PNG),
    the same rays and lights (to rounding), the same mesh.

    Example:
        >>> save_transforms(obs, "out/sphere_capture")              # doctest: +SKIP
        PosixPath('out/sphere_capture/transforms.json')
    """
    from ..render.mesh import Mesh
    from ..render.mesh_io import obj_text
    from .images import write_exr, write_png
    from .outputs import write_text

    if image_format not in ("exr", "png"):
        raise InputError(f"unknown image format {image_format!r}", fix="use exr (linear, exact) or png (8-bit sRGB)")
    if isinstance(obs, (tuple, list)):
        views, images, surface = obs
        obs = Observations(list(views), torch.as_tensor(images), surface)
    if not isinstance(obs.surface, Mesh):
        raise InputError(f"a transforms.json capture needs a mesh surface, got {type(obs.surface).__name__}",
                         fix="use Mesh.plane(size) for a planar sample, or save_observations for a bundle")
    if mesh_path is None:
        mesh_path = (re.sub(r"[^\w.-]+", "_", obs.surface.name).strip("._") or "mesh") + ".obj"
    mp = Path(mesh_path)
    if mp.is_absolute() or ".." in mp.parts or mp.suffix.lower() != ".obj":
        raise InputError(f"mesh_path {mesh_path!r} must be a relative .obj path inside the folder", fix="e.g. mesh.obj")
    out = Path(folder)
    if out.exists() and not out.is_dir():
        raise InputError("output path exists and is not a folder", where=out, fix="give a folder path")
    h, w = obs.resolution
    env_files = _environment_files(obs.views)
    frames, descs, legacy, collocated, powers = [], [], True, True, set()
    for i, v in enumerate(obs.views):
        cam = v.camera
        if not isinstance(cam, PerspectiveCamera):
            raise InputError(f"view {i} ('{v.name}') has a {type(cam).__name__}: a transforms.json stores only "
                             "perspective (pinhole) cameras", fix="render perspective views of the mesh")
        flat = [l for l in v.point_lights if not l.falloff]
        if flat:
            raise InputError(f"view {i} ('{v.name}') has a point light without distance falloff",
                             fix="a transforms.json stores point lights with 1/d^2 falloff")
        descs.append([_light_object(l, cam, env_files) for l in v.lights])
        legacy &= len(v.lights) == 1 and v.environment is None
        r, u, f = (x.numpy() for x in cam.frame())
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, u, -f, cam.position
        ax = math.radians(cam.fov)
        fl = w / (2 * math.tan(ax / 2))
        frames.append({"file_path": f"images/frame_{i:03d}.{image_format}", "transform_matrix": m.tolist(),
                       "camera_angle_x": ax, "fl_x": fl, "fl_y": fl})
        if legacy:
            collocated &= v.lights[0].position == cam.position
            powers.add(v.lights[0].power)
    doc = {"format": "bayes-brdf transforms/1", "units": "cm", "up": "z", "mesh": mp.as_posix(),
           "w": w, "h": h, "cx": w / 2, "cy": h / 2}
    if legacy:                  # one point light per view: the layout every reader of this format knows
        if collocated and len(powers) == 1:
            doc["light"] = {"type": "collocated", "power": list(powers.pop())}
        else:
            for fr, v in zip(frames, obs.views):
                fr["light_position"], fr["light_power"] = list(v.lights[0].position), list(v.lights[0].power)
    elif all(dl == descs[0] for dl in descs):      # the same lights in every view: once, at the top
        doc["light" if len(descs[0]) == 1 else "lights"] = descs[0][0] if len(descs[0]) == 1 else descs[0]
    else:
        for fr, dl in zip(frames, descs):
            fr["light" if len(dl) == 1 else "lights"] = dl[0] if len(dl) == 1 else dl
    if len({fr["camera_angle_x"] for fr in frames}) == 1:     # one lens: intrinsics once, at the top
        for k in ("camera_angle_x", "fl_x", "fl_y"):
            doc[k] = frames[0][k]
            for fr in frames:
                del fr[k]
    out.mkdir(parents=True, exist_ok=True)
    imgs = obs.images.detach().cpu().float()
    for i, fr in enumerate(frames):
        if image_format == "exr":
            write_exr(out / fr["file_path"], imgs[i])
        else:
            write_png(out / fr["file_path"], imgs[i], gamma=gamma)
        for name, key in (("mask", "mask"), ("saturated", "saturated")):
            mk = getattr(obs, name)
            keep = mk is not None and (bool((~mk[i]).any()) if name == "mask" else bool(mk.any()))
            if keep:
                fr[key] = f"{'masks' if name == 'mask' else name}/frame_{i:03d}.png"
                write_png(out / fr[key], mk[i].detach().cpu().float(), linear=False)
        if obs.variance is not None:           # the renderer's own variance per pixel (linear EXR)
            fr["variance"] = f"variance/frame_{i:03d}.exr"
            write_exr(out / fr["variance"], obs.variance[i].detach().cpu().float())
    for name, env in dict(env_files.values()).items():
        write_exr(out / name, env.radiance)
    write_text(out / mp, obj_text(obs.surface))
    doc["frames"] = frames
    return write_text(out / TRANSFORMS_FILE, _dumps(doc))
