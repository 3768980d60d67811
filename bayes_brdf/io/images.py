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

Building blocks shared by the capture, bundle and map-file loaders:

* :func:`read_raw` -- a file's native pixels (``uint8`` / ``uint16`` codes or
  ``float32``) and full-scale code; :func:`to_rgb` -- gray promoted, alpha dropped.
* :func:`sniff_format` -- the format from the file's first bytes. The content,
  not the name, decides how a file is read, and a ``.png`` / ``.exr`` name
  that disagrees with the content is an :class:`~bayes_brdf.errors.InputError`.
* :func:`check_gamma` / :func:`parse_resolution` -- validate a display curve
  and an ``R`` or ``(H, W)`` resolution.

numpy appears only at the file boundary; everything else works on torch tensors.

Pillow reads 16-bit RGB(A) PNGs as 8-bit and cannot write them, so 16-bit PNGs
are read and written with OpenCV (``opencv-python-headless``, libpng; imported
only when a 16-bit PNG is met); 8-bit PNGs and other formats go through Pillow,
EXR through OpenEXR.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError

__all__ = ["read_image", "write_png", "write_exr", "srgb_to_linear", "linear_to_srgb",
           "resample", "resample_mask", "read_raw", "to_rgb", "check_gamma", "parse_resolution",
           "sniff_format", "PNG_SIGNATURE", "EXR_MAGIC", "IMAGE_SUFFIXES"]


# ------------------------------------------------------------------ colour curves
def check_gamma(gamma) -> str | float:
    """Validate a display-curve choice: returns ``"srgb"`` or the power-law exponent as a float.

    Accepts ``"srgb"`` (any case) or a positive finite number; anything else
    raises :class:`~bayes_brdf.errors.InputError`.

    Example:
        >>> check_gamma("sRGB"), check_gamma(2)
        ('srgb', 2.0)
    """
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
    g = check_gamma(gamma)
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
    g = check_gamma(gamma)
    t, was_np = _as_float_tensor(x)
    t = t.clamp_min(0)
    if g == "srgb":
        out = torch.where(t <= 0.0031308, t * 12.92, 1.055 * t ** (1 / 2.4) - 0.055)
    else:
        out = t ** (1.0 / g)
    return out.numpy() if was_np else out


# ------------------------------------------------------------------ file formats (by content)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = b"\x76\x2f\x31\x01"

# first bytes -> format name; the name -> the file name extension it should have
_MAGIC = ((PNG_SIGNATURE, "PNG"), (EXR_MAGIC, "OpenEXR"), (b"\xff\xd8\xff", "JPEG"), (b"II*\x00", "TIFF"),
          (b"MM\x00*", "TIFF"), (b"GIF87a", "GIF"), (b"GIF89a", "GIF"), (b"#?RADIANCE", "Radiance HDR"),
          (b"#?RGBE", "Radiance HDR"), (b"BM", "BMP"))
_EXTENSION = {"PNG": ".png", "OpenEXR": ".exr", "JPEG": ".jpg", "TIFF": ".tif", "GIF": ".gif",
              "Radiance HDR": ".hdr", "BMP": ".bmp", "WebP": ".webp"}
_CHECKED = {".png": "PNG", ".exr": "OpenEXR"}  # extensions whose content must match
IMAGE_SUFFIXES = (".png", ".exr", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".gif", ".webp", ".hdr")


def _format_of(head: bytes) -> str | None:
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "WebP"
    return next((name for magic, name in _MAGIC if head.startswith(magic)), None)


def _read_head(path: Path, n: int = 33) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(n)
    except OSError as e:
        raise InputError(f"cannot open image ({e.strerror})", where=path) from None


def sniff_format(path) -> str | None:
    """The image format of a file judged from its first bytes (its content, not its name).

    Returns ``"PNG"``, ``"OpenEXR"``, ``"JPEG"``, ``"TIFF"``, ``"GIF"``, ``"WebP"``,
    ``"BMP"``, ``"Radiance HDR"``, or None when the content is none of these.

    Example:
        >>> sniff_format(write_exr("/tmp/x.png", torch.zeros(2, 2)))   # doctest: +SKIP
        'OpenEXR'
    """
    return _format_of(_read_head(Path(path), 12))


def _png_header(head: bytes) -> tuple[int, int] | None:
    """``(bit depth, colour type)`` from a PNG file's first 33 bytes, or None when it is not a PNG."""
    if not head.startswith(PNG_SIGNATURE) or len(head) < 29 or head[12:16] != b"IHDR":
        return None
    return head[24], head[25]


def _check_content_matches_name(path: Path, fmt: str | None) -> None:
    """A ``.png`` must hold a PNG and a ``.exr`` an OpenEXR image; EXR data under another image extension is refused too.

    The name is what the capture/bundle/map loaders (and people) go by: ``NN.png``
    means display-encoded integer codes (with clipping), ``.exr`` exact linear
    floats. When name and content disagree we cannot know which one is meant.
    """
    ext = path.suffix.lower()
    want = _CHECKED.get(ext)
    if fmt == "OpenEXR" and ext != ".exr" and ext in IMAGE_SUFFIXES:
        raise InputError(f"the file holds an OpenEXR image (linear float) but its name ends in {path.suffix}",
                         where=path, fix=f"rename it to {path.stem}.exr if it is meant as linear EXR data, "
                                         f"or re-export it as a real {ext.lstrip('.').upper()}")
    if want is None or fmt == want:
        return
    if fmt is None:
        raise InputError(f"cannot read image (not a{'n' if want == 'OpenEXR' else ''} {want} file: it does not start "
                         f"with the {want} {'signature' if want == 'PNG' else 'magic number'})", where=path,
                         fix="check the file is a valid, complete image (re-export it)")
    real = _EXTENSION.get(fmt, "")
    raise InputError(f"the file holds a {fmt} image but its name ends in {path.suffix}", where=path,
                     fix=f"rename it to {path.stem}{real}, or convert it to "
                         f"{'a linear float OpenEXR image' if want == 'OpenEXR' else 'a lossless PNG'}")


# ------------------------------------------------------------------ 16-bit PNG (OpenCV)
# Pillow reads 16-bit RGB(A) PNGs as 8-bit and cannot write them, so 16-bit PNGs go through
# OpenCV (libpng); 8-bit ones (incl. palette / transparency) stay with Pillow.
class _Quiet:
    """What OpenCV / libpng wrote to the stderr file descriptor while silenced (their own error text)."""

    text = ""

    def reason(self) -> str:
        lines = [ln.strip() for ln in self.text.splitlines() if ln.strip()]
        return f" ({lines[-1][:200]})" if lines else ""


@contextmanager
def _quiet_opencv():
    """Yield ``cv2`` with its logger silenced and fd 2 captured.

    On a corrupt file libpng prints ``libpng error: ...`` straight to the stderr
    file descriptor (not through Python or OpenCV's logger); we raise one
    InputError instead and put libpng's words in it, so nothing else is printed.
    """
    import os
    import sys
    import tempfile

    import cv2

    quiet = _Quiet()
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    old_level = None
    if log is not None:
        try:
            old_level = log.getLogLevel()
            log.setLogLevel(log.LOG_LEVEL_SILENT)
        except Exception:  # pragma: no cover - an OpenCV without the logging API
            old_level = None
    saved, tmp = None, None
    try:
        sys.stderr.flush()
        tmp = tempfile.TemporaryFile()
        saved = os.dup(2)
        os.dup2(tmp.fileno(), 2)
    except (OSError, ValueError, AttributeError):  # no usable fd 2 (e.g. a daemon): just run
        if tmp is not None:
            tmp.close()
        saved, tmp = None, None
    try:
        yield cv2, quiet
    finally:
        if saved is not None:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            quiet.text = tmp.read().decode("utf-8", "replace")
            tmp.close()
        if old_level is not None:
            log.setLogLevel(old_level)


def _read_png16(path: Path, ctype: int) -> np.ndarray:
    """Decode a 16-bit PNG to ``uint16 [H, W, C]`` as stored (C: 1 gray, 2 gray+alpha, 3 RGB, 4 RGBA)."""
    data = np.fromfile(path, dtype=np.uint8)
    with _quiet_opencv() as (cv2, quiet):
        try:
            a = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        except cv2.error:
            a = None
    if a is None or a.dtype != np.uint16:
        raise InputError(f"cannot read image: corrupt or truncated 16-bit PNG data{quiet.reason()}", where=path,
                         fix="re-export the image")
    if a.ndim == 2:
        a = a[..., None]
    elif a.shape[-1] == 3:
        a = a[..., ::-1]  # OpenCV's BGR -> RGB
    elif a.shape[-1] == 4:
        a = a[..., [2, 1, 0, 3]]  # BGRA -> RGBA
    if ctype in (0, 4) and a.shape[-1] >= 3:  # gray(+alpha) that OpenCV expanded to BGR(A)
        a = a[..., [0, 3]] if a.shape[-1] == 4 else a[..., :1]
    return np.ascontiguousarray(a)


def _encode_png16(q: np.ndarray, where) -> bytes:
    """Encode ``uint16 [H, W, C]`` (C in 1..4; gray+alpha is stored as RGBA) as PNG bytes."""
    c = q.shape[-1]
    if c == 1:
        bgr = q[..., 0]
    elif c == 2:  # libpng through OpenCV writes 1, 3 or 4 channels
        bgr = q[..., [0, 0, 0, 1]]
    elif c == 3:
        bgr = q[..., ::-1]
    else:
        bgr = q[..., [2, 1, 0, 3]]
    with _quiet_opencv() as (cv2, quiet):
        try:
            ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr))
        except cv2.error:
            ok = False
    if not ok:
        raise InputError(f"cannot encode a {q.shape[1]}x{q.shape[0]} 16-bit PNG{quiet.reason()}", where=where,
                         fix="check the image size, or write an EXR instead")
    return buf.tobytes()


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


def read_raw(path) -> tuple[np.ndarray, float | None]:
    """Native pixels ``[H, W, C]`` of an image file and its integer full-scale code (None for float files).

    The format is decided by the file's content (:func:`sniff_format`), and a
    name that promises another format is an :class:`~bayes_brdf.errors.InputError`:
    a ``.png`` must hold a PNG, a ``.exr`` an OpenEXR image, and OpenEXR data is
    refused under any other image extension (see :data:`IMAGE_SUFFIXES`). Files
    with other or no extensions are read by content.

    Integer images come back as ``uint8`` / ``uint16`` with ``C = 1..4`` channels
    as stored (1 gray, 2 gray + alpha, 3 RGB, 4 RGBA; palette images expanded
    to RGB(A)) and full scale ``255.0`` / ``65535.0``; float files (EXR) as
    ``float32`` and ``None``. This is the building block of :func:`read_image`
    for callers that need the raw codes (e.g. to find clipped pixels).

    Example:
        >>> a, full = read_raw("capture/00.png")     # doctest: +SKIP
        >>> a.dtype, a.shape, full   # doctest: +SKIP
        (dtype('uint8'), (1024, 1024, 3), 255.0)
    """
    path = Path(path)
    if not path.exists():
        raise InputError("image file not found", where=path, fix="check the path")
    if path.is_dir():
        raise InputError("expected an image file but this is a folder", where=path)
    head = _read_head(path)
    fmt = _format_of(head)
    _check_content_matches_name(path, fmt)
    if fmt == "OpenEXR":
        return _read_exr(path), None
    hdr = _png_header(head)
    if hdr is not None and hdr[0] == 16:
        return _read_png16(path, hdr[1]), 65535.0
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


def to_rgb(a: np.ndarray) -> np.ndarray:
    """``[H, W, C]`` pixels (as from :func:`read_raw`) -> ``[H, W, 3]``: gray promoted, alpha dropped.

    Example:
        >>> to_rgb(np.zeros((2, 2, 2), np.uint8)).shape      # gray + alpha
        (2, 2, 3)
    """
    c = a.shape[-1]
    if c in (1, 2):
        return np.repeat(a[..., :1], 3, axis=-1)
    return a[..., :3]


def read_image(path) -> np.ndarray:
    """Read an image file as ``float32 [H, W, 3]``.

    PNG / JPEG / ... (8 or 16 bit) come back as the stored display values
    scaled to ``[0, 1]`` (NOT linearised: see :func:`srgb_to_linear`); EXR comes
    back as its linear float values. Grayscale is promoted to 3 channels and
    alpha is dropped. The content decides the format; a ``.png`` that is not a
    PNG or a ``.exr`` that is not an OpenEXR image (e.g. an EXR renamed to
    ``.png``) is refused rather than guessed (see :func:`read_raw`). Every
    problem raises :class:`~bayes_brdf.errors.InputError` naming the file.

    Example:
        >>> img = read_image("capture/00.png")          # doctest: +SKIP
        >>> img.shape, img.dtype   # doctest: +SKIP
        ((1024, 1024, 3), dtype('float32'))
    """
    a, full = read_raw(path)
    a = to_rgb(a)
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
    is. Values are clipped to ``[0, 1]`` and rounded to ``bits`` (8 or 16) bits
    (atomically, mode 0644; 8-bit files are written by Pillow, 16-bit ones by OpenCV; a 2-channel
    gray + alpha image is stored as 16-bit RGBA). Parent folders are created.
    Returns the path.

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
    from .outputs import atomic_path, write_bytes

    if bits == 8:
        from PIL import Image

        with atomic_path(path) as tmp:
            Image.fromarray(q[..., 0] if q.shape[-1] == 1 else q).save(tmp, format="PNG")
    else:
        write_bytes(path, _encode_png16(q, path))
    return path


def write_exr(path, img) -> Path:
    """Write ``img`` (``[H, W]``, ``[H, W, 1]`` or ``[H, W, 3]``) as a lossless float32 EXR.

    One channel is stored as ``Y``, three as ``RGB`` (ZIP compression, lossless,
    so :func:`read_image` gives back the same float32 values), atomically. Returns the path.

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
    from .outputs import atomic_path

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp, OpenEXR.File(header, chans) as f:
        f.write(str(tmp))
    return path


# ------------------------------------------------------------------ resampling
def parse_resolution(size) -> tuple[int, int]:
    """``size`` (an int ``R`` or ``(height, width)``) as ``(height, width)`` of positive ints.

    Raises :class:`~bayes_brdf.errors.InputError` naming "resolution" for
    anything else (0, negatives, fractions, strings).

    Example:
        >>> parse_resolution(128), parse_resolution((64, 32))
        ((128, 128), (64, 32))
    """
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

    h, w = parse_resolution(size)
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
    h, w = parse_resolution(size)
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
