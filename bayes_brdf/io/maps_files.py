"""SVBRDF map files: our own folder of EXR maps (+ PNG previews), and peers' PNG layouts.

* :func:`save_svbrdf` / :func:`load_svbrdf` -- ``albedo.exr``, ``roughness.exr``,
  ``specular.exr``, ``normal.exr`` (exact linear float32) plus 8-bit previews
  ``albedo.png`` / ``specular.png`` (sRGB gamma 2.2), ``roughness.png``
  (linear) and ``normal.png`` (``n * 0.5 + 0.5``). Loading prefers the EXR and
  falls back to the PNG (also under svbrdf-diff-renderer's names ``dif.png``,
  ``rgh.png``, ``spe.png``, ``nom.png``).
* :func:`load_peer_svbrdf_panel` -- the DeepInverseRendering 4-panel PNG
  (normal | diffuse | roughness | specular, each square).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..render.maps import SVBRDF
from .images import read_raw, srgb_to_linear, write_exr, write_png

__all__ = ["save_svbrdf", "load_svbrdf", "load_peer_svbrdf_panel", "MAP_NAMES"]

MAP_NAMES = ("albedo", "roughness", "specular", "normal")
_ALIASES = {"albedo": ("albedo", "diffuse", "dif"), "roughness": ("roughness", "rgh"),
            "specular": ("specular", "spe"), "normal": ("normal", "nom")}
_PREVIEW_GAMMA = 2.2


def _single(maps: SVBRDF) -> SVBRDF:
    n = maps.num_particles
    if n is None:
        return maps
    if n == 1:
        return maps.particle(0)
    raise InputError(f"the SVBRDF has {n} particles; a map folder holds one set of maps",
                     fix="save one particle (maps.particle(i)) or a summary such as the posterior mean")


def save_svbrdf(maps: SVBRDF, directory) -> Path:
    """Write ``maps`` (``[C, H, W]`` each, or one particle) to ``directory``; returns the folder.

    Files: ``albedo.exr`` / ``specular.exr`` / ``normal.exr`` (RGB) and
    ``roughness.exr`` (one channel ``Y``), all linear float32 and exact, plus
    8-bit PNG previews: albedo / specular encoded with gamma 2.2, roughness
    linear, normal as ``n * 0.5 + 0.5``. Maps may differ in resolution.

    Example:
        >>> save_svbrdf(SVBRDF.constant(albedo=0.5), "out/maps")   # doctest: +SKIP
        PosixPath('out/maps')
    """
    maps = _single(maps)
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise InputError("map folder path exists and is not a folder", where=d, fix="give a folder path")
    d.mkdir(parents=True, exist_ok=True)
    for name in MAP_NAMES:
        x = maps.channels_last(name).detach().cpu().float()  # [H, W, C]
        write_exr(d / f"{name}.exr", x)
        if name in ("albedo", "specular"):
            write_png(d / f"{name}.png", x, linear=True, gamma=_PREVIEW_GAMMA)
        elif name == "normal":
            write_png(d / f"{name}.png", x * 0.5 + 0.5, linear=False)
        else:
            write_png(d / f"{name}.png", x, linear=False)
    return d


def _normalise(n: torch.Tensor, where) -> torch.Tensor:
    norm = n.norm(dim=0, keepdim=True)
    if bool((norm < 1e-8).any()):
        raise InputError("normal map has zero-length normals", where=where,
                         fix="store unit normals (PNG: n * 0.5 + 0.5, so a flat normal is (128, 128, 255))")
    return n / norm


def _decode_map(name: str, raw: np.ndarray, full, path: Path) -> torch.Tensor:
    """``[H, W, C]`` file pixels -> ``[C, H, W]`` float32 linear map."""
    if full is None:
        x = torch.from_numpy(np.ascontiguousarray(raw, dtype=np.float32))
        if not bool(torch.isfinite(x).all()):
            raise InputError(f"{name} map has NaN or infinite values", where=path, fix="re-export it with finite values")
    else:
        x = torch.from_numpy(raw.astype(np.float64) / full)
    c = x.shape[-1]
    if name == "roughness":
        x = x[..., :1] if c in (1, 2) else x[..., :3].mean(-1, keepdim=True)
    else:
        x = x[..., :1].expand(*x.shape[:2], 3) if c in (1, 2) else x[..., :3]
    if full is not None:
        if name in ("albedo", "specular"):
            x = srgb_to_linear(x, _PREVIEW_GAMMA)
        elif name == "normal":
            x = x * 2 - 1
    x = x.movedim(-1, 0).contiguous()
    if name == "normal":  # PNG normals are always renormalised; EXR ones only if not already unit
        norm = x.norm(dim=0)
        if full is not None or bool((norm < 1e-8).any()) or float((norm - 1).abs().max()) > 1e-4:
            x = _normalise(x, path)
    return x.to(torch.float32)


def load_svbrdf(directory) -> SVBRDF:
    """Read a map folder written by :func:`save_svbrdf` as an :class:`SVBRDF` of ``[C, H, W]`` float32 maps.

    For each map the EXR is used when present, else the PNG (``albedo.png`` /
    ``specular.png`` decoded with gamma 2.2, ``roughness.png`` linear,
    ``normal.png`` as ``2 v - 1`` renormalised); svbrdf-diff-renderer names
    (``dif.png``, ``rgh.png``, ``spe.png``, ``nom.png``) are accepted too.

    Example:
        >>> m = load_svbrdf("out/maps")     # doctest: +SKIP
        >>> m.roughness.shape   # doctest: +SKIP
        torch.Size([1, 256, 256])
    """
    d = Path(directory)
    if not d.is_dir():
        raise InputError("map folder does not exist" if not d.exists() else "expected a folder of maps", where=d,
                         fix="point to a folder written by save_svbrdf")
    out = {}
    for name in MAP_NAMES:
        cands = [d / f"{a}.{ext}" for ext in ("exr", "png") for a in _ALIASES[name]]
        path = next((p for p in cands if p.is_file()), None)
        if path is None:
            raise InputError(f"{name} map not found", where=d / f"{name}.exr",
                             fix=f"add {name}.exr (or {name}.png) to the folder")
        raw, full = read_raw(path)
        out[name] = _decode_map(name, raw, full, path)
    return SVBRDF(**out)


#: the maps of a metallic-roughness material folder (:func:`load_metallic_maps`)
METALLIC_MAP_NAMES = ("base_color", "metallic", "roughness")


def is_metallic_folder(directory) -> bool:
    """Whether ``directory`` holds a metallic-roughness material (``base_color`` and ``metallic`` maps)."""
    d = Path(directory)
    return d.is_dir() and all(any((d / f"{n}.{e}").is_file() for e in ("exr", "png")) for n in ("base_color", "metallic"))


def load_metallic_maps(directory) -> dict:
    """Read a metallic-roughness material folder (glTF / Substance / Blender maps): ``base_color.{exr,png}``
    (PNG decoded with gamma 2.2), ``metallic`` and ``roughness`` (linear; channels averaged), as
    ``{"base_color": [3, H, W], "metallic": [1, H, W], "roughness": [1, H, W]}`` float32 in our map convention
    (row 0 of the file at ``v = 1``, as every map here); values outside [0, 1] are one line.

    Example:
        >>> t = load_metallic_maps("../shared/data/peer_wiersma/experiments/scenes/plane/textures")  # doctest: +SKIP
        >>> t["metallic"].shape   # doctest: +SKIP
        torch.Size([1, 64, 64])
    """
    d = Path(directory)
    out = {}
    for name in METALLIC_MAP_NAMES:
        path = next((d / f"{name}.{e}" for e in ("exr", "png") if (d / f"{name}.{e}").is_file()), None)
        if path is None:
            raise InputError(f"{name} map not found", where=d / f"{name}.exr",
                             fix=f"add {name}.exr (or .png) to the metallic-roughness folder")
        raw, full = read_raw(path)
        x = torch.from_numpy(np.ascontiguousarray(raw, dtype=np.float64) / (full or 1.0))
        if x.dim() == 2:
            x = x[..., None]
        if name == "base_color":
            x = x[..., :1].expand(*x.shape[:2], 3) if x.shape[-1] < 3 else x[..., :3]
            if full is not None:
                x = srgb_to_linear(x, _PREVIEW_GAMMA)
        else:
            x = x[..., :3].mean(-1, keepdim=True)
        if not bool(torch.isfinite(x).all()) or float(x.min()) < 0 or float(x.max()) > 1:
            raise InputError(f"{name} map has values outside [0, 1] (or not finite)", where=path,
                             fix="a metallic-roughness map holds values in [0, 1]")
        out[name] = x.movedim(-1, 0).contiguous().to(torch.float32)
    return out


def load_peer_svbrdf_panel(png_path) -> SVBRDF:
    """Read a DeepInverseRendering 4-panel map image as an :class:`SVBRDF` (``[C, H, W]`` float32).

    The image is four ``H x H`` panels side by side: normal (``2 v - 1``,
    renormalised), diffuse (sRGB gamma 2.2 -> linear albedo), roughness
    (linear, channels averaged), specular (linear).

    Example:
        >>> m = load_peer_svbrdf_panel("example_svbrdf/0000066;...X4.png")   # doctest: +SKIP
        >>> m.albedo.shape, m.roughness.shape   # doctest: +SKIP
        (torch.Size([3, 256, 256]), torch.Size([1, 256, 256]))
    """
    path = Path(png_path)
    raw, full = read_raw(path)
    h, w = raw.shape[:2]
    if w != 4 * h:
        raise InputError(f"panel image is {w}x{h}, expected four square panels side by side (width = 4 x height)",
                         where=path, fix="give the normal|diffuse|roughness|specular panel PNG")
    x = torch.from_numpy(raw.astype(np.float64))
    x = x / full if full is not None else x
    if x.shape[-1] in (1, 2):
        x = x[..., :1].expand(h, w, 3)
    x = x[..., :3].movedim(-1, 0)  # [3, H, 4H]
    nrm, dif, rgh, spe = (x[:, :, k * h:(k + 1) * h] for k in range(4))
    normal = _normalise(nrm * 2 - 1, path)
    return SVBRDF(albedo=srgb_to_linear(dif, _PREVIEW_GAMMA).float().contiguous(),
                  roughness=rgh.mean(0, keepdim=True).float().contiguous(),
                  specular=spe.float().contiguous(), normal=normal.float().contiguous())
