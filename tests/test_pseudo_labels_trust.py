"""adapt's aligned pseudo labels with ``pseudo_labels.untrusted``: agents and the static pixels
whose alignment repeats over the adaptation split keep their label, the others take the base
network's value (``base``), leave the loss (``ignore``) or keep it too (``aligned``, every pixel
shift-free); checked against the stable mask
recomputed from adapt's own ``align`` output (the base prediction aligned, every frame)."""
from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

from staticdepth.adaptation.common import FrameFile
from staticdepth.dataset.h5 import SequenceReader
from staticdepth.dataset.synth_io import render_to_file
from staticdepth.pseudo_labels import stable_depth

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


class Ramp(torch.nn.Module):
    """Inverse depth growing down the image (a ground that recedes, as the aligned labels need)
    plus a term of the image's brightness, which varies from frame to frame."""

    def forward(self, x):
        b, _, h, w = x.shape
        v = torch.linspace(0.0, 1.0, h).view(1, h, 1).expand(b, h, w)
        return 0.1 + v + 0.2 * torch.sigmoid(x.mean(1))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("trust")
    model = d / "ramp.pt"
    torch.jit.script(Ramp()).save(str(model))
    clip = d / "clip.h5"
    render_to_file(clip, preset_name="c1", n_frames=30, adapt_frames=20, seed=1,
                   overrides={"width": 128, "height": 64})
    return str(clip), str(model)


def _labels(seq):
    with FrameFile(seq + ".adapt/labels.h5", None) as f:
        return np.stack([f[k] for k in range(len(f))])


def test_untrusted_pixels_take_the_base_value_or_leave_the_loss(tmp_path, scene):
    from staticdepth.adapt import adapt
    from staticdepth.adaptation.config import build_config

    clip, model = scene
    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    base = {"model": f"torch:{model}", "detector.name": "gt", "finetune.epochs": 0,
            "tracking.min_height_px": 3, "plane.bootstrap": 0,
            # the labels align without the plane's bound and the colour foot (both shape adapt's
            # `align` output only): off here, the stored `align` is the labels' alignment
            "align.plane_bound": False, "align.colour_foot": False}
    adapt(seq, build_config(base), log=lambda m: None)
    label = _labels(seq)
    with SequenceReader(seq) as r:
        split = list(r.split("adapt"))
        aligned = np.stack([r.prediction("align", i) for i in split])
        static = np.stack([r.instances(i) == 0 for i in split])
    with FrameFile(seq + ".adapt/inverse-base.h5", None) as f:
        inv = np.stack([f[i] for i in split])
    _, stable = stable_depth(aligned, static, 0.03)         # 20 frames < dense_frames: all
    trusted = stable[None] | ~static
    assert stable.mean() > 0.2 and np.count_nonzero(~stable) > 50     # both kinds present
    adapt(seq, build_config({**base, "pseudo_labels.untrusted": "base"}), log=lambda m: None)
    kept = _labels(seq)
    assert not np.allclose(label[~trusted], inv[~trusted])  # the default labels did move them
    for k in range(len(split)):
        # trusted: s / aligned, one s a frame (shift-free)
        m = trusted[k] & np.isfinite(aligned[k]) & (aligned[k] > 0)
        s = kept[k][m] * aligned[k][m]
        np.testing.assert_allclose(s, np.median(s), rtol=1e-4)
        # untrusted: the base less one shift t a frame, t that of the base over trusted pixels
        u = ~trusted[k] & np.isfinite(kept[k])
        assert np.count_nonzero(u) > 0.9 * np.count_nonzero(~trusted[k])
        minus_t = kept[k][u] - inv[k][u]
        np.testing.assert_allclose(minus_t, np.median(minus_t), atol=1e-5)
        rng = np.ptp(inv[k][m])
        assert abs(np.median(minus_t) - np.median(kept[k][m] - inv[k][m])) < 0.05 * rng
    adapt(seq, build_config({**base, "pseudo_labels.untrusted": "ignore"}), log=lambda m: None)
    dropped = _labels(seq)
    assert np.isnan(dropped[~trusted]).all()
    np.testing.assert_array_equal(dropped[trusted], kept[trusted])
    # aligned: no stability test, every pixel with an alignment takes s / aligned (one s a
    # frame, fitted over all of them): shift-free, and the untrusted pixels move with the rest
    adapt(seq, build_config({**base, "pseudo_labels.untrusted": "aligned"}), log=lambda m: None)
    every = _labels(seq)
    for k in range(len(split)):
        m = np.isfinite(aligned[k]) & (aligned[k] > 0)
        assert m.mean() > 0.9
        s = every[k][m] * aligned[k][m]
        np.testing.assert_allclose(s, np.median(s), rtol=1e-4)
    u = ~trusted & np.isfinite(aligned)
    assert not np.allclose(every[u], kept[u], rtol=1e-3)      # not the base's value there


def test_scale_only_loss_needs_shift_free_labels(tmp_path, scene):
    """finetune.loss=si with labels that carry the network's shift is refused before any
    prediction (no stage file is written)."""
    import os

    from staticdepth.adapt import adapt
    from staticdepth.adaptation.config import build_config
    from staticdepth.errors import InputError

    clip, model = scene
    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    conf = {"model": f"torch:{model}", "detector.name": "gt", "finetune.epochs": 1,
            "tracking.min_height_px": 3, "plane.bootstrap": 0, "finetune.loss": "si"}
    for bad in ({"pseudo_labels.untrusted": "label"}, {"pseudo_labels.source": "plane"}):
        with pytest.raises(InputError, match="needs shift-free labels"):
            adapt(seq, build_config({**conf, **bad}), log=lambda m: None)
    assert not os.path.exists(seq + ".adapt/inverse-base.h5")


class Inverted(torch.nn.Module):
    """Inverse depth falling down the image: the network's ground does not recede against the
    agents' plane, the frames where the labels used to fall back to the paper's (shifted) ones."""

    def forward(self, x):
        b, _, h, w = x.shape
        v = torch.linspace(0.0, 1.0, h).view(1, h, 1).expand(b, h, w)
        return 1.1 - v + 0.2 * torch.sigmoid(x.mean(1))


def test_frames_without_a_receding_ground_keep_shift_free_labels(tmp_path, scene):
    """Where the network's ground does not recede, the labels still come from the fit over the
    trusted pixels (``s / aligned`` there, one s a frame; untrusted ones left out with
    ``ignore``), not the paper's labels, which carry the network's shift (wrong for loss=si)."""
    from staticdepth.adapt import adapt
    from staticdepth.adaptation.config import build_config
    from staticdepth.geometry.alignment import ground_mask_from_feet
    from staticdepth.geometry.projection import ray_grid
    from staticdepth.pseudo_labels import aligned_pseudo_label

    clip, _ = scene
    model = tmp_path / "inverted.pt"
    torch.jit.script(Inverted()).save(str(model))
    seq = str(tmp_path / "s.h5")
    shutil.copy(clip, seq)
    conf = build_config({"model": f"torch:{model}", "detector.name": "gt", "finetune.epochs": 0,
                         "tracking.min_height_px": 3, "plane.bootstrap": 0,
                         "align.plane_bound": False, "align.colour_foot": False,
                         "pseudo_labels.untrusted": "ignore",
                         # the labels come from the network's alignment; align.min_ground_r2 0
                         # writes that alignment as `align` too (else the plane alone, R^2 0)
                         "align.min_ground_r2": 0.0})
    summary = adapt(seq, conf, log=lambda m: None)
    label = _labels(seq)
    with SequenceReader(seq) as r:
        split = list(r.split("adapt"))
        aligned = np.stack([r.prediction("align", i) for i in split])
        static = np.stack([r.instances(i) == 0 for i in split])
        K, W, H = r.camera.K, r.width, r.height
        feet = np.concatenate([np.stack([a["foot_u"], a["foot_v"]], 1)
                               for a in (r.agents(i) for i in split) if len(a)])
    with FrameFile(seq + ".adapt/inverse-base.h5", None) as f:
        inv = np.stack([f[i] for i in split])
    q = (ray_grid(K, W, H) @ np.asarray(summary["plane"]["normal"])).astype(np.float32)
    ground = ground_mask_from_feet(feet[feet[:, 1] >= 0], W, H, W / 80.0)    # adapt's default
    receding = [aligned_pseudo_label(inv[k], aligned[k], q, ground & static[k])[1].any()
                for k in range(len(split))]
    assert not any(receding)             # every frame is one the labels used to fall back on
    _, stable = stable_depth(aligned, static, 0.03)
    trusted = stable[None] | ~static
    assert np.isnan(label[~trusted]).all()
    for k in range(len(split)):
        m = trusted[k] & np.isfinite(label[k])
        assert m.mean() > 0.2
        s = label[k][m] * aligned[k][m]
        np.testing.assert_allclose(s, np.median(s), rtol=1e-4)
