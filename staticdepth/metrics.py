"""Depth metrics as the paper reports them (METHOD.md section 6). Pure numpy.

- valid pixels: finite gt with ``min_depth < gt < max_depth`` (and inside ``mask``);
- predictions clamped to ``[min_depth, max_depth]``;
- ``silog`` = mean(d^2) - mean(d)^2 with d = ln(pred) - ln(gt) (no square root, no x100);
- ``abs_rel``, ``sq_rel``, ``rmse``, ``rmse_log``, ``a1..a3`` as MonoDepth2's
  ``compute_depth_errors``.
Protocols: ``median`` (per-image median rescaling, the paper's Table 1), ``metric`` (no rescaling,
Table 3 and the stereo baseline), ``lsq`` (least-squares scale and shift in inverse depth, the MiDaS
protocol; a diagnostic, not the paper's).
"""
from __future__ import annotations

from typing import Iterable, Mapping

import math

import numpy as np

from staticdepth.errors import InputError

METRIC_KEYS = ("silog", "abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")
PROTOCOLS = ("median", "metric", "lsq")


def valid_mask(gt: np.ndarray, min_depth: float = 1e-3, max_depth: float = 80.0,
               mask: np.ndarray | None = None) -> np.ndarray:
    gt = np.asarray(gt)
    with np.errstate(invalid="ignore"):
        m = np.isfinite(gt) & (gt > min_depth) & (gt < max_depth)
    if mask is not None:
        m &= np.asarray(mask, dtype=bool)
    return m


def check_depth_range(min_depth: float, max_depth: float) -> None:
    """Refuse a depth cap that leaves no depth to evaluate (0, negative, NaN, below the floor):
    every pixel would leave the metrics and the error would blame the data."""
    if not (math.isfinite(max_depth) and max_depth > min_depth):
        raise InputError(f"--max-depth must be a finite depth above {min_depth:g} m "
                         f"(got {max_depth:g})")


def check_prediction(pred: np.ndarray, where=None, *, valid: np.ndarray | None = None
                     ) -> np.ndarray:
    """A user's prediction as float64, refused (:class:`InputError` naming ``where``) when it is
    not real numbers (complex, text), holds +-inf anywhere, or - given the ground truth's
    ``valid`` pixels - NaN where the ground truth is valid. Metrics would otherwise drop those
    pixels, so a map that is NaN wherever it is wrong would score perfectly; NaN elsewhere is the
    project's "unknown" and stays allowed."""
    a = np.asarray(pred)
    if a.dtype.kind == "c":
        raise InputError(f"the prediction holds complex numbers ({a.dtype}): depth is real", where)
    if a.dtype.kind not in "fiub":
        raise InputError(f"the prediction is not numeric (dtype {a.dtype})", where)
    a = a.astype(np.float64)
    n_inf = int(np.isinf(a).sum())
    if n_inf:
        raise InputError(f"the prediction has {n_inf} infinite pixel(s): give finite depths "
                         "(NaN = unknown)", where)
    if valid is not None:
        n_nan = int((np.isnan(a) & valid).sum())
        if n_nan:
            raise InputError(f"the prediction is NaN at {n_nan} pixel(s) where the ground truth "
                             "is valid: those would be left out of the metrics; predict a depth "
                             "there", where)
    return a


def median_scale(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """ratio = median(gt) / median(pred) over the valid pixels (finite positive prediction)."""
    m = valid_mask(gt, 0.0, np.inf, mask) & np.isfinite(pred) & (np.asarray(pred) > 0)
    if not m.any():
        raise InputError("median scaling: no valid pixel")
    return float(np.median(np.asarray(gt)[m]) / np.median(np.asarray(pred)[m]))


def lsq_inverse_alignment(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None
                          ) -> tuple[float, float]:
    """(s, t) minimising ||s/pred + t - 1/gt||^2 over valid pixels (MiDaS protocol)."""
    m = valid_mask(gt, 0.0, np.inf, mask) & np.isfinite(pred) & (np.asarray(pred) > 0)
    if m.sum() < 2:
        raise InputError("least-squares alignment: fewer than 2 valid pixels")
    x = 1.0 / np.asarray(pred, dtype=np.float64)[m]
    y = 1.0 / np.asarray(gt, dtype=np.float64)[m]
    A = np.stack([x, np.ones_like(x)], axis=1)
    (s, t), *_ = np.linalg.lstsq(A, y, rcond=None)
    return float(s), float(t)


def apply_protocol(pred: np.ndarray, gt: np.ndarray, protocol: str,
                   mask: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The prediction as the protocol evaluates it, and the scale applied (1 for ``metric``)."""
    pred = np.asarray(pred, dtype=np.float64)
    if protocol == "metric":
        return pred, 1.0
    if protocol == "median":
        s = median_scale(pred, gt, mask)
        return pred * s, s
    if protocol == "lsq":
        s, t = lsq_inverse_alignment(pred, gt, mask)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = s / pred + t
            out = np.where(inv > 0, 1.0 / inv, np.inf)
        return out, s
    raise InputError(f"unknown protocol {protocol!r} (one of {PROTOCOLS})")


def depth_metrics(pred: np.ndarray, gt: np.ndarray, *, min_depth: float = 1e-3,
                  max_depth: float = 80.0, mask: np.ndarray | None = None) -> dict[str, float]:
    """Metrics of one image over its valid pixels. ``n`` is the number of valid pixels.

    Pixels where the prediction is NaN are counted as invalid predictions: they are clamped like
    any other value would be impossible, so they are excluded and reported in ``n_pred_missing``.
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise InputError(f"prediction shape {pred.shape} differs from ground truth {gt.shape}")
    m = valid_mask(gt, min_depth, max_depth, mask)
    missing = m & ~np.isfinite(pred) & ~np.isposinf(pred)
    m &= ~missing
    n = int(m.sum())
    if n == 0:
        raise InputError("no valid ground-truth pixel to evaluate")
    g = gt[m]
    p = np.clip(pred[m], min_depth, max_depth)
    d = np.log(p) - np.log(g)
    thresh = np.maximum(g / p, p / g)
    return {
        "silog": float(np.mean(d ** 2) - np.mean(d) ** 2),
        "abs_rel": float(np.mean(np.abs(g - p) / g)),
        "sq_rel": float(np.mean((g - p) ** 2 / g)),
        "rmse": float(np.sqrt(np.mean((g - p) ** 2))),
        "rmse_log": float(np.sqrt(np.mean(d ** 2))),
        "a1": float(np.mean(thresh < 1.25)),
        "a2": float(np.mean(thresh < 1.25 ** 2)),
        "a3": float(np.mean(thresh < 1.25 ** 3)),
        "n": n,
        "n_pred_missing": int(missing.sum()),
    }


def evaluate(pred: np.ndarray, gt: np.ndarray, protocol: str = "median", *,
             min_depth: float = 1e-3, max_depth: float = 80.0,
             mask: np.ndarray | None = None) -> dict[str, float]:
    """Apply the protocol (its scale fitted on the same valid pixels) then :func:`depth_metrics`."""
    m = valid_mask(gt, min_depth, max_depth, mask)
    scaled, s = apply_protocol(pred, gt, protocol, m)
    out = depth_metrics(scaled, gt, min_depth=min_depth, max_depth=max_depth, mask=m)
    out["scale"] = s
    return out


def average(per_image: Iterable[Mapping[str, float]]) -> dict[str, float]:
    """Mean of each metric over images (the paper averages per-image values)."""
    rows = list(per_image)
    if not rows:
        raise InputError("no image to average")
    out = {k: float(np.mean([r[k] for r in rows])) for k in METRIC_KEYS}
    out["n_images"] = len(rows)
    return out
