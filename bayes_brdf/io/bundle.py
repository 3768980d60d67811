"""Our own observation bundle: a folder that stores an :class:`Observations` losslessly.

Layout::

    observations.json     format_version, units, surface ({type: plane, size, grid} or
                          {type: mesh, ...}), resolution, views (View.to_dict()),
                          image / mask file names, meta, and environments ({digest: map file}) when
                          views hold an environment light
    surface.safetensors   a mesh's arrays (vertices, faces, uv, normals), for mesh scenes
    environment_<hash>.exr  the map of each environment light (linear float32, exact), when views have one
    view_000.exr ...      one image per view: linear float32 EXR (exact), or
                          16-bit PNG holding linear_to_srgb(image / scale, "srgb")
    mask_000.png ...      8-bit 0/255 PNGs, when the observations have a mask
    saturated_000.png ... likewise for the saturation mask

PNG images are scaled by a per-view ``scale`` (recorded in the JSON) so that
linear values above 1 survive; negative values are clipped to 0.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from .. import checks
from ..errors import InputError
from ..observations import Observations
from ..render.scene import surface_from_state, surface_state
from ..render.surface import PlanarSample
from ..render.views import View
from .jsonfile import read_json_object
from .images import linear_to_srgb, read_raw, srgb_to_linear, to_rgb, write_exr, write_png

__all__ = ["save_observations", "load_observations", "load_environments", "FORMAT_VERSION", "BUNDLE_FILE"]

#: 2: surfaces may be meshes; 3: views may hold an environment light (its map in an EXR next to the JSON). A
#: bundle is written with the lowest version that holds it (a plane without environments as 1), so older
#: readers take what they can read and refuse the rest in one line
FORMAT_VERSION = 3
BUNDLE_FILE = "observations.json"
SURFACE_FILE = "surface.safetensors"
_PNG_CURVE = "srgb"  # exact piecewise sRGB curve for PNG-stored images


def _jsonable(x):
    """Meta values made JSON-safe (paths and tuples become strings and lists)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, torch.Tensor):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return _jsonable(x.item())
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    return str(x)


def save_observations(obs: Observations, directory, image_format: str = "exr") -> Path:
    """Save ``obs`` as a bundle folder; returns the path of ``observations.json``.

    ``image_format="exr"`` (default) stores each view's linear ``[H, W, 3]``
    image as float32 EXR (bit-exact); ``"png"`` stores 16-bit PNGs encoded with
    the exact sRGB curve after dividing by a per-view scale (``max(1, max
    value)``), so :func:`load_observations` gets the values back to within
    16-bit quantisation (about 2e-5 relative). ``mask`` / ``saturated`` go to
    8-bit PNGs. Existing files of the same names are overwritten.

    Example:
        >>> save_observations(obs, "runs/card_blue_128")              # doctest: +SKIP
        PosixPath('runs/card_blue_128/observations.json')
        >>> load_observations("runs/card_blue_128").images.shape     # doctest: +SKIP
        torch.Size([9, 128, 128, 3])
    """
    if image_format not in ("exr", "png"):
        raise InputError(f"unknown bundle image format '{image_format}'", fix="use exr (exact) or png (16-bit)")
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise InputError("bundle path exists and is not a folder", where=d, fix="give a folder path")
    d.mkdir(parents=True, exist_ok=True)
    imgs = obs.images.detach().cpu().float()
    entries = []
    for i, v in enumerate(obs.views):
        e = {"view": v.to_dict()}
        x = imgs[i]
        if image_format == "exr":
            e["image"] = f"view_{i:03d}.exr"
            write_exr(d / e["image"], x)
        else:
            scale = max(1.0, float(torch.nan_to_num(x, nan=0.0).max()))
            e["image"], e["scale"] = f"view_{i:03d}.png", scale
            write_png(d / e["image"], linear_to_srgb(x / scale, _PNG_CURVE), linear=False, bits=16)
        for name in ("mask", "saturated"):
            m = getattr(obs, name)
            if m is not None:
                e[name] = f"{name}_{i:03d}.png"
                write_png(d / e[name], m[i].detach().cpu().float(), linear=False, bits=8)
        if obs.variance is not None:           # the renderer's own variance per pixel (always EXR: exact)
            e["variance"] = f"variance_{i:03d}.exr"
            write_exr(d / e["variance"], obs.variance[i].detach().cpu().float())
        entries.append(e)
    envs = _save_environments(obs.views, d)
    smeta, stensors = surface_state(obs.surface)
    if stensors:
        from safetensors.torch import save_file

        from .outputs import atomic_path
        with atomic_path(d / SURFACE_FILE) as tmp:
            save_file({k: v.contiguous().cpu() for k, v in stensors.items()}, str(tmp))
        smeta = {**smeta, "file": SURFACE_FILE}
    doc = {
        "format_version": 3 if envs else 1 if isinstance(obs.surface, PlanarSample) else 2,
        "kind": "bayes_brdf.observations",
        "units": (obs.meta or {}).get("units", ""),
        "surface": smeta,
        "resolution": list(obs.resolution),
        "image_format": image_format,
        "png_curve": _PNG_CURVE if image_format == "png" else None,
        "views": entries,
        "meta": _jsonable(obs.meta or {}),
    }
    if envs:
        doc["environments"] = envs
    from .outputs import write_text

    return write_text(d / BUNDLE_FILE, json.dumps(doc, indent=2, allow_nan=False))


def _save_environments(views, d: Path) -> dict:
    """Write each distinct environment map of ``views`` as ``environment_<hash>.exr`` in ``d`` (once, however
    many views, scales and rotations use it); returns ``{environment digest: file name}``."""
    import hashlib

    out, written = {}, {}
    for v in views:
        e = v.environment
        if e is None or e.digest in out:
            continue
        r = e.radiance.detach().cpu().contiguous()
        key = hashlib.sha256(r.numpy().tobytes() + repr(tuple(r.shape)).encode()).hexdigest()[:16]
        if key not in written:
            written[key] = write_exr(d / f"environment_{key}.exr", r).name
        out[e.digest] = written[key]
    return out


def load_environments(doc: dict, jf) -> dict:
    """``{digest: radiance [H, W, 3]}`` of the environment maps a bundle's ``observations.json`` (the dict
    ``doc``, read from ``jf``) lists, for :meth:`~bayes_brdf.render.views.View.from_dict`; ``{}`` when none."""
    envs = doc.get("environments") or {}
    jf = Path(jf)
    if not isinstance(envs, dict) or not all(isinstance(v, str) and v for v in envs.values()):
        raise InputError("'environments' must map each environment's digest to its map file", where=jf,
                         fix="re-save the bundle with save_observations")
    out, cache = {}, {}
    for dg, name in envs.items():
        p = jf.parent / name
        if name not in cache:
            if not p.is_file():
                raise InputError("environment map listed in observations.json is missing", where=p,
                                 fix="restore it or re-save the bundle")
            from ..render.environment import EnvironmentLight
            cache[name] = EnvironmentLight.from_file(p).radiance      # refuses a map that is not HDR, NaN, < 0
        out[str(dg)] = cache[name]
    return out


def _load_mask(path: Path, shape) -> torch.Tensor:
    a, full = read_raw(path)
    if a.shape[:2] != tuple(shape):
        raise InputError(f"mask is {a.shape[1]}x{a.shape[0]} but the images are {shape[1]}x{shape[0]}", where=path)
    thr = (full or 1.0) / 2
    return torch.from_numpy(np.ascontiguousarray(a[..., 0] > thr))


def _load_surface(meta, jf: Path):
    if not isinstance(meta, dict):
        raise InputError("'surface' must be an object ({\"size\": cm, \"grid\": centers|endpoints} for a plane)",
                         where=jf)
    tensors = {}
    if meta.get("file"):
        sf = jf.parent / str(meta["file"])
        if not sf.is_file():
            raise InputError("the surface file listed in observations.json is missing", where=sf,
                             fix="restore it or re-save the bundle")
        from safetensors import safe_open
        try:
            with safe_open(str(sf), framework="pt") as f:
                tensors = {k: f.get_tensor(k) for k in f.keys()}
        except Exception as e:  # noqa: BLE001
            raise InputError(f"unreadable surface file ({type(e).__name__})", where=sf) from None
    if meta.get("type", "plane") == "plane" and not isinstance(meta.get("size"), (int, float)):
        raise InputError("'surface' must be {\"size\": cm, \"grid\": centers|endpoints}", where=jf)
    return surface_from_state(meta, tensors, where=str(jf))


def load_observations(directory) -> Observations:
    """Load a bundle written by :func:`save_observations` (``directory`` or its ``observations.json``).

    Returns an equal :class:`Observations`: images ``[V, H, W, 3]`` float32
    (exact from EXR, within 16-bit quantisation from PNG), the same views,
    surface, masks and meta.

    Example:
        >>> obs = load_observations("runs/card_blue_128")   # doctest: +SKIP
        >>> obs.meta["format"]   # doctest: +SKIP
        'materialgan'
    """
    d = Path(directory)
    if not d.exists():
        raise InputError("bundle path does not exist", where=d, fix="check the path")
    jf = d if d.is_file() else d / BUNDLE_FILE
    d = jf.parent
    if not jf.is_file():
        raise InputError(f"no {BUNDLE_FILE} in this folder", where=d, fix="point to a folder written by save_observations")
    doc = read_json_object(jf, fix="fix the JSON syntax or re-save the bundle")
    for k in ("format_version", "surface", "views"):
        if k not in doc:
            raise InputError(f"missing key '{k}'", where=jf, fix="re-save the bundle with save_observations")
    ver = doc["format_version"]
    if not isinstance(ver, int) or ver > FORMAT_VERSION or ver < 1:
        raise InputError(f"unsupported bundle format_version {ver!r} (this version reads 1..{FORMAT_VERSION})",
                         where=jf, fix="upgrade bayes_brdf or re-save the bundle")
    surface = _load_surface(doc["surface"], jf)
    envs = load_environments(doc, jf)
    entries = doc["views"]
    if not isinstance(entries, list) or not entries:
        raise InputError("'views' must be a non-empty list", where=jf)
    views, images, masks, sats, variances = [], [], [], [], []
    for i, e in enumerate(entries):
        if not isinstance(e, dict) or "view" not in e or "image" not in e:
            raise InputError(f"views[{i}] needs 'view' and 'image'", where=jf, fix="re-save the bundle")
        views.append(View.from_dict(e["view"], where=f"{jf} views[{i}]", environments=envs))
        ip = d / str(e["image"])
        if not ip.is_file():
            raise InputError("image listed in observations.json is missing", where=ip, fix="restore it or re-save the bundle")
        raw, full = read_raw(ip)
        rgb = to_rgb(raw)
        if full is None:
            x = torch.from_numpy(np.ascontiguousarray(rgb, dtype=np.float32))
        else:
            scale = checks.positive(e.get("scale", 1.0), f"views[{i}].scale", where=jf)
            enc = torch.from_numpy(rgb.astype(np.float64)) / full
            x = (srgb_to_linear(enc, doc.get("png_curve") or _PNG_CURVE) * scale).to(torch.float32)
        if not bool(torch.isfinite(x).all()):
            raise InputError("image has NaN or infinite pixel values", where=ip, fix="re-save the bundle with finite images")
        if bool((x < 0).any()):
            raise InputError(f"image has negative pixel values (min {float(x.min()):.3g})", where=ip,
                             fix="radiance must be >= 0; clamp the images and re-save")
        if tuple(x.shape[:2]) != tuple(views[-1].resolution):
            raise InputError(f"image is {x.shape[1]}x{x.shape[0]} but its view says {views[-1].resolution}", where=ip)
        if images and x.shape != images[0].shape:
            raise InputError(f"image is {x.shape[1]}x{x.shape[0]} but {entries[0]['image']} is "
                             f"{images[0].shape[1]}x{images[0].shape[0]}", where=ip, fix="all views must share one size")
        images.append(x)
        if e.get("variance"):
            vp = d / str(e["variance"])
            if not vp.is_file():
                raise InputError("variance image listed in observations.json is missing", where=vp)
            vx = torch.from_numpy(np.ascontiguousarray(to_rgb(read_raw(vp)[0]), dtype=np.float32))
            if tuple(vx.shape) != tuple(x.shape):
                raise InputError(f"variance image is {vx.shape[1]}x{vx.shape[0]}, its photo {x.shape[1]}x{x.shape[0]}",
                                 where=vp)
            variances.append(vx)
        for name, acc in (("mask", masks), ("saturated", sats)):
            if e.get(name):
                mp = d / str(e[name])
                if not mp.is_file():
                    raise InputError(f"{name} image listed in observations.json is missing", where=mp)
                acc.append(_load_mask(mp, x.shape[:2]))
    for name, acc in (("mask", masks), ("saturated", sats)):
        if acc and len(acc) != len(entries):
            raise InputError(f"only {len(acc)} of {len(entries)} views list a {name} image", where=jf,
                             fix="give every view a mask image or none")
    if variances and len(variances) != len(entries):
        raise InputError(f"only {len(variances)} of {len(entries)} views list a variance image", where=jf,
                         fix="give every view a variance image or none")
    meta = doc.get("meta", {}) if isinstance(doc.get("meta", {}), dict) else {}
    try:
        return Observations(views, torch.stack(images), surface, mask=torch.stack(masks) if masks else None,
                            saturated=torch.stack(sats) if sats else None, meta=meta,
                            variance=torch.stack(variances) if variances else None)
    except InputError as err:
        raise InputError(str(err), where=jf) from None
