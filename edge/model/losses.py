"""Training losses: the paper's self-supervised terms (Section 4) and RAFT's sequence loss.

Images are (B, 1, H, W) grey 0-255 (scaled to 0-1 inside); disparities (B, 1, H, W) px.
"""

from __future__ import annotations

from typing import Any

import torch
from torch.nn import functional as F

WEIGHTS = dict(appearance=1.0, sparse=0.5, lr=0.01, smooth=0.01)  # the paper's β
ALPHA = 0.85  # SSIM vs L1 (eq. 8)


def warp_horizontal(source: torch.Tensor, disparity: torch.Tensor, sign: float = -1.0
                    ) -> torch.Tensor:
    """Sample `source` at x + sign·d on the same row (bilinear, border clamped). With sign -1
    the right image warped by the left disparity reconstructs the left (eq. 7)."""
    b, _, h, w = disparity.shape
    xs = torch.arange(w, device=disparity.device, dtype=disparity.dtype).view(1, 1, w)
    ys = torch.arange(h, device=disparity.device, dtype=disparity.dtype).view(1, h, 1)
    x = xs + sign * disparity[:, 0]
    grid = torch.stack([2 * x / (w - 1) - 1, (2 * ys / (h - 1) - 1).expand(b, h, w)], -1)
    return F.grid_sample(source, grid, mode="bilinear", padding_mode="border",
                         align_corners=True)


def ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM over 3x3 windows (images in [0, 1]); our own few lines, as in Monodepth,
    rather than a dependency for one formula."""
    c1, c2 = 0.01**2, 0.03**2
    pad = (1, 1, 1, 1)
    xp, yp = F.pad(x, pad, mode="reflect"), F.pad(y, pad, mode="reflect")
    mu_x, mu_y = F.avg_pool2d(xp, 3, 1), F.avg_pool2d(yp, 3, 1)
    sx = F.avg_pool2d(xp * xp, 3, 1) - mu_x**2
    sy = F.avg_pool2d(yp * yp, 3, 1) - mu_y**2
    sxy = F.avg_pool2d(xp * yp, 3, 1) - mu_x * mu_y
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x**2 + mu_y**2 + c1) * (sx + sy + c2)
    return (num / den).clamp(-1, 1)


def occlusion_from_range_map(other_disparity: torch.Tensor, sign: float = 1.0) -> torch.Tensor:
    """Occlusion of this view (1 = occluded) from the other view's disparity (Wang et al.):
    splat every pixel of the other view to x + sign·d here with bilinear weights; pixels that
    receive less than 0.5 in total are seen by no pixel of the other view."""
    b, _, h, w = other_disparity.shape
    x = torch.arange(w, device=other_disparity.device, dtype=other_disparity.dtype)
    target = x.view(1, 1, w) + sign * other_disparity[:, 0]  # (B, H, W)
    x0 = torch.floor(target)
    frac = target - x0
    range_map = torch.zeros(b, h, w + 2, device=other_disparity.device,
                            dtype=other_disparity.dtype)
    for offset, weight in ((0, 1 - frac), (1, frac)):
        idx = (x0 + offset).clamp(-1, w).long() + 1  # slots 0 and w+1 catch the outside
        range_map.scatter_add_(2, idx, weight)
    return (range_map[:, :, 1:-1] < 0.5).to(other_disparity.dtype).unsqueeze(1)


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    return (values * mask).sum() / mask.sum().clamp(min=1.0)


def view_loss(image: torch.Tensor, other: torch.Tensor, disparity: torch.Tensor,
              other_disparity: torch.Tensor, sparse: torch.Tensor, sparse_valid: torch.Tensor,
              sign: float = -1.0) -> dict[str, torch.Tensor]:
    """The four terms of one view (eqs. 8-12). sign -1 for the left view (its correspondent is
    at x - d in the right image), +1 for the right view."""
    visible = 1.0 - occlusion_from_range_map(other_disparity, -sign)
    img, oth = image / 255.0, other / 255.0
    recon = warp_horizontal(oth, disparity, sign)
    appearance = ALPHA * (1 - ssim(img, recon)) / 2 + (1 - ALPHA) * (img - recon).abs()
    other_warped = warp_horizontal(other_disparity, disparity, sign)
    d2x = disparity[..., :, 2:] - 2 * disparity[..., :, 1:-1] + disparity[..., :, :-2]
    d2y = disparity[..., 2:, :] - 2 * disparity[..., 1:-1, :] + disparity[..., :-2, :]
    i2x = img[..., :, 2:] - 2 * img[..., :, 1:-1] + img[..., :, :-2]
    i2y = img[..., 2:, :] - 2 * img[..., 1:-1, :] + img[..., :-2, :]
    smooth = (_masked_mean(d2x.abs() * torch.exp(-i2x.abs()), visible[..., :, 1:-1])
              + _masked_mean(d2y.abs() * torch.exp(-i2y.abs()), visible[..., 1:-1, :]))
    return dict(appearance=_masked_mean(appearance, visible),
                sparse=_masked_mean((disparity - sparse).abs(), sparse_valid),
                lr=_masked_mean((other_warped - disparity).abs(), visible),
                smooth=smooth)


def self_supervised_loss(terms_left: dict, terms_right: dict) -> tuple[torch.Tensor, dict]:
    """(L^l + L^r) / 2 with the paper's weights; also returns the averaged terms."""
    total: Any = 0.0  # a tensor after the first term
    averaged = {}
    for key, weight in WEIGHTS.items():
        averaged[key] = (terms_left[key] + terms_right[key]) / 2
        total = total + weight * averaged[key]
    return total, averaged


def sequence_loss(predictions: list[torch.Tensor], gt: torch.Tensor, valid: torch.Tensor,
                  gamma: float = 0.9, weight: torch.Tensor | None = None) -> torch.Tensor:
    """RAFT's supervised loss: Σ_i γ^(n-1-i) · mean |d_i - gt| over valid GT pixels; with a
    per-pixel `weight`, the weighted mean (the loss keeps its scale, the weights its balance)."""
    mask = valid if weight is None else valid * weight
    n = len(predictions)
    total: Any = 0.0  # a tensor after the first term
    for i, pred in enumerate(predictions):
        total = total + gamma ** (n - 1 - i) * _masked_mean((pred - gt).abs(), mask)
    return total


def depth_edges(gt: torch.Tensor, valid: torch.Tensor, radius: int = 4,
                jump: float = 2.0) -> torch.Tensor:
    """1 where the known GT within `radius` px spans more than `jump` px (a depth edge, as the
    real pairs' bad-3 is split by region in docs/experiments.md), else 0; (B, 1, H, W)."""
    k = 2 * radius + 1
    high = F.max_pool2d(torch.where(valid > 0, gt, -torch.inf), k, 1, radius)
    low = -F.max_pool2d(torch.where(valid > 0, -gt, -torch.inf), k, 1, radius)
    return ((high - low) > jump).to(gt.dtype) * valid


CONFIDENCE_WEIGHT = 0.2
CONFIDENCE_PX = 1.0


def confidence_loss(logit: torch.Tensor, disparity: torch.Tensor, gt: torch.Tensor,
                    valid: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of the confidence logits against "the disparity is within
    CONFIDENCE_PX of the truth", over pixels with GT (the disparity is detached by callers:
    the confidence learns to judge the estimate, not to move it)."""
    target = ((disparity - gt).abs() < CONFIDENCE_PX).to(logit.dtype)
    bce = F.binary_cross_entropy_with_logits(logit, target, reduction="none")
    return _masked_mean(bce, valid)


def split_sparse(valid: torch.Tensor, strategy: str, generator: torch.Generator | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """(input mask, supervision mask) for the split strategies: "all" (every point in, every
    point supervises: the paper's naive one), "half1" (half in, all supervise), "half2" (half
    in, the other half supervises: Sparse-half2)."""
    if strategy == "all":
        return valid, valid
    coin = torch.rand(valid.shape, generator=generator, device=valid.device) < 0.5
    coin = coin.to(valid.dtype)
    inp = valid * coin
    if strategy == "half1":
        return inp, valid
    if strategy == "half2":
        return inp, valid * (1 - coin)
    raise ValueError(f"split strategy: expected all, half1 or half2, got {strategy!r}")
