"""A layer's parameter typed as the tensor it is: torch types an nn.Sequential's items as
modules and a convolution's bias as optional, so initialisers and surgery on them go
through `param`."""

from __future__ import annotations

import torch


def param(layer: object, name: str = "weight") -> torch.Tensor:
    """`layer.name` (its weight by default); AssertionError if the layer has none."""
    value = getattr(layer, name)
    assert isinstance(value, torch.Tensor), f"{type(layer).__name__}.{name} is {value!r}"
    return value
