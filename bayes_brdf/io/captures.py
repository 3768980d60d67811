"""Load real captures (rectified flash photos of a planar sample) as :class:`Observations`.

Recognised folder layouts (auto-detected from the files present):

=============================  =============================================================
format                         files
=============================  =============================================================
``bundle``                     ``observations.json`` + images (our own, see :mod:`.bundle`)
``svbrdf-diff-renderer``       ``parameters.json`` (``image_size``, ``camera_pos``,
                               ``light_pos``, ``light_pow``, ``idx``) + ``NN.png``
``svbrdf-diff-renderer-optim`` ``optim.json`` (``im_size``, ...) + ``NN.png``
``materialgan``                ``NN.png``, ``camera_pos.txt``, ``light_pos.txt``
                               (``x,y,z`` per line), ``image_size.txt``, ``light_power.txt``
``transforms``                 ``transforms.json`` (NeRF / nerfstudio poses, plus ``mesh``,
                               ``units`` and ``light``) + photos + a mesh file: perspective
                               photos of an object (see :mod:`.transforms`)
=============================  =============================================================

For the planar formats, positions and the sample size are in cm; the sample is the square of side
``image_size`` centred at the origin on ``z = 0`` and each photo is already
rectified to its texel grid (row 0 at ``+y``). As in svbrdf-diff-renderer,
``idx`` selects which poses (and which ``NN.png``) are used: view ``i`` is
photo ``f"{idx[i]:02d}.png"`` with ``camera_pos[idx[i]]`` / ``light_pos[idx[i]]``.

Nothing in a capture folder is skipped without a word: in a MaterialGAN folder
a numbered image that is not a PNG (``03.exr``, ``03.jpg``) or two photos with
one index (``3.png`` and ``03.png``) is an :class:`~bayes_brdf.errors.InputError`,
and other image files (``preview.jpg``) are ignored with a ``UserWarning``. A
file whose content is not what its name says (an EXR named ``00.png``) is an
InputError too (see :func:`~bayes_brdf.io.images.read_raw`). Photos are never
upsampled: a ``resolution`` above their native size is an InputError.
"""
from __future__ import annotations

import dataclasses
import math
import re
import warnings
from pathlib import Path

import numpy as np
import torch

from .. import checks
from ..errors import InputError
from ..observations import Observations
from ..render.cameras import RectifiedCamera
from ..render.lights import PointLight
from ..render.surface import PlanarSample
from ..render.views import View
from .jsonfile import read_json_object
from .transforms import is_transforms_file, load_transforms
from .images import (IMAGE_SUFFIXES, check_gamma, parse_resolution, read_raw, resample, resample_mask, sniff_format,
                     srgb_to_linear, to_rgb)

__all__ = ["load_capture", "describe", "resample_observations", "FORMATS"]

FORMATS = ("materialgan", "svbrdf-diff-renderer", "svbrdf-diff-renderer-optim", "bundle", "transforms")
_MARKERS = (("bundle", "observations.json"), ("svbrdf-diff-renderer", "parameters.json"),
            ("svbrdf-diff-renderer-optim", "optim.json"), ("materialgan", "camera_pos.txt"),
            ("transforms", "transforms.json"))
_IMAGE_NAME = re.compile(r"^(\d+)\.png$", re.IGNORECASE)


# ------------------------------------------------------------------ small parsers
def _finite_vec3(v, where, what) -> tuple[float, float, float]:
    return checks.vec3(v, what, where=where, fix="give finite x,y,z positions in cm")


def _power(v, where) -> tuple[float, float, float]:
    return checks.rgb(v, "light power", where=where, fix="give the flash power as R,G,B >= 0 (e.g. 1500,1500,1500)")


def _size_cm(v, where) -> float:
    return checks.positive(v[0] if isinstance(v, (list, tuple)) and len(v) == 1 else v, "sample size (cm)",
                           where=where, fix="give the side of the photographed square in cm")


def _read_text_rows(path: Path) -> list[list[float]]:
    if not path.is_file():
        raise InputError("file not found", where=path, fix="this capture format needs it next to the photos")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read text file ({e})", where=path) from None
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        try:
            rows.append([float(x) for x in re.split(r"[,\s;]+", line) if x])
        except ValueError:
            raise InputError(f"line {n} is not a list of numbers: {line!r}", where=path,
                             fix="write one comma-separated row of numbers per line") from None
    if not rows:
        raise InputError("file is empty", where=path)
    return rows


def _need(d: dict, keys, path: Path):
    for k in keys if isinstance(keys, (list, tuple)) else [keys]:
        if k in d:
            return d[k]
    names = " or ".join(f"'{k}'" for k in (keys if isinstance(keys, (list, tuple)) else [keys]))
    raise InputError(f"missing key {names}", where=path, fix=f"add {names} to the JSON file")


# ------------------------------------------------------------------ resolution
def _square_resolution(value, name: str) -> int | None:
    """``None`` or one positive int (a ``(R, R)`` pair is accepted); ``name`` is the argument named in errors."""
    if value is None:
        return None
    try:
        h, w = parse_resolution(value)
    except InputError:
        raise InputError(f"{name} must be a positive integer, got {value!r}",
                         fix=f"give {name} as the number of pixels per side, e.g. 128") from None
    if h != w:
        raise InputError(f"{name} {value!r} is not square but rectified photos are",
                         fix=f"give {name} as one number of pixels per side") from None
    return h


def _target_resolution(native: int, resolution, max_resolution, where, what="the photos'") -> int | None:
    """The resolution to resample to (None: keep ``native``); refuses to upsample."""
    if resolution is not None:
        if resolution > native:
            raise InputError(f"--resolution {resolution} is above {what} native {native}", where=where,
                             fix=f"use at most {native} (upsampling would only interpolate the photos: it adds no "
                                 "information), or leave it unset for the native size")
        return resolution
    if max_resolution is not None and max_resolution < native:
        return max_resolution
    return None


# ------------------------------------------------------------------ images
def _load_photos(paths: list[Path], resolution, max_resolution, gamma, where):
    """Decode photos to linear ``[V, R, R, 3]``, saturation ``[V, R, R]`` and the native size."""
    g = check_gamma(gamma)
    lut_cache: dict[float, torch.Tensor] = {}
    imgs, sats, native = [], [], None
    for p in paths:
        raw, full = read_raw(p)
        h, w = raw.shape[:2]
        if h != w:
            raise InputError(f"image is {w}x{h} pixels but rectified photos must be square", where=p,
                             fix="crop/rectify it to the square sample")
        if native is None:
            native = (h, w)
            resolution = _target_resolution(h, resolution, max_resolution, where)  # before decoding the others
        elif (h, w) != native:
            raise InputError(f"image is {w}x{h} but {paths[0].name} is {native[1]}x{native[0]}", where=p,
                             fix="all photos of a capture must have the same size")
        rgb = to_rgb(raw)
        if full is not None:  # integer photo: decode through a lookup table (exact curve)
            if full not in lut_cache:
                codes = torch.arange(int(full) + 1, dtype=torch.float64) / full
                lut_cache[full] = srgb_to_linear(codes, g).to(torch.float32)
            codes = torch.from_numpy(np.ascontiguousarray(rgb if rgb.dtype == np.uint8 else rgb.astype(np.int32)))
            lin = lut_cache[full][codes.long()]
            sat = codes.amax(dim=-1) >= int(full)
        else:  # float file (EXR): already linear, no clipping information
            if not np.isfinite(rgb).all():
                raise InputError("image has NaN or infinite pixel values", where=p, fix="re-export it with finite values")
            if (rgb < 0).any():
                raise InputError(f"image has negative pixel values (min {float(rgb.min()):.3g})", where=p,
                                 fix="radiance must be >= 0; clamp or re-export it")
            lin = torch.from_numpy(np.ascontiguousarray(rgb, dtype=np.float32))
            sat = torch.zeros(h, w, dtype=torch.bool)
        if resolution is not None:
            lin = resample(lin[None], resolution)[0]
            sat = resample_mask(sat[None], resolution)[0]
        imgs.append(lin)
        sats.append(sat)
    return torch.stack(imgs), torch.stack(sats), native


def _find_image(folder: Path, name: str, extra_dirs) -> Path:
    for d in [folder, *extra_dirs]:
        p = d / name
        if p.is_file():
            return p
    return folder / name


def _other_image_files(p: Path) -> list[Path]:
    """Image files next to ``p`` with its stem but another extension (``02.exr`` for ``02.png``)."""
    try:
        return sorted(q for q in p.parent.iterdir() if q.stem == p.stem and q.name.lower() != p.name.lower()
                      and q.suffix.lower() in IMAGE_SUFFIXES and q.is_file())
    except OSError:
        return []


def _assemble(fmt, path, image_paths, cams, lights, power, size, resolution, max_resolution, gamma,
              where_poses) -> Observations:
    for p in image_paths:
        if not p.is_file():
            others = _other_image_files(p)
            if others:
                raise InputError(f"image listed by the capture is missing (there is {others[0].name}, but the photos "
                                 f"must be PNGs named {p.name})", where=p,
                                 fix=f"convert {others[0].name} to an 8-bit sRGB PNG {p.name}, or remove its index "
                                     f"from {where_poses.name}")
            raise InputError("image listed by the capture is missing", where=p,
                             fix=f"add it, or remove its index from {where_poses.name}")
    images, sat, native = _load_photos(image_paths, resolution, max_resolution, gamma, path)
    r = images.shape[1]
    views = [View(RectifiedCamera(position=c, resolution=(r, r)), (PointLight(l, power=power),), name=p.stem)
             for c, l, p in zip(cams, lights, image_paths)]
    meta = {"format": fmt, "source": str(path), "units": "cm",
            "gamma": gamma if isinstance(gamma, str) else float(gamma),
            "native_resolution": list(native), "images": [p.name for p in image_paths]}
    return Observations(views, images.contiguous(), PlanarSample(size=size, grid="centers"),
                        mask=torch.ones(images.shape[:3], dtype=torch.bool), saturated=sat, meta=meta)


# ------------------------------------------------------------------ formats
def _kind(p: Path) -> str:
    """``"an OpenEXR image"``, ``"a JPEG image"``, ... from the content; ``"a file"`` when unknown."""
    kind = sniff_format(p)
    return f"an {kind} image" if kind == "OpenEXR" else f"a {kind} image" if kind else "a file"


def _materialgan_photos(folder: Path) -> list[Path]:
    """The ``NN.png`` photos in index order; other image files are an error (numbered) or a warning (not)."""
    files = sorted(p for p in folder.iterdir() if p.is_file())
    photos = [p for p in files if _IMAGE_NAME.match(p.name)]
    others = [p for p in files if p.suffix.lower() in IMAGE_SUFFIXES and not _IMAGE_NAME.match(p.name)]
    numbered = [p for p in others if p.stem.isdigit()]
    if numbered:
        one = len(numbered) == 1
        it = "it" if one else "them"
        what = (f"{_kind(numbered[0])} numbered like the photos but not a PNG" if one else
                ", ".join(f"{p.name} ({_kind(p)})" for p in numbered) + " are numbered like the photos but not PNGs")
        raise InputError(f"{what}: a MaterialGAN capture reads only photos named NN.png, so {it} would be left out "
                         "without a word", where=numbered[0] if one else folder,
                         fix=f"convert {it} to 8-bit sRGB PNG ({numbered[0].stem}.png{', ...' if not one else ''}) or "
                             f"move {it} out of the folder; for linear EXR photos save an observation bundle "
                             "(bayes_brdf.io.save_observations) instead")
    by_index: dict[int, list[Path]] = {}
    for p in photos:
        by_index.setdefault(int(_IMAGE_NAME.match(p.name).group(1)), []).append(p)
    dup = [ps for ps in by_index.values() if len(ps) > 1]
    if dup:
        raise InputError(f"photos {' and '.join(p.name for p in dup[0])} have the same index {int(dup[0][0].stem)}",
                         where=folder, fix="keep one photo per index (00.png, 01.png, ...)")
    if others:
        names = ", ".join(p.name for p in others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
        warnings.warn(f"{folder}: ignoring {len(others)} image file(s) not named NN.png: {names} (a MaterialGAN "
                      "capture uses only its NN.png photos)", UserWarning, stacklevel=4)
    return sorted(photos, key=lambda p: int(_IMAGE_NAME.match(p.name).group(1)))


def _load_materialgan(folder: Path, resolution, max_resolution, gamma) -> Observations:
    cam_file, light_file = folder / "camera_pos.txt", folder / "light_pos.txt"
    size_file, pow_file = folder / "image_size.txt", folder / "light_power.txt"
    cams_raw = _read_text_rows(cam_file)
    if not light_file.is_file():
        raise InputError("file not found", where=light_file,
                         fix="add one x,y,z light position per photo (for a flash at the camera, copy camera_pos.txt)")
    lights_raw = _read_text_rows(light_file)
    cams = [_finite_vec3(r, cam_file, f"camera position on line {i + 1}") for i, r in enumerate(cams_raw)]
    lights = [_finite_vec3(r, light_file, f"light position on line {i + 1}") for i, r in enumerate(lights_raw)]
    size_rows = _read_text_rows(size_file)
    size = _size_cm(size_rows[0] if len(size_rows) == 1 else size_rows, size_file)
    pow_rows = _read_text_rows(pow_file)
    power = _power(pow_rows[0] if len(pow_rows) == 1 else pow_rows, pow_file)
    images = _materialgan_photos(folder)
    if not images:
        raise InputError("no photos named NN.png (00.png, 01.png, ...) found", where=folder,
                         fix="put the rectified photos next to camera_pos.txt")
    if len(lights) != len(cams):
        raise InputError(f"{len(lights)} light positions but {len(cams)} camera positions in camera_pos.txt",
                         where=light_file, fix="give one line per photo in both files")
    if len(images) != len(cams):
        raise InputError(f"{len(cams)} camera positions but {len(images)} photos NN.png in the folder",
                         where=cam_file, fix="give exactly one x,y,z line per photo, in the photos' sorted order")
    return _assemble("materialgan", folder, images, cams, lights, power, size, resolution, max_resolution, gamma,
                     cam_file)


def _load_sdr(folder: Path, json_name: str, fmt: str, resolution, max_resolution, gamma) -> Observations:
    jf = folder / json_name
    d = read_json_object(jf)
    size = _size_cm(_need(d, ["image_size", "im_size"], jf), jf)
    cam_raw, light_raw = _need(d, "camera_pos", jf), _need(d, "light_pos", jf)
    power = _power(_need(d, "light_pow", jf), jf)
    for key, v in (("camera_pos", cam_raw), ("light_pos", light_raw)):
        if not isinstance(v, list) or not v:
            raise InputError(f"'{key}' must be a non-empty list of [x, y, z]", where=jf)
    cams = [_finite_vec3(v, jf, f"camera_pos[{i}]") for i, v in enumerate(cam_raw)]
    lights = [_finite_vec3(v, jf, f"light_pos[{i}]") for i, v in enumerate(light_raw)]
    if len(cams) != len(lights):
        raise InputError(f"{len(cams)} camera_pos entries but {len(lights)} light_pos entries", where=jf,
                         fix="give one camera and one light position per photo")
    idx = d.get("idx", list(range(len(cams))))
    if not isinstance(idx, list) or not idx or not all(isinstance(i, int) and not isinstance(i, bool) for i in idx):
        raise InputError(f"'idx' must be a non-empty list of integers, got {idx!r}", where=jf)
    bad = [i for i in idx if not 0 <= i < len(cams)]
    if bad:
        raise InputError(f"idx {bad} out of range for {len(cams)} camera positions", where=jf,
                         fix=f"use indices 0..{len(cams) - 1} (one pose per photo)")
    extra = []
    for key in ("images_dir", "target_dir"):
        sub = d.get(key)
        if isinstance(sub, str) and sub:
            extra.append(folder / sub)
            ref = folder / sub / "reference"
            if ref.is_dir():
                extra += sorted((p for p in ref.iterdir() if p.is_dir() and p.name.isdigit()),
                                key=lambda p: -int(p.name))
    images = [_find_image(folder, f"{i:02d}.png", extra) for i in idx]
    return _assemble(fmt, folder, images, [cams[i] for i in idx], [lights[i] for i in idx], power, size,
                     resolution, max_resolution, gamma, jf)


def _detect(folder: Path) -> str:
    for fmt, marker in _MARKERS:
        if (folder / marker).is_file():
            return fmt
    raise InputError("no recognised capture files (observations.json, parameters.json, optim.json, camera_pos.txt "
                     "or transforms.json)", where=folder,
                     fix="point to a MaterialGAN / svbrdf-diff-renderer / transforms.json capture folder or a saved bundle")


def load_capture(path, resolution: int | None = None, fmt: str = "auto", gamma=2.2, *,
                 max_resolution: int | None = None) -> Observations:
    """Load a capture folder as :class:`~bayes_brdf.observations.Observations`.

    ``path`` is the capture folder (or its ``parameters.json`` / ``optim.json``
    / ``camera_pos.txt`` / ``observations.json`` / ``transforms*.json``). ``fmt``
    is ``"auto"`` (detected from the files present) or one of :data:`FORMATS`.
    A ``"transforms"`` capture (perspective photos of a mesh, see
    :func:`~bayes_brdf.io.transforms.load_transforms`) may have non-square
    photos: there an int ``resolution`` / ``max_resolution`` is the LONGER
    side (aspect ratio kept) and the surface is the mesh.
    ``resolution`` (int): resample every photo to ``R x R`` (area average of
    linear values); ``None`` keeps the native size, or shrinks it to
    ``max_resolution`` when that is given and smaller (``min(native,
    max_resolution)``; ignored when ``resolution`` is given). A ``resolution``
    above the photos' native size is an :class:`~bayes_brdf.errors.InputError`:
    photos are never upsampled. ``gamma``
    decodes the 8-bit sRGB photos to linear: ``2.2`` (the plain power law the
    source tools use), ``"srgb"`` (exact piecewise curve) or any positive
    exponent.

    Returns ``images [V, R, R, 3]`` linear float32, one view per photo
    (``RectifiedCamera`` at the camera position, one ``PointLight``), the
    surface ``PlanarSample(image_size cm, grid="centers")``, ``mask`` all True,
    ``saturated`` = pixels where any channel of the photo was at its maximum
    code (255) -- after downsampling, a pixel is saturated if any photo pixel
    in its footprint was -- and ``meta`` (format, source, units "cm", gamma,
    native resolution, image names). A saved bundle (``fmt="bundle"``) is read
    by :func:`~bayes_brdf.io.bundle.load_observations` and resampled if asked.

    Example:
        >>> obs = load_capture("../shared/data/captures/card_blue", resolution=128)   # doctest: +SKIP
        >>> obs.images.shape, obs.surface.size   # doctest: +SKIP
        (torch.Size([9, 128, 128, 3]), 6.848)
    """
    p = Path(path)
    if not p.exists():
        raise InputError("capture path does not exist", where=p, fix="check the path to the capture folder")
    folder = p
    if p.is_file():
        folder = p.parent
        by_marker = {m: f for f, m in _MARKERS}
        if fmt == "auto" and p.name in by_marker:
            fmt = by_marker[p.name]
        elif fmt == "auto" and is_transforms_file(p):      # transforms_train.json, ...
            fmt = "transforms"
    if fmt == "auto":
        fmt = _detect(folder)
    if fmt not in FORMATS:
        raise InputError(f"unknown capture format '{fmt}'", fix=f"use auto or one of: {', '.join(FORMATS)}")
    check_gamma(gamma)
    if fmt == "transforms":     # non-square photos: resolution is the longer side
        return load_transforms(p, resolution, gamma, max_resolution=max_resolution)
    resolution = _square_resolution(resolution, "resolution")
    max_resolution = _square_resolution(max_resolution, "max_resolution")
    if fmt == "materialgan":
        return _load_materialgan(folder, resolution, max_resolution, gamma)
    if fmt == "svbrdf-diff-renderer":
        return _load_sdr(folder, "parameters.json", fmt, resolution, max_resolution, gamma)
    if fmt == "svbrdf-diff-renderer-optim":
        return _load_sdr(folder, "optim.json", fmt, resolution, max_resolution, gamma)
    from .bundle import load_observations

    obs = load_observations(folder)
    h, w = obs.resolution
    if resolution is not None:
        return resample_observations(obs, _target_resolution(min(h, w), resolution, None, folder, "the bundle's"))
    if max_resolution is not None and max(h, w) > max_resolution:  # shrink, keeping the aspect ratio
        f = max_resolution / max(h, w)
        return resample_observations(obs, (max(1, round(h * f)), max(1, round(w * f))))
    return obs


def resample_observations(obs: Observations, resolution) -> Observations:
    """``obs`` with images resampled to ``resolution`` (see :func:`~bayes_brdf.io.images.resample`).

    Views get the new camera resolution; ``mask`` and ``saturated`` are
    resampled conservatively: a pixel is ``saturated`` if ANY source pixel it
    covers was, and stays in ``mask`` (usable) only if ALL of them were. A render's ``variance``
    is averaged like the images and divided by the number of source pixels a new pixel averages
    (``H W / (h w)``): the variance of a mean of independent pixels.

    Example:
        >>> small = resample_observations(obs, 64)     # doctest: +SKIP
        >>> small.resolution   # doctest: +SKIP
        (64, 64)
    """
    h, w = parse_resolution(resolution)
    if tuple(obs.resolution) == (h, w):
        return obs
    views = [dataclasses.replace(v, camera=dataclasses.replace(v.camera, resolution=(h, w))) for v in obs.views]
    mask = None if obs.mask is None else ~resample_mask(~obs.mask.bool(), (h, w))
    sat = None if obs.saturated is None else resample_mask(obs.saturated, (h, w))
    var = None
    if obs.variance is not None:
        H, W = obs.resolution
        var = (resample(obs.variance, (h, w)) * (h * w / (H * W))).clamp_min(0).contiguous()
    return Observations(views, resample(obs.images, (h, w)).contiguous(), obs.surface, mask=mask, saturated=sat,
                        meta=dict(obs.meta), variance=var)


# ------------------------------------------------------------------ describe
def _fmt3(v) -> str:
    return "(" + ", ".join(f"{x:.3g}" if abs(x) < 1e4 else f"{x:.4g}" for x in v) + ")"


def describe(obs: Observations) -> str:
    """A multi-line human summary of ``obs`` (what ``bayes-brdf inspect`` prints).

    Lists the format and source, number of views, resolution (and native
    resolution), sample size in cm (for a mesh: its name, faces, centre,
    bounding radius and file), gamma, and per view: camera and light
    positions with their distance to the sample (or mesh) centre, light power, the environment light
    (map name, size, scale) if any, min /
    mean / max of the linear pixel values, and the fraction of saturated pixels.

    Example:
        >>> print(describe(load_capture("captures/card_blue", resolution=64)))   # doctest: +SKIP
        capture: materialgan  (captures/card_blue)
        views: 9   resolution: 64x64 (native 1024x1024)   sample: 6.848 x 6.848 cm (grid centers)
        ...
    """
    m = obs.meta or {}
    units = m.get("units", "")
    h, w = obs.resolution
    lines = [f"capture: {m.get('format', 'unknown')}  ({m.get('source', 'in memory')})"]
    nat = m.get("native_resolution")
    res = f"{h}x{w}" + (f" (native {nat[0]}x{nat[1]})" if nat and tuple(nat) != (h, w) else "")
    surf = obs.surface
    centre = (0.0, 0.0, 0.0)
    if hasattr(surf, "size") and hasattr(surf, "grid"):
        what = f"sample: {surf.size:g} x {surf.size:g} {units} (grid {surf.grid})"
    elif hasattr(surf, "num_faces") and hasattr(surf, "center"):
        centre = surf.center
        what = (f"mesh: '{surf.name}' {surf.num_faces} faces, centre {_fmt3(centre)}, radius {surf.radius:.3g}{units}"
                + (f" ({m['mesh']})" if m.get("mesh") else ""))
    else:
        what = f"surface: {type(surf).__name__}"
    lines.append(f"views: {len(obs)}   resolution: {res}   {what}   gamma: {m.get('gamma', '?')}")
    im = obs.images.detach().float()
    sat = obs.saturated
    for i, v in enumerate(obs.views):
        c = v.camera.position
        x = im[i]
        line = (f"  [{i}] {v.name or '-':>4}  camera {_fmt3(c)} d={math.dist(c, centre):.3g}{units}")
        if hasattr(v.camera, "fov"):
            line += f" fov {v.camera.fov:.3g}"
        for li in v.point_lights:
            line += f"  light {_fmt3(li.position)} d={math.dist(li.position, centre):.3g}{units} power {_fmt3(li.power)}"
        env = v.environment
        if env is not None:
            eh, ew = env.radiance.shape[:2]
            line += f"  environment {env.name or env.digest} {ew}x{eh} scale {env.scale:g}"
        line += f"  linear min/mean/max {x.min():.4g}/{x.mean():.4g}/{x.max():.4g}"
        if sat is not None:
            line += f"  saturated {100 * float(sat[i].float().mean()):.2f}%"
        if obs.mask is not None and not bool(obs.mask[i].all()):
            line += f"  masked-out {100 * float((~obs.mask[i]).float().mean()):.2f}%"
        lines.append(line)
    return "\n".join(lines)
