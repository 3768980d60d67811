"""Procedural SVBRDF materials (wood, tiles, marble, scratched metal, leather, fabric).

Example:
    >>> from bayes_brdf.materials import MATERIALS, make_material
    >>> sorted(MATERIALS)[:3]
    ['fabric', 'leather', 'marble']
    >>> make_material("wood", resolution=64, seed=1).albedo.shape
    torch.Size([3, 64, 64])
"""
from .procedural import (MATERIALS, fabric, height_to_normal, leather, make_material, marble,
                         scratched_metal, tiles, wood)

__all__ = ["MATERIALS", "make_material", "height_to_normal",
           "wood", "tiles", "marble", "scratched_metal", "leather", "fabric"]
