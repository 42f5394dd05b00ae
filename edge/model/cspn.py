"""Convolutional spatial propagation with sparse re-injection (the paper's eqs. 4-6).

Â = A / Σ|A| over the 8 neighbours, centre weight Â_c = 1 - ΣÂ, and
d_{t+1} = Â_c · d_0 + Σ_ab Â_ab · d_t(neighbour ab), followed by
d = (1 - V) · d + V · d_s at valid sparse pixels (eq. 6 as intended; the paper's has a typo).
"""

from __future__ import annotations

import torch
from torch.nn import functional as F


def normalise_affinity(affinity: torch.Tensor, eps: float = 1e-6
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, 8, H, W) raw affinity -> (neighbour weights (B, 8, H, W), centre (B, 1, H, W))."""
    norm = affinity.abs().sum(1, keepdim=True) + eps
    weights = affinity / norm
    return weights, 1.0 - weights.sum(1, keepdim=True)


def neighbours(d: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) -> (B, 8, H, W): the 3x3 neighbourhood without its centre, in row-major
    order (-1,-1), (-1,0), (-1,1), (0,-1), (0,1), (1,-1), (1,0), (1,1); borders replicate."""
    b, _, h, w = d.shape
    padded = F.pad(d, (1, 1, 1, 1), mode="replicate")
    patches = F.unfold(padded, 3).view(b, 9, h, w)
    return torch.cat([patches[:, :4], patches[:, 5:]], 1)


def cspn(d: torch.Tensor, weights: torch.Tensor, centre: torch.Tensor, steps: int,
         sparse: torch.Tensor | None = None, valid: torch.Tensor | None = None) -> torch.Tensor:
    """Propagate `d` (B, 1, H, W) for `steps` steps, re-injecting sparse values each step."""
    d0 = d
    if sparse is not None:
        d = (1 - valid) * d + valid * sparse
        d0 = d
    for _ in range(steps):
        d = centre * d0 + (weights * neighbours(d)).sum(1, keepdim=True)
        if sparse is not None:
            d = (1 - valid) * d + valid * sparse
    return d
