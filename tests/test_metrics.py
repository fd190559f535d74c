"""Metrics against closed-form cases and a direct transcription of MonoDepth2's formulas."""
import math

import numpy as np
import pytest

from staticdepth.errors import InputError
from staticdepth.metrics import apply_protocol, average, depth_metrics, evaluate, median_scale


def monodepth2_compute_depth_errors(gt, pred):
    """MonoDepth2 ``compute_depth_errors`` (layers.py), transcribed in numpy."""
    thresh = np.maximum((gt / pred), (pred / gt))
    a1 = (thresh < 1.25).mean()
    a2 = (thresh < 1.25 ** 2).mean()
    a3 = (thresh < 1.25 ** 3).mean()
    rmse = np.sqrt(((gt - pred) ** 2).mean())
    rmse_log = np.sqrt(((np.log(gt) - np.log(pred)) ** 2).mean())
    abs_rel = np.mean(np.abs(gt - pred) / gt)
    sq_rel = np.mean(((gt - pred) ** 2) / gt)
    return abs_rel, sq_rel, rmse, rmse_log, a1, a2, a3


def test_perfect_prediction_is_zero_error(rng):
    gt = rng.uniform(1, 70, (20, 30))
    m = depth_metrics(gt, gt)
    for k in ("silog", "abs_rel", "sq_rel", "rmse", "rmse_log"):
        assert m[k] == pytest.approx(0, abs=1e-12)
    assert m["a1"] == m["a2"] == m["a3"] == 1.0 and m["n"] == 600


def test_pred_1_3_times_gt_known_values(rng):
    gt = rng.uniform(1, 50, (40, 40))
    m = depth_metrics(1.3 * gt, gt)
    assert m["abs_rel"] == pytest.approx(0.3)
    assert m["sq_rel"] == pytest.approx(0.09 * gt.mean())
    assert m["rmse"] == pytest.approx(0.3 * math.sqrt((gt ** 2).mean()))
    assert m["rmse_log"] == pytest.approx(math.log(1.3))
    assert m["silog"] == pytest.approx(0, abs=1e-12)  # a pure scale error has zero log variance
    assert m["a1"] == 0 and m["a2"] == 1  # 1.3 > 1.25, 1.3 < 1.5625
    # median rescaling removes a global scale completely
    e = evaluate(1.3 * gt, gt, "median")
    assert e["abs_rel"] == pytest.approx(0, abs=1e-12) and e["scale"] == pytest.approx(1 / 1.3)


def test_silog_is_variance_of_log_error():
    gt = np.array([1.0, 2.0, 4.0, 8.0])
    pred = gt * np.array([1.0, math.e, 1.0, math.e])  # d = [0, 1, 0, 1]: variance 0.25
    assert depth_metrics(pred, gt)["silog"] == pytest.approx(0.25)


def test_against_monodepth2_on_random_data(rng):
    gt = rng.uniform(0.5, 79, 5000)
    pred = gt * np.exp(rng.normal(0, 0.2, 5000))
    ref = monodepth2_compute_depth_errors(gt, np.clip(pred, 1e-3, 80))
    m = depth_metrics(pred, gt)
    for k, v in zip(("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3"), ref):
        assert m[k] == pytest.approx(v, rel=1e-12)


def test_valid_pixels_and_clamping():
    gt = np.array([np.nan, 0.0, 100.0, 10.0, 10.0])
    pred = np.array([5.0, 5.0, 5.0, 200.0, np.nan])
    m = depth_metrics(pred, gt)  # only index 3 is valid; its prediction clamps to 80; 4 is missing
    assert m["n"] == 1 and m["n_pred_missing"] == 1
    assert m["abs_rel"] == pytest.approx(7.0)


def test_lsq_protocol_recovers_inverse_affine(rng):
    gt = rng.uniform(2, 60, 1000)
    pred = 1.0 / (3.0 / gt + 0.05)  # relative depth from an inverse-depth prediction with a shift
    out, s = apply_protocol(pred, gt, "lsq")
    np.testing.assert_allclose(out, gt, rtol=1e-9)


def test_median_scale_and_average():
    assert median_scale(np.array([1.0, 2, 3]), np.array([2.0, 4, 6])) == pytest.approx(2)
    avg = average([{k: 1.0 for k in ("silog", "abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")},
                   {k: 3.0 for k in ("silog", "abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")}])
    assert avg["abs_rel"] == 2.0 and avg["n_images"] == 2


def test_metric_errors():
    with pytest.raises(InputError, match="no valid"):
        depth_metrics(np.ones(3), np.full(3, np.nan))
    with pytest.raises(InputError, match="shape"):
        depth_metrics(np.ones(3), np.ones(4))
    with pytest.raises(InputError, match="unknown protocol"):
        apply_protocol(np.ones(3), np.ones(3), "magic")
    with pytest.raises(InputError, match="no image"):
        average([])


def test_check_prediction_refuses_what_metrics_would_drop():
    from staticdepth.metrics import check_prediction

    gt = np.full((4, 4), 5.0)
    gt[0, :] = np.nan  # no ground truth on the first row
    valid = np.isfinite(gt)
    pred = np.full((4, 4), 5.0, np.float32)
    pred[0, 1] = np.nan  # unknown where there is nothing to compare: allowed
    out = check_prediction(pred, "p.npy", valid=valid)
    assert out.dtype == np.float64 and np.isnan(out[0, 1])
    pred[2, 2] = pred[3, 3] = np.nan  # NaN where the ground truth is valid
    with pytest.raises(InputError, match=r"p.npy: the prediction is NaN at 2 pixel\(s\)"):
        check_prediction(pred, "p.npy", valid=valid)
    for bad in (np.inf, -np.inf):
        with pytest.raises(InputError, match=r"1 infinite pixel"):
            check_prediction(np.where(np.eye(4) * np.arange(4) == 3, bad, 5.0))
    with pytest.raises(InputError, match="complex"):
        check_prediction(np.ones((2, 2), np.complex64))
    with pytest.raises(InputError, match="not numeric"):
        check_prediction(np.array([["a"]]))
