"""Losses for training depth networks (torch tensors, (N, C, H, W)).

Self-supervised, as Monodepth2 (Godard et al. 2019, thesis eqs. 5.2–5.6):
- ``photometric_error``: α/2 · (1 − SSIM) + (1 − α) · L1, α = 0.85, SSIM on 3 × 3 windows;
- ``warp``: a source image sampled where the target's pixels land given the target's depth,
  the relative pose and the intrinsics (bilinear);
- ``reprojection_loss``: the per-pixel minimum over sources, with auto-masking (a pixel whose
  unwarped source already matches better — a static camera, an object moving with it — is
  left out);
- ``smoothness``: edge-aware, on the mean-normalised disparity.

Supervised and distillation:
- ``log_l1``: L1 of log depths where a target exists;
- ``gradient_matching``: the scale-invariant gradient loss (MegaDepth, Li & Snavely 2018):
  differences of log-depth gradients at four scales, so edges land where the target's are
  whatever the overall scale;
- ``feature_hint``: FitNets-style hints, a student's features mapped to a teacher's by a
  learned 1 × 1 convolution, compared after normalising each position's feature vector.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

ALPHA = 0.85


def ssim(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM on 3 × 3 windows (reflection padded), Monodepth2's constants."""
    c1, c2 = 0.01**2, 0.03**2
    x, y = F.pad(x, (1, 1, 1, 1), mode="reflect"), F.pad(y, (1, 1, 1, 1), mode="reflect")
    mu_x, mu_y = F.avg_pool2d(x, 3, 1), F.avg_pool2d(y, 3, 1)
    sigma_x = F.avg_pool2d(x * x, 3, 1) - mu_x**2
    sigma_y = F.avg_pool2d(y * y, 3, 1) - mu_y**2
    sigma_xy = F.avg_pool2d(x * y, 3, 1) - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + c1) * (2 * sigma_xy + c2)
    denominator = (mu_x**2 + mu_y**2 + c1) * (sigma_x + sigma_y + c2)
    return numerator / denominator


def photometric_error(predicted: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W): α/2 (1 − SSIM) + (1 − α) L1, averaged over colour channels."""
    l1 = (predicted - target).abs().mean(1, keepdim=True)
    structure = torch.clamp((1 - ssim(predicted, target)) / 2, 0, 1).mean(1, keepdim=True)
    return ALPHA * structure + (1 - ALPHA) * l1


def warp(
    source: torch.Tensor, depth_m: torch.Tensor, K: torch.Tensor, source_T_target: torch.Tensor
) -> torch.Tensor:
    """``source`` (N, C, H, W) resampled into the target's view: each target pixel is lifted
    by its depth (N, 1, H, W), moved by ``source_T_target`` (N, 4, 4) and projected by ``K``
    (N, 3, 3) at this size; outside the source the border is repeated."""
    n, _, height, width = depth_m.shape
    v, u = torch.meshgrid(
        torch.arange(height, dtype=depth_m.dtype, device=depth_m.device),
        torch.arange(width, dtype=depth_m.dtype, device=depth_m.device),
        indexing="ij",
    )
    pixels = torch.stack((u, v, torch.ones_like(u))).reshape(1, 3, -1)
    rays = torch.linalg.inv(K) @ pixels
    points = rays * depth_m.reshape(n, 1, -1)
    moved = source_T_target[:, :3, :3] @ points + source_T_target[:, :3, 3:]
    projected = K @ moved
    z = projected[:, 2:3].clamp(min=1e-3)
    uv = projected[:, :2] / z
    grid = torch.stack(
        (uv[:, 0] / (width - 1) * 2 - 1, uv[:, 1] / (height - 1) * 2 - 1), dim=-1
    ).reshape(n, height, width, 2)
    return F.grid_sample(source, grid, mode="bilinear", padding_mode="border", align_corners=True)


def reprojection_loss(
    target: torch.Tensor,
    warped: list[torch.Tensor],
    sources: list[torch.Tensor],
    automask: bool = True,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The mean over pixels of the per-pixel minimum photometric error over the warped
    sources, and the share of pixels auto-masking kept (Monodepth2's identity reprojection,
    with a tiny noise to break ties)."""
    errors = torch.cat([photometric_error(w, target) for w in warped], dim=1)
    if automask:
        identity = torch.cat([photometric_error(s, target) for s in sources], dim=1)
        identity = identity + 1e-5 * torch.randn_like(identity)
        combined = torch.cat((identity, errors), dim=1)
        best, which = combined.min(dim=1)
        kept = (which >= identity.shape[1]).float()
        return best.mean(), kept.mean()
    return errors.min(dim=1).values.mean(), torch.ones((), device=target.device)


def smoothness(disparity: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """Edge-aware smoothness of the mean-normalised disparity (eq. 5.5)."""
    normalised = disparity / (disparity.mean(dim=(2, 3), keepdim=True) + 1e-7)
    dx = (normalised[..., :, :-1] - normalised[..., :, 1:]).abs()
    dy = (normalised[..., :-1, :] - normalised[..., 1:, :]).abs()
    ix = (image[..., :, :-1] - image[..., :, 1:]).abs().mean(1, keepdim=True)
    iy = (image[..., :-1, :] - image[..., 1:, :]).abs().mean(1, keepdim=True)
    return (dx * torch.exp(-ix)).mean() + (dy * torch.exp(-iy)).mean()


def log_l1(depth_m: torch.Tensor, target_m: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Mean |log d − log t| over the ``valid`` pixels (a bool mask)."""
    if not valid.any():
        return depth_m.sum() * 0
    return (depth_m[valid].log() - target_m[valid].log()).abs().mean()


def gradient_matching(
    depth_m: torch.Tensor, target_m: torch.Tensor, valid: torch.Tensor, scales: int = 4
) -> torch.Tensor:
    """Scale-invariant gradient loss: at each of ``scales`` halvings, the mean absolute
    difference of the x and y gradients of R = log d − log t where both pixels are valid."""
    residual = torch.where(
        valid,
        depth_m.clamp(min=1e-3).log() - target_m.clamp(min=1e-3).log(),
        torch.zeros_like(depth_m),
    )
    mask = valid.float()
    total = depth_m.sum() * 0
    for scale in range(scales):
        if scale:
            residual = F.avg_pool2d(residual * mask, 2) / F.avg_pool2d(mask, 2).clamp(min=1e-6)
            mask = (F.avg_pool2d(mask, 2) > 0.99).float()
        mx = mask[..., :, 1:] * mask[..., :, :-1]
        my = mask[..., 1:, :] * mask[..., :-1, :]
        gx = (residual[..., :, 1:] - residual[..., :, :-1]).abs() * mx
        gy = (residual[..., 1:, :] - residual[..., :-1, :]).abs() * my
        total = total + (gx.sum() + gy.sum()) / (mx.sum() + my.sum()).clamp(min=1)
    return total / scales


def feature_hint(
    student: torch.Tensor, teacher: torch.Tensor, adapter: torch.nn.Module
) -> torch.Tensor:
    """Mean squared difference of the adapted student features and the teacher's, each
    position's vector normalised to unit length (sizes matched by bilinear resizing)."""
    mapped = adapter(student)
    if mapped.shape[2:] != teacher.shape[2:]:
        mapped = F.interpolate(mapped, size=teacher.shape[2:], mode="bilinear", align_corners=False)
    return (F.normalize(mapped, dim=1) - F.normalize(teacher, dim=1)).pow(2).sum(1).mean()
