"""Fine-tuning losses on relative inverse depth (pure torch, device-agnostic).

- :func:`ssi_loss`: MiDaS's scale-and-shift-invariant loss (Ranftl et al., TPAMI 2020): per image,
  the least-squares scale and shift aligning the prediction to the target over the mask, then the
  masked squared error ``sum(m (s p + t - y)^2) / (2 sum m)`` summed over the batch (batch-based
  reduction), plus ``grad_weight`` x the multi-scale gradient-matching term on the aligned residual
  (4 scales, stride 2^k sub-sampling as MiDaS does).
- :func:`ssi_mae_loss`: MiDaS's other scale-and-shift-invariant loss (its Eq. 5-7, untrimmed):
  prediction and target each shifted by their median and divided by their mean absolute deviation
  over the mask, then the mean absolute difference (+ gradient matching on that residual). Its
  gradients do not vanish for an uncorrelated prediction (the least-squares scale does -> 0), so
  it is the one that trains a network from scratch (``staticdepth train-builtin``).
- :func:`si_loss`: as ``ssi`` with the shift fixed at 0 (scale only): for shift-free labels
  (``pseudo_labels.untrusted``), so the fine-tuned network's ``1 / prediction`` is a depth up to
  one scale.
- :func:`masked_l1`: mean absolute error over the mask, no alignment (the labels live in the
  network's own inverse-depth space, so no alignment is needed).
Tensors: prediction, target (B, H, W) float; mask (B, H, W) bool, or float weights (``ssi`` and
``l1``: weighted fit and data term; the gradient term and ``ssi_mae`` use the mask > 0).
"""
from __future__ import annotations

import torch


def scale_shift(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-image (s, t) minimising ``sum(m (s p + t - y)^2)``; (B,) each (0, 0 when degenerate)."""
    m = mask.to(pred.dtype)
    a00 = (m * pred * pred).sum((1, 2))
    a01 = (m * pred).sum((1, 2))
    a11 = m.sum((1, 2))
    b0 = (m * pred * target).sum((1, 2))
    b1 = (m * target).sum((1, 2))
    det = a00 * a11 - a01 * a01
    ok = det > 1e-12 * torch.clamp(a00 * a11, min=1e-30)
    safe = torch.where(ok, det, torch.ones_like(det))
    s = torch.where(ok, (a11 * b0 - a01 * b1) / safe, torch.zeros_like(det))
    t = torch.where(ok, (-a01 * b0 + a00 * b1) / safe, torch.zeros_like(det))
    return s, t


def _mse_batch(res: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    denom = 2.0 * m.sum()
    return (m * res * res).sum() / torch.clamp(denom, min=1.0)


def gradient_loss(res: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """sum(|d/dx (m res)| m_x + |d/dy (m res)| m_y) / sum(m), batch-based (MiDaS)."""
    diff = m * res
    gx = torch.abs(diff[:, :, 1:] - diff[:, :, :-1]) * (m[:, :, 1:] * m[:, :, :-1])
    gy = torch.abs(diff[:, 1:, :] - diff[:, :-1, :]) * (m[:, 1:, :] * m[:, :-1, :])
    return (gx.sum() + gy.sum()) / torch.clamp(m.sum(), min=1.0)


def scale_only(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-image s minimising ``sum(m (s p - y)^2)``; (B,) (0 when the prediction is 0)."""
    m = mask.to(pred.dtype)
    a = (m * pred * pred).sum((1, 2))
    b = (m * pred * target).sum((1, 2))
    ok = a > 1e-30
    return torch.where(ok, b / torch.where(ok, a, torch.ones_like(a)), torch.zeros_like(a))


def si_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None, *,
            grad_weight: float = 0.5, scales: int = 4) -> torch.Tensor:
    """Scale-invariant (no shift) loss + ``grad_weight`` x gradient matching: as :func:`ssi_loss`
    with the per-image shift fixed at 0, so a network trained on shift-free inverse-depth labels
    (0 at infinity) learns to predict with no shift, and its depth ``1 / prediction`` is right up
    to one scale (what median scaling and a metric scale assume)."""
    return _fitted_loss(pred, target, mask, False, grad_weight, scales)


def ssi_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None, *,
             grad_weight: float = 0.5, scales: int = 4) -> torch.Tensor:
    """Scale-and-shift-invariant loss + ``grad_weight`` x multi-scale gradient matching."""
    return _fitted_loss(pred, target, mask, True, grad_weight, scales)


def _fitted_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None,
                 shift: bool, grad_weight: float, scales: int) -> torch.Tensor:
    """The residual of the per-image least-squares fit of ``pred`` to ``target`` (scale and
    shift, or scale only): its mean square + ``grad_weight`` x multi-scale gradient matching."""
    if mask is None:
        mask = torch.isfinite(target)
    m = mask.to(pred.dtype) * torch.isfinite(target).to(pred.dtype)
    y = torch.nan_to_num(target, nan=0.0, posinf=0.0, neginf=0.0)
    if shift:
        s, t = scale_shift(pred, y, m)
        res = s[:, None, None] * pred + t[:, None, None] - y
    else:
        res = scale_only(pred, y, m)[:, None, None] * pred - y
    loss = _mse_batch(res, m)
    if grad_weight > 0:
        reg = pred.new_zeros(())
        mg = (m > 0).to(pred.dtype)     # weights (agent_weight) enter the fit and data term only
        for k in range(scales):
            step = 2 ** k
            reg = reg + gradient_loss(res[:, ::step, ::step], mg[:, ::step, ::step])
        loss = loss + grad_weight * reg
    return loss


def _normalise(x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """(x - median) / mean|x - median| per image over the mask m (B, H, W) bool."""
    out = torch.zeros_like(x)
    for b in range(x.shape[0]):
        v = x[b][m[b]]
        if v.numel() == 0:
            continue
        med = v.median()
        scale = torch.clamp((v - med).abs().mean(), min=1e-6)
        out[b] = (x[b] - med) / scale
    return out


def ssi_mae_loss(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None, *,
                 grad_weight: float = 0.5, scales: int = 4) -> torch.Tensor:
    """Median / mean-absolute-deviation normalised L1 (+ ``grad_weight`` x gradient matching)."""
    if mask is None:
        mask = torch.isfinite(target)
    mb = mask.bool() & torch.isfinite(target)
    m = mb.to(pred.dtype)
    y = torch.nan_to_num(target, nan=0.0, posinf=0.0, neginf=0.0)
    res = _normalise(pred, mb) - _normalise(y, mb)
    loss = (m * res.abs()).sum() / torch.clamp(m.sum(), min=1.0)
    if grad_weight > 0:
        for k in range(scales):
            step = 2 ** k
            loss = loss + grad_weight * gradient_loss(res[:, ::step, ::step], m[:, ::step, ::step])
    return loss


def masked_l1(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
              ) -> torch.Tensor:
    """mean(|pred - target|) over the mask (and finite targets)."""
    if mask is None:
        mask = torch.isfinite(target)
    m = mask.to(pred.dtype) * torch.isfinite(target).to(pred.dtype)
    y = torch.nan_to_num(target, nan=0.0, posinf=0.0, neginf=0.0)
    return (m * torch.abs(pred - y)).sum() / torch.clamp(m.sum(), min=1.0)


LOSSES = {"ssi": ssi_loss, "ssi_mae": ssi_mae_loss, "si": si_loss, "l1": masked_l1}
