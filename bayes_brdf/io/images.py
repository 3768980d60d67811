"""Image files and colour curves.

* :func:`read_image` -- PNG (8 or 16 bit), EXR (linear float) or anything
  Pillow reads, as ``float32 [H, W, 3]``.
* :func:`write_png` / :func:`write_exr` -- the other way.
* :func:`srgb_to_linear` / :func:`linear_to_srgb` -- display curves. ``gamma=2.2``
  is the plain power law ``x ** 2.2`` that MaterialGAN and svbrdf-diff-renderer
  use; ``gamma="srgb"`` is the exact piecewise IEC 61966-2-1 curve; any other
  positive number is a power law with that exponent (``1.0``: already linear).
* :func:`resample` / :func:`resample_mask` -- change the resolution of image
  stacks ``[V, H, W, C]`` (area average when shrinking, bilinear when growing)
  and of boolean masks (a pixel is set if any source pixel it covers is set).

numpy appears only at the file boundary; everything else works on torch tensors.

Pillow reads 16-bit RGB(A) PNGs as 8-bit, so those are decoded here by a small
PNG reader (non-interlaced files only); 16-bit PNGs are written by a small
encoder for the same reason.
"""
from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError

__all__ = ["read_image", "write_png", "write_exr", "srgb_to_linear", "linear_to_srgb",
           "resample", "resample_mask"]

_PNG_SIG = b"\x89PNG\r\n\x1a\n"


# ------------------------------------------------------------------ colour curves
def _check_gamma(gamma) -> str | float:
    if isinstance(gamma, str):
        if gamma.lower() != "srgb":
            raise InputError(f"unknown gamma '{gamma}'", fix="use a positive number (2.2: plain power law) or 'srgb'")
        return "srgb"
    try:
        g = float(gamma)
    except (TypeError, ValueError):
        raise InputError(f"gamma must be a positive number or 'srgb', got {gamma!r}") from None
    if not (math.isfinite(g) and g > 0):
        raise InputError(f"gamma must be a positive number or 'srgb', got {gamma!r}")
    return g


def _as_float_tensor(x) -> tuple[Tensor, bool]:
    if isinstance(x, Tensor):
        return (x if x.is_floating_point() else x.to(torch.get_default_dtype())), False
    t = torch.as_tensor(np.asarray(x))
    return (t if t.is_floating_point() else t.to(torch.float64)), True


def srgb_to_linear(x, gamma=2.2):
    """Decode display values (sRGB-like, ``[0, 1]``) to linear radiance.

    ``gamma=2.2`` (default) is the plain power law ``x ** 2.2`` of MaterialGAN /
    svbrdf-diff-renderer; ``gamma="srgb"`` is the exact piecewise IEC 61966-2-1
    curve (``x / 12.92`` below 0.04045, else ``((x + 0.055) / 1.055) ** 2.4``).
    Negative inputs are treated as 0. Accepts any shape; returns a torch tensor
    (or a numpy array when given one), same dtype for float inputs.

    Example:
        >>> float(srgb_to_linear(torch.tensor(0.5)))            # 0.5 ** 2.2
        0.21763764321804047
        >>> round(float(srgb_to_linear(torch.tensor(0.5), "srgb")), 6)
        0.214041
    """
    g = _check_gamma(gamma)
    t, was_np = _as_float_tensor(x)
    t = t.clamp_min(0)
    if g == "srgb":
        out = torch.where(t <= 0.04045, t / 12.92, ((t + 0.055) / 1.055) ** 2.4)
    else:
        out = t ** g
    return out.numpy() if was_np else out


def linear_to_srgb(x, gamma=2.2):
    """Encode linear radiance for display; the inverse of :func:`srgb_to_linear`.

    ``gamma=2.2``: ``x ** (1 / 2.2)``; ``gamma="srgb"``: the exact piecewise
    curve. Negative inputs are treated as 0; values above 1 are NOT clipped
    (:func:`write_png` clips).

    Example:
        >>> x = torch.tensor([0.0, 0.01, 0.5, 1.0])
        >>> torch.allclose(srgb_to_linear(linear_to_srgb(x, "srgb"), "srgb"), x, atol=1e-6)
        True
    """
    g = _check_gamma(gamma)
    t, was_np = _as_float_tensor(x)
    t = t.clamp_min(0)
    if g == "srgb":
        out = torch.where(t <= 0.0031308, t * 12.92, 1.055 * t ** (1 / 2.4) - 0.055)
    else:
        out = t ** (1.0 / g)
    return out.numpy() if was_np else out


# ------------------------------------------------------------------ PNG (own codec)
def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    return b if pb <= pc else c


def _unfilter(raw: bytes, h: int, stride: int, bpp: int, where) -> np.ndarray:
    """Undo the PNG per-row filters; returns ``uint8 [h, stride]``."""
    need = h * (stride + 1)
    if len(raw) < need:
        raise InputError("PNG data is truncated", where=where, fix="re-export the image")
    rows = np.frombuffer(raw, dtype=np.uint8, count=need).reshape(h, stride + 1)
    out = np.zeros((h, stride), dtype=np.uint8)
    prior = np.zeros(stride, dtype=np.uint8)
    for y in range(h):
        f, line = int(rows[y, 0]), rows[y, 1:]
        if f == 0:
            cur = line.copy()
        elif f == 1:  # Sub: running sum per byte lane, mod 256
            lanes = line.reshape(-1, bpp).astype(np.uint64)
            cur = (np.cumsum(lanes, axis=0) % 256).astype(np.uint8).reshape(-1)
        elif f == 2:  # Up
            cur = line + prior  # uint8 arithmetic wraps mod 256
        elif f in (3, 4):  # Average / Paeth: sequential along the row
            cur_l = bytearray(stride)
            ln, pr = line.tolist(), prior.tolist()
            for i in range(stride):
                a = cur_l[i - bpp] if i >= bpp else 0
                b = pr[i]
                if f == 3:
                    pred = (a + b) >> 1
                else:
                    pred = _paeth(a, b, pr[i - bpp] if i >= bpp else 0)
                cur_l[i] = (ln[i] + pred) & 255
            cur = np.frombuffer(bytes(cur_l), dtype=np.uint8)
        else:
            raise InputError(f"PNG row {y} has unknown filter type {f}", where=where,
                             fix="the file is corrupt; re-export the image")
        out[y] = cur
        prior = cur
    return out


def _decode_png(data: bytes, where) -> np.ndarray:
    """Decode a non-interlaced 8/16-bit gray/RGB(A) PNG to ``uint8/uint16 [H, W, C]``."""
    if not data.startswith(_PNG_SIG):
        raise InputError("not a PNG file", where=where, fix="give a PNG image")
    pos, ihdr, idat = 8, None, []
    try:
        while pos < len(data):
            n, kind = struct.unpack(">I4s", data[pos:pos + 8])
            body = data[pos + 8:pos + 8 + n]
            if kind == b"IHDR":
                ihdr = struct.unpack(">IIBBBBB", body)
            elif kind == b"IDAT":
                idat.append(body)
            elif kind == b"IEND":
                break
            pos += 12 + n
        w, h, depth, ctype, _, _, interlace = ihdr
        raw = zlib.decompress(b"".join(idat))
    except (struct.error, TypeError, zlib.error):
        raise InputError("corrupt PNG (bad chunks or compressed data)", where=where,
                         fix="re-export the image") from None
    chans = {0: 1, 2: 3, 4: 2, 6: 4}.get(ctype)
    if chans is None or depth not in (8, 16) or interlace != 0:
        raise InputError(f"unsupported PNG layout (bit depth {depth}, colour type {ctype}, interlace {interlace})",
                         where=where, fix="save it as a non-interlaced 8- or 16-bit gray/RGB PNG")
    bps = depth // 8
    bpp = chans * bps
    flat = _unfilter(raw, h, w * bpp, bpp, where)
    if bps == 1:
        return flat.reshape(h, w, chans)
    return flat.view(">u2").reshape(h, w, chans).astype(np.uint16)


def _filter_rows(img: np.ndarray, bpp: int, ftype: int) -> np.ndarray:
    """Apply one PNG filter type to all rows of ``uint8 [h, stride]`` (vectorised)."""
    x = img.astype(np.int32)
    h, stride = x.shape
    a = np.zeros_like(x)
    a[:, bpp:] = x[:, :-bpp]
    b = np.zeros_like(x)
    b[1:] = x[:-1]
    c = np.zeros_like(x)
    c[1:, bpp:] = x[:-1, :-bpp]
    if ftype == 0:
        pred = np.zeros_like(x)
    elif ftype == 1:
        pred = a
    elif ftype == 2:
        pred = b
    elif ftype == 3:
        pred = (a + b) >> 1
    elif ftype == 4:
        p = a + b - c
        pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - c)
        pred = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
    else:
        raise ValueError(f"PNG filter type must be 0..4, got {ftype}")
    return ((x - pred) & 255).astype(np.uint8)


def _encode_png(arr: np.ndarray, filter_type: int = 2) -> bytes:
    """Encode ``uint8/uint16 [H, W, C]`` (C in 1..4) as a PNG (one filter type for all rows)."""
    h, w, c = arr.shape
    depth = 16 if arr.dtype == np.uint16 else 8
    ctype = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    rows = np.ascontiguousarray(arr.astype(">u2") if depth == 16 else arr).view(np.uint8).reshape(h, -1)
    filt = _filter_rows(rows, c * depth // 8, filter_type)
    body = np.concatenate([np.full((h, 1), filter_type, np.uint8), filt], axis=1).tobytes()

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (_PNG_SIG + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, ctype, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(body, 6)) + chunk(b"IEND", b""))


def _png_header(path: Path) -> tuple[int, int] | None:
    """``(bit depth, colour type)`` of a PNG file, or None when it is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(33)
    if not head.startswith(_PNG_SIG) or len(head) < 29 or head[12:16] != b"IHDR":
        return None
    return head[24], head[25]


# ------------------------------------------------------------------ reading
def _read_exr(path: Path) -> np.ndarray:
    import OpenEXR

    try:
        with OpenEXR.File(str(path)) as f:
            chans = {k: np.asarray(v.pixels) for k, v in f.channels().items()}
    except Exception as e:  # OpenEXR raises plain RuntimeError/Exception on bad files
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"cannot read EXR image ({msg})", where=path, fix="check the file is a valid OpenEXR image") from None
    for key in ("RGB", "RGBA", "XYZ"):
        if key in chans:
            return chans[key][..., :3].astype(np.float32)
    if all(k in chans for k in "RGB"):
        return np.stack([chans[k] for k in "RGB"], axis=-1).astype(np.float32)
    for key in ("Y", "R", "L", "Z"):
        if key in chans and chans[key].ndim == 2:
            return chans[key][..., None].astype(np.float32)
    if len(chans) == 1:
        a = next(iter(chans.values()))
        return (a if a.ndim == 3 else a[..., None]).astype(np.float32)
    raise InputError(f"EXR image has channels {sorted(chans)}, expected RGB or Y", where=path,
                     fix="save it with R, G, B (or a single Y) channels")


def _read_raw(path) -> tuple[np.ndarray, float | None]:
    """Native pixels ``[H, W, C]`` and the integer full-scale code (None for float files).

    Integer images come back as uint8/uint16 (C = 1..4 as stored); float files as float32.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("image file not found", where=path, fix="check the path")
    if path.is_dir():
        raise InputError("expected an image file but this is a folder", where=path)
    try:
        with open(path, "rb") as f:
            magic = f.read(4)
    except OSError as e:
        raise InputError(f"cannot open image ({e.strerror})", where=path) from None
    if magic == b"\x76\x2f\x31\x01":  # OpenEXR magic number
        return _read_exr(path), None
    hdr = _png_header(path)
    if hdr is not None and hdr[0] == 16:
        a = _decode_png(path.read_bytes(), path)
        return a, 65535.0
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode in ("P", "PA", "CMYK", "YCbCr", "LAB", "HSV", "1"):
                im = im.convert("RGBA" if ("A" in mode or "transparency" in im.info) else "RGB")
                mode = im.mode
            a = np.array(im)
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, EOFError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(f"cannot read image ({msg})", where=path, fix="check the file is a valid, complete PNG/EXR image") from None
    if a.ndim == 2:
        a = a[..., None]
    if a.dtype == np.uint8:
        return a, 255.0
    if a.dtype == np.uint16 or mode.startswith("I;16"):
        return a.astype(np.uint16), 65535.0
    if mode == "I":  # 16-bit gray as int32
        return np.clip(a, 0, 65535).astype(np.uint16), 65535.0
    return a.astype(np.float32), None


def _to_rgb(a: np.ndarray) -> np.ndarray:
    """``[H, W, C]`` -> ``[H, W, 3]``: gray promoted, alpha dropped."""
    c = a.shape[-1]
    if c in (1, 2):
        return np.repeat(a[..., :1], 3, axis=-1)
    return a[..., :3]


def read_image(path) -> np.ndarray:
    """Read an image file as ``float32 [H, W, 3]``.

    PNG / JPEG / ... (8 or 16 bit) come back as the stored display values
    scaled to ``[0, 1]`` (NOT linearised: see :func:`srgb_to_linear`); EXR comes
    back as its linear float values. Grayscale is promoted to 3 channels and
    alpha is dropped. Every problem raises :class:`~bayes_brdf.errors.InputError`
    naming the file.

    Example:
        >>> img = read_image("capture/00.png")          # doctest: +SKIP
        >>> img.shape, img.dtype   # doctest: +SKIP
        ((1024, 1024, 3), dtype('float32'))
    """
    a, full = _read_raw(path)
    a = _to_rgb(a)
    if full is not None:
        return (a.astype(np.float32) / np.float32(full)).astype(np.float32)
    return np.ascontiguousarray(a, dtype=np.float32)


# ------------------------------------------------------------------ writing
def _to_numpy_hwc(img, where) -> np.ndarray:
    if isinstance(img, Tensor):
        img = img.detach().cpu().numpy()
    a = np.asarray(img)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[-1] not in (1, 2, 3, 4):
        raise InputError(f"image to write has shape {a.shape}, expected [H, W], [H, W, 1] or [H, W, 3]", where=where)
    return a


def write_png(path, img, *, linear: bool = True, gamma=2.2, bits: int = 8) -> Path:
    """Write ``img`` (``[H, W]``, ``[H, W, 1]`` or ``[H, W, 3]``, torch or numpy) as a PNG.

    ``linear=True`` (default): ``img`` is linear radiance and is encoded with
    :func:`linear_to_srgb` (``gamma``: 2.2 power law or ``"srgb"``) before
    quantisation; ``linear=False``: ``img`` already holds display values in
    ``[0, 1]`` (e.g. a roughness map or an encoded normal map) and is stored as
    is. Values are clipped to ``[0, 1]`` and rounded to ``bits`` (8 or 16) bits.
    Parent folders are created. Returns the path.

    Example:
        >>> write_png("/tmp/preview.png", torch.rand(64, 64, 3))   # doctest: +SKIP
        PosixPath('/tmp/preview.png')
    """
    path = Path(path)
    if bits not in (8, 16):
        raise InputError(f"PNG bit depth must be 8 or 16, got {bits}", where=path)
    a = _to_numpy_hwc(img, path)
    t = torch.as_tensor(a.astype(np.float64))
    if linear:
        t = linear_to_srgb(t, gamma)
    t = torch.nan_to_num(t, nan=0.0).clamp(0, 1)
    full = 255 if bits == 8 else 65535
    q = torch.round(t * full).numpy().astype(np.uint8 if bits == 8 else np.uint16)
    path.parent.mkdir(parents=True, exist_ok=True)
    if bits == 8:
        from PIL import Image

        Image.fromarray(q[..., 0] if q.shape[-1] == 1 else q).save(path, format="PNG")
    else:
        path.write_bytes(_encode_png(q))
    return path


def write_exr(path, img) -> Path:
    """Write ``img`` (``[H, W]``, ``[H, W, 1]`` or ``[H, W, 3]``) as a lossless float32 EXR.

    One channel is stored as ``Y``, three as ``RGB`` (ZIP compression, lossless,
    so :func:`read_image` gives back the same float32 values). Returns the path.

    Example:
        >>> write_exr("/tmp/radiance.exr", torch.rand(32, 32, 3))   # doctest: +SKIP
        PosixPath('/tmp/radiance.exr')
    """
    import OpenEXR

    path = Path(path)
    a = np.ascontiguousarray(_to_numpy_hwc(img, path), dtype=np.float32)
    if a.shape[-1] == 1:
        chans = {"Y": np.ascontiguousarray(a[..., 0])}
    elif a.shape[-1] == 3:
        chans = {"RGB": a}
    else:
        raise InputError(f"EXR image must have 1 or 3 channels, got {a.shape[-1]}", where=path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, chans) as f:
        f.write(str(path))
    return path


# ------------------------------------------------------------------ resampling
def _size2(size) -> tuple[int, int]:
    if isinstance(size, (tuple, list)):
        hw = tuple(size)
    else:
        hw = (size, size)
    try:
        ok = len(hw) == 2 and all(int(s) == s and int(s) >= 1 for s in hw)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(f"resolution must be a positive integer (or (height, width)), got {size!r}")
    return int(hw[0]), int(hw[1])


def resample(images: Tensor, size) -> Tensor:
    """Resample an image stack ``[..., H, W, C]`` (channels last) to ``size x size``.

    Shrinking averages the LINEAR values over each output pixel's footprint
    (``area`` interpolation, i.e. an exact box filter for integer factors:
    this is the anti-aliasing); growing is bilinear (half-pixel centres). Uses
    :func:`kornia.geometry.transform.resize`. ``size`` may also be ``(h, w)``.
    Returns the input unchanged when the size already matches.

    Example:
        >>> x = torch.rand(9, 1024, 1024, 3)
        >>> resample(x, 128).shape
        torch.Size([9, 128, 128, 3])
        >>> torch.allclose(resample(x, 128)[0, 0, 0], x[0, :8, :8].mean((0, 1)))
        True
    """
    from kornia.geometry.transform import resize

    h, w = _size2(size)
    if not isinstance(images, Tensor) or images.dim() < 3:
        raise InputError(f"resample needs a tensor [..., H, W, C], got {getattr(images, 'shape', type(images))}")
    if tuple(images.shape[-3:-1]) == (h, w):
        return images
    x = images.movedim(-1, -3)
    lead = x.shape[:-3]
    x = x.reshape(-1, *x.shape[-3:])
    shrink = h <= x.shape[-2] and w <= x.shape[-1]
    dt = x.dtype
    if not x.is_floating_point():
        x = x.float()
    if shrink:
        y = resize(x, (h, w), interpolation="area")
    else:
        y = resize(x, (h, w), interpolation="bilinear", align_corners=False)
    return y.to(dt).reshape(*lead, *y.shape[-3:]).movedim(-3, -1)


def resample_mask(mask: Tensor, size) -> Tensor:
    """Resample a boolean mask ``[..., H, W]`` so a pixel is set if ANY source pixel it uses is set.

    Shrinking max-pools over exactly the footprints :func:`resample` averages
    over; growing sets a pixel wherever one of its bilinear source pixels is set
    (conservative: e.g. a saturated source pixel marks every output pixel it
    contributes to).

    Example:
        >>> m = torch.zeros(1, 8, 8, dtype=torch.bool); m[0, 0, 0] = True
        >>> resample_mask(m, 2)[0].tolist()
        [[True, False], [False, False]]
    """
    h, w = _size2(size)
    if mask.dim() < 2:
        raise InputError(f"resample_mask needs a tensor [..., H, W], got shape {tuple(mask.shape)}")
    if tuple(mask.shape[-2:]) == (h, w):
        return mask.bool()
    lead = mask.shape[:-2]
    x = mask.reshape(-1, 1, *mask.shape[-2:]).float()
    if h <= x.shape[-2] and w <= x.shape[-1]:
        y = torch.nn.functional.adaptive_max_pool2d(x, (h, w)) > 0
    else:
        y = resample(x.movedim(1, -1), (h, w)).movedim(-1, 1) > 0
    return y.reshape(*lead, h, w)
