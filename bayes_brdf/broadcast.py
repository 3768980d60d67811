"""Broadcasting of shapes without ``torch.broadcast_shapes``.

``torch.broadcast_shapes`` is Python that imports ``torch._refs`` on its first call, and with it
``torch.fx.experimental.symbolic_shapes`` and sympy: about half a second of any command's start on the 2-core
machine (``python -X importtime``, 2026-12-07), for a rule of a few lines. The distributions of the models call
:func:`broadcast_shapes` in their ``log_prob`` instead.
"""
from __future__ import annotations

import torch


def broadcast_shapes(*shapes) -> torch.Size:
    """The shape that tensors of ``shapes`` broadcast to (numpy's rule), or ``ValueError`` when they do not.

    Example:
        >>> broadcast_shapes((2,), (3, 1), (1, 1, 1))
        torch.Size([1, 3, 2])
    """
    out: list[int] = []
    for shape in shapes:
        shape = tuple(shape)
        if len(shape) > len(out):
            out = [1] * (len(shape) - len(out)) + out
        for i, s in enumerate(shape, start=len(out) - len(shape)):
            if s != out[i]:
                if out[i] == 1:
                    out[i] = s
                elif s != 1:
                    raise ValueError(f"shapes {[tuple(s) for s in shapes]} do not broadcast")
    return torch.Size(out)
