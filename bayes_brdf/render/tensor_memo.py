"""Values derived from tensors, kept while the same, unmodified tensors come again.

A sampler passes the same observed images, clip levels and weights on every step; their kernel layouts (a
channels-first copy, values repeated per channel) are made once and found again by the tensors' identity and
version (an in-place change makes them again). One small LRU per use: :class:`TensorMemo`.
"""
from __future__ import annotations

from collections import OrderedDict
from typing import Callable


class TensorMemo:
    """An LRU of at most ``size`` values, each keyed by its source tensors (``None`` allowed) and some hashable
    extras. An entry holds its tensors, so their ids are not reused while it lives.

    Example:
        >>> import torch
        >>> memo, t = TensorMemo(2), torch.ones(3)
        >>> a = memo.get((t,), ("double",), lambda: t.double())
        >>> memo.get((t,), ("double",), lambda: None) is a
        True
        >>> _ = t.add_(1)
        >>> float(memo.get((t,), ("double",), lambda: t.double())[0])
        2.0
    """

    def __init__(self, size: int):
        self.size = size
        self._store: OrderedDict = OrderedDict()

    def get(self, tensors: tuple, extra: tuple, make: Callable):
        key = tuple(None if t is None else id(t) for t in tensors) + tuple(extra)
        versions = tuple(None if t is None else t._version for t in tensors)
        hit = self._store.get(key)
        if hit is not None and hit[1] == versions and all(a is b for a, b in zip(hit[0], tensors)):
            self._store.move_to_end(key)
            return hit[2]
        out = make()
        self._store[key] = (tuple(tensors), versions, out)
        while len(self._store) > self.size:
            self._store.popitem(last=False)
        return out
