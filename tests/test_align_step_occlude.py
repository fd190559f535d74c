"""``upright`` with ``step_occlude``: a wall whose foot a nearer, lower wall hides.

A network that resolves the nearer wall steps down to it going down the far wall's columns, so
the far wall's run ends there without a contact and keeps the ground mode's scale, which is the
ground's, not the far wall's. With ``step_occlude`` that run is cut like one an agent cuts
(tests/test_align_occlude.py) and takes the ratio of the same far wall beside the near one, whose
foot is visible: the far wall's own scale. The network here is exact up to one scale per
structure (ground, near wall, far wall)."""
from __future__ import annotations

import numpy as np
import pytest

from billboard_scene import billboard_camera
from staticdepth.geometry.alignment import align_depth

W, H, F = 160, 100, 100.0
CAM = 1.5


def _scene(pitch_deg=10.0, far_m=14.0, near_m=6.0, near_h=1.2, near_half_w=1.5):
    """True depth and ground / far wall / near wall masks: a wall 14 m away (|lateral| < 6 m,
    5 m tall) and a lower wall 6 m away in front of its middle (|lateral| < 1.5 m, 1.2 m tall:
    its top is above the far wall's foot in the image); sky 200 m."""
    K, n, z_ground, billboard = billboard_camera(CAM, pitch_deg, W, H, F)
    z_far, far = billboard(far_m, 6.0, 5.0)
    z_near, near = billboard(near_m, near_half_w, near_h)
    depth = np.where(near, z_near, np.where(far, z_far, z_ground))
    far &= ~near
    depth[~np.isfinite(depth)] = 200.0
    ground = ~far & ~near & (z_ground < 60)
    return K, n, depth.astype(np.float32), ground, far, near


def _network(depth, far, near, far_scale=0.6, near_scale=0.85):
    """Exact up to a scale per structure: the far wall 40% too near, the near wall 15% too near
    (the ground exact; a wall too far is pulled nearer than ``max_pull`` allows and keeps the
    ground mode, tests/test_align_upright.py)."""
    pred = depth.copy()
    pred[far] *= far_scale
    pred[near] *= near_scale
    return pred


def _aligned(pred, K, n, ground, **kw):
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    opts = {**upright_options(build_config({}).align), **kw}      # adapt's defaults
    return align_depth(pred, K, n, CAM, ground, mode="upright", **opts).depth


def _rel(A, Z, m):
    return float(np.median(np.abs(A[m] - Z[m]) / Z[m]))


def _parts(far, near):
    cols = near.any(0)
    hidden = far & cols[None, :]            # the far wall above the near one: its foot hidden
    return hidden, far & ~hidden


def test_the_scene_is_what_the_test_needs():
    K, n, Z, ground, far, near = _scene()
    hidden, beside = _parts(far, near)
    assert hidden.sum() > 100 and beside.sum() > 300
    cols = np.flatnonzero(near.any(0))
    # in the near wall's columns the far wall ends on the near wall, not on the ground
    for u in cols[:: max(1, len(cols) // 5)]:
        low = np.flatnonzero(far[:, u])[-1]
        assert near[low + 1, u]
    # a step the runs stop at: the near wall is more than jump_rel nearer
    assert np.all(Z[np.roll(near, -1, 0) & far] > 1.08 * Z[near & np.roll(far, 1, 0)].max())


def test_a_far_wall_behind_a_nearer_wall_takes_its_own_scale():
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    assert not upright_options(build_config({}).align)["step_occlude"]  # off by default
    assert upright_options(build_config({"align": {"step_occlude": True}}).align)["step_occlude"]
    K, n, Z, ground, far, near = _scene()
    pred = _network(Z, far, near)
    hidden, beside = _parts(far, near)
    off = _aligned(pred, K, n, ground)
    on = _aligned(pred, K, n, ground, step_occlude=True)
    # the near wall and the far wall beside it stand on their own feet either way
    assert _rel(off, Z, near) < 0.04 and _rel(on, Z, near) < 0.04
    assert _rel(off, Z, beside) < 0.04 and _rel(on, Z, beside) == _rel(off, Z, beside)
    # above the near wall the far wall's run stops at the step: without the rule it keeps the
    # ground mode's scale (the ground's: the network's 0.6 x), not the far wall's own
    assert _rel(off, Z, hidden) > 0.3
    assert _rel(on, Z, hidden) < 0.04
    # nor the near wall's (0.6 / 0.85 x), which a run through a smooth ramp would take
    assert np.median(on[hidden] / Z[hidden]) == pytest.approx(1.0, abs=0.04)


def test_the_far_wall_aligned_again_stays():
    """ft-align aligns an aligned map again: the far wall placed by its neighbours' ratio keeps
    its place in a second pass."""
    K, n, Z, ground, far, near = _scene()
    once = _aligned(_network(Z, far, near), K, n, ground, step_occlude=True)
    twice = _aligned(once, K, n, ground, step_occlude=True)
    assert _rel(once, Z, far) < 0.04
    assert np.max(np.abs(twice[far] - once[far]) / once[far]) < 0.01


def test_the_torch_twin_matches_numpy_and_exports():
    """The exported graph has no agent mask, but it sees the step: the twin cuts the same runs
    (UprightAlignment, geometry/alignment_upright_torch.py), also in ONNX."""
    import warnings

    import onnxruntime as ort
    import torch

    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config
    from staticdepth.geometry.alignment_torch import alignment_module

    K, n, Z, ground, far, near = _scene()
    pred = _network(Z, far, near)
    opts = upright_options(build_config({"align": {"step_occlude": True}}).align)   # the rule on
    ref = align_depth(pred, K, n, CAM, ground, mode="upright", **opts).depth
    mod = alignment_module("upright", K, W, H, n, CAM, ground, snap_rel=0.1, **opts)
    out = mod(torch.from_numpy(pred)).numpy()
    assert np.max(np.abs(out - ref) / ref) < 1e-5
    hidden, _ = _parts(far, near)
    assert _rel(out, Z, hidden) < 0.04
    import tempfile

    with tempfile.TemporaryDirectory() as d, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        path = f"{d}/u.onnx"
        torch.onnx.export(mod, (torch.from_numpy(pred),), path, input_names=["z"],
                          opset_version=17, dynamo=False)
        sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
        # another frame: the walls at other scales (the graph follows any frame)
        pred2 = _network(Z, far, near, far_scale=0.75, near_scale=0.9)
        ref2 = align_depth(pred2, K, n, CAM, ground, mode="upright", **opts).depth
        got = sess.run(None, {"z": pred2})[0]
    assert np.max(np.abs(got - ref2) / ref2) < 1e-4
    assert _rel(got, Z, hidden) < 0.04


def test_the_torch_twin_matches_numpy_on_an_independent_frame():
    """On a frame of the independent generator whose structures are sharp and 25-35% too near
    (tests/test_alignment_upright_torch.py's frame): the rule cuts runs there, and the twin
    cuts the same."""
    import torch

    from staticdepth.geometry.alignment_upright_torch import UprightAlignment
    from tests.test_alignment_upright_torch import frame as frame_fixture

    Z, K, n, G, _ = frame_fixture.__wrapped__()
    kw = {"fill": False, "max_pull": 1.1, "contact_range": 2.0, "recede_push": 2.0,
          "walked_ratio": 1.2}
    off = align_depth(Z, K, n, 1.0, G, mode="upright", **kw).depth
    ref = align_depth(Z, K, n, 1.0, G, mode="upright", step_occlude=True, **kw).depth
    assert np.mean(np.abs(ref - off) / off > 1e-3) > 0.002      # the rule changed ~200 pixels
    out = UprightAlignment(K, 320, 160, n, 1.0, G, step_occlude=True, **kw)(
        torch.from_numpy(Z)).numpy()
    assert np.max(np.abs(out - ref) / ref) < 1e-5
