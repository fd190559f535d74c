"""Losses against numpy references and their invariances."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from staticdepth.losses import gradient_loss, masked_l1, scale_shift, ssi_loss


def _np_ssi(pred, target, mask, grad_weight=0.5, scales=4):
    """Reference written independently: lstsq per image, then MiDaS's batch-based reductions."""
    B = pred.shape[0]
    res = np.zeros_like(pred)
    for b in range(B):
        m = mask[b]
        A = np.stack([pred[b][m], np.ones(m.sum())], 1)
        (s, t), *_ = np.linalg.lstsq(A, target[b][m], rcond=None)
        res[b] = s * pred[b] + t - target[b]
    mf = mask.astype(np.float64)
    data = (mf * res ** 2).sum() / (2 * mf.sum())
    reg = 0.0
    for k in range(scales):
        r, m = res[:, ::2 ** k, ::2 ** k], mf[:, ::2 ** k, ::2 ** k]
        d = m * r
        gx = np.abs(np.diff(d, axis=2)) * m[:, :, 1:] * m[:, :, :-1]
        gy = np.abs(np.diff(d, axis=1)) * m[:, 1:] * m[:, :-1]
        reg += (gx.sum() + gy.sum()) / m.sum()
    return data + grad_weight * reg


def test_ssi_matches_numpy_reference():
    rng = np.random.default_rng(0)
    pred = rng.random((3, 17, 23))
    target = rng.random((3, 17, 23))
    mask = rng.random((3, 17, 23)) > 0.3
    got = ssi_loss(torch.from_numpy(pred), torch.from_numpy(target), torch.from_numpy(mask))
    assert float(got) == pytest.approx(_np_ssi(pred, target, mask), rel=1e-9)
    got0 = ssi_loss(torch.from_numpy(pred), torch.from_numpy(target), torch.from_numpy(mask),
                    grad_weight=0.0)
    assert float(got0) == pytest.approx(_np_ssi(pred, target, mask, grad_weight=0.0), rel=1e-9)


@settings(max_examples=25, deadline=None)
@given(s=st.floats(0.01, 100), t=st.floats(-10, 10))
def test_ssi_is_zero_for_affine_prediction(s, t):
    rng = np.random.default_rng(1)
    target = torch.from_numpy(rng.random((2, 12, 16)) + 0.1)
    pred = (target - t) / s
    assert float(ssi_loss(pred, target)) < 1e-9


def test_ssi_invariant_to_prediction_scale_and_shift():
    rng = np.random.default_rng(2)
    pred = torch.from_numpy(rng.random((2, 16, 16)))
    target = torch.from_numpy(rng.random((2, 16, 16)))
    a = ssi_loss(pred, target)
    b = ssi_loss(3.7 * pred - 2.0, target)
    assert float(a) == pytest.approx(float(b), rel=1e-9)
    assert float(a) > 0.01


def test_scale_shift_closed_form_and_degenerate():
    p = torch.tensor([[[1.0, 2.0, 3.0]]])
    y = 2 * p + 1
    s, t = scale_shift(p, y, torch.ones_like(p, dtype=torch.bool))
    assert float(s) == pytest.approx(2.0) and float(t) == pytest.approx(1.0)
    s, t = scale_shift(torch.ones(1, 2, 2), torch.rand(1, 2, 2), torch.ones(1, 2, 2))
    assert float(s) == 0.0 and float(t) == 0.0      # constant prediction: no unique fit


def test_nan_targets_are_ignored_and_gradients_flow():
    target = torch.rand(1, 16, 8, dtype=torch.float64)
    target[0, :8] = float("nan")      # 8 rows: the stride-8 sub-sampling sees the same rows
    pred = torch.rand(1, 16, 8, dtype=torch.float64, requires_grad=True)
    loss = ssi_loss(pred, target)
    ref = ssi_loss(pred[:, 8:], target[:, 8:])
    assert torch.isfinite(loss)
    assert float(loss) == pytest.approx(float(ref), rel=1e-9)
    loss.backward()
    assert torch.all(torch.isfinite(pred.grad))
    assert torch.all(pred.grad[0, :8] == 0)


def test_masked_l1_and_gradient_term():
    pred = torch.tensor([[[1.0, 2.0], [3.0, 4.0]]])
    target = torch.tensor([[[1.0, 0.0], [3.0, float("nan")]]])
    assert float(masked_l1(pred, target)) == pytest.approx(2.0 / 3.0)
    mask = torch.tensor([[[True, False], [True, True]]])
    assert float(masked_l1(pred, target, mask)) == pytest.approx(0.0)
    # a linear residual ramp of slope 1 along x over a full mask: mean |d/dx| = (W-1)/W per row
    res = torch.arange(4.0).repeat(1, 3, 1)
    m = torch.ones(1, 3, 4)
    assert float(gradient_loss(res, m)) == pytest.approx(3 * 3 / 12)


def test_weighted_ssi_matches_a_weighted_reference():
    """Float weights (fine-tuning's agent_weight): a weighted least-squares fit and data term,
    the gradient term over the weights > 0; integer weights equal repeating the pixels."""
    rng = np.random.default_rng(3)
    pred, target = rng.random((2, 16, 16)), rng.random((2, 16, 16))
    w = np.where(rng.random((2, 16, 16)) > 0.8, 7.0, 1.0)
    w[:, :2] = 0.0
    res = np.zeros_like(pred)
    for b in range(2):
        sw = np.sqrt(w[b].ravel())
        A = np.stack([pred[b].ravel(), np.ones(pred[b].size)], 1) * sw[:, None]
        (s, t), *_ = np.linalg.lstsq(A, target[b].ravel() * sw, rcond=None)
        res[b] = s * pred[b] + t - target[b]
    data = (w * res ** 2).sum() / (2 * w.sum())
    got0 = ssi_loss(torch.from_numpy(pred), torch.from_numpy(target), torch.from_numpy(w),
                    grad_weight=0.0)
    assert float(got0) == pytest.approx(data, rel=1e-9)
    got = ssi_loss(torch.from_numpy(pred), torch.from_numpy(target), torch.from_numpy(w))
    grad = float(got) - float(got0)
    ref = _np_ssi(pred, target, w > 0) - _np_ssi(pred, target, w > 0, grad_weight=0.0)
    assert grad > 0.01
    # the gradient term uses the weighted fit's residual over the mask w > 0
    m = (w > 0).astype(np.float64)
    reg = 0.0
    for k in range(4):
        r, mk = res[:, ::2 ** k, ::2 ** k], m[:, ::2 ** k, ::2 ** k]
        d = mk * r
        reg += ((np.abs(np.diff(d, axis=2)) * mk[:, :, 1:] * mk[:, :, :-1]).sum()
                + (np.abs(np.diff(d, axis=1)) * mk[:, 1:] * mk[:, :-1]).sum()) / mk.sum()
    assert grad == pytest.approx(0.5 * reg, rel=1e-9)
    assert abs(grad - ref) > 1e-6          # not the unweighted fit's residual


def test_si_loss_is_scale_invariant_not_shift_invariant_and_matches_numpy():
    from staticdepth.losses import si_loss

    rng = np.random.default_rng(1)
    pred = rng.random((2, 9, 13)) + 0.1
    target = rng.random((2, 9, 13))
    mask = rng.random((2, 9, 13)) > 0.2
    res = np.zeros_like(pred)
    for b in range(2):                 # independent reference: 1-D least squares through 0
        m = mask[b]
        s = (pred[b][m] @ target[b][m]) / (pred[b][m] @ pred[b][m])
        res[b] = s * pred[b] - target[b]
    mf = mask.astype(np.float64)
    ref = (mf * res ** 2).sum() / (2 * mf.sum())
    got = si_loss(torch.from_numpy(pred), torch.from_numpy(target), torch.from_numpy(mask),
                  grad_weight=0.0)
    assert float(got) == pytest.approx(ref, rel=1e-9)
    t, p, m = (torch.from_numpy(x) for x in (target, pred, mask))
    assert float(si_loss(3.0 * t, t, m)) == pytest.approx(0.0, abs=1e-12)
    assert float(si_loss(t + 0.5, t, m)) > 1e-3           # a shift is an error
    with_grad = si_loss(p, t, m)
    assert float(with_grad) > float(got)
