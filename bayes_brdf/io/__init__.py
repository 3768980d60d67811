"""Captures I/O: image files, real capture folders (planar, and transforms.json of a mesh), our observation
bundle, SVBRDF map files.

Example:
    >>> from bayes_brdf.io import load_capture, describe
    >>> obs = load_capture("../shared/data/captures/card_blue", resolution=128)   # doctest: +SKIP
    >>> print(describe(obs))                                                      # doctest: +SKIP
"""
from .bundle import load_observations, save_observations
from .captures import describe, load_capture, resample_observations
from .images import linear_to_srgb, read_image, resample, resample_mask, srgb_to_linear, write_exr, write_png
from .maps_files import is_metallic_folder, load_metallic_maps, load_peer_svbrdf_panel, load_svbrdf, save_svbrdf
from .transforms import load_transforms, save_transforms

__all__ = [
    "read_image", "write_png", "write_exr", "srgb_to_linear", "linear_to_srgb", "resample", "resample_mask",
    "load_capture", "describe", "resample_observations",
    "save_observations", "load_observations",
    "save_transforms", "load_transforms",
    "save_svbrdf", "load_svbrdf", "load_peer_svbrdf_panel", "load_metallic_maps", "is_metallic_folder",
]
