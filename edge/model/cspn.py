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


def patches_3x3(d: torch.Tensor, centre: bool = True) -> torch.Tensor:
    """(B, 1, H, W) -> (B, 9, H, W) (or 8 without the centre): the 3x3 neighbourhood in
    row-major order (-1,-1), (-1,0), (-1,1), (0,-1), [(0,0)], (0,1), (1,-1), (1,0), (1,1);
    borders replicate. Slices of the padded map, which export to ONNX as Slice ops (F.unfold
    becomes a chain of Gathers several times slower in ONNX Runtime)."""
    h, w = d.shape[-2:]
    padded = F.pad(d, (1, 1, 1, 1), mode="replicate")
    shifts = [(dy, dx) for dy in range(3) for dx in range(3) if centre or (dy, dx) != (1, 1)]
    return torch.cat([padded[:, :, dy:dy + h, dx:dx + w] for dy, dx in shifts], 1)


def neighbours(d: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) -> (B, 8, H, W): the 3x3 neighbourhood without its centre."""
    return patches_3x3(d, centre=False)


def cspn(d: torch.Tensor, weights: torch.Tensor, centre: torch.Tensor, steps: int,
         sparse: torch.Tensor | None = None, valid: torch.Tensor | None = None) -> torch.Tensor:
    """Propagate `d` (B, 1, H, W) for `steps` steps, re-injecting sparse values each step."""
    d0 = d
    anchored = sparse is not None and valid is not None
    if anchored:
        d = (1 - valid) * d + valid * sparse  # type: ignore[operator]  # both given
        d0 = d
    for _ in range(steps):
        d = centre * d0 + (weights * neighbours(d)).sum(1, keepdim=True)
        if anchored:
            d = (1 - valid) * d + valid * sparse  # type: ignore[operator]
    return d
