"""Stereo baseline building blocks: references, closed forms, the warp on a synthetic pair."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from numpy.lib.stride_tricks import sliding_window_view
from test_baseline_scene import BASELINE_M, camera, render_pair

from staticdepth.baseline.config import BaselineConfig, preset
from staticdepth.baseline.data import StereoGeometry, color_jitter, make_batch, to_float
from staticdepth.baseline.decoder import DepthDecoder
from staticdepth.baseline.layers import (disp_to_depth, disparity_px_from_depth,
                                         photometric_error, smoothness_loss, ssim,
                                         ssim_dissimilarity, warp_horizontal)
from staticdepth.baseline.losses import stereo_loss
from staticdepth.baseline.network import DepthNet, build_model
from staticdepth.baseline.resnet import ResnetEncoder, load_imagenet_weights
from staticdepth.errors import InputError


# -- references --------------------------------------------------------------------------------
def test_disp_to_depth_matches_monodepth2_formula():
    s = torch.linspace(0, 1, 101, dtype=torch.float64)
    scaled, depth = disp_to_depth(s, 0.1, 100.0)
    ref = 1.0 / (1 / 100 + (1 / 0.1 - 1 / 100) * s.numpy())   # MonoDepth2 / the formula
    np.testing.assert_allclose(depth.numpy(), ref, rtol=1e-12)
    np.testing.assert_allclose(scaled.numpy(), 1.0 / ref, rtol=1e-12)
    assert depth[0] == pytest.approx(100.0) and depth[-1] == pytest.approx(0.1)
    _, d = disp_to_depth(torch.tensor([0.0, 1.0]), 1.0, 80.0)
    np.testing.assert_allclose(d.numpy(), [80.0, 1.0], rtol=1e-6)


def _ssim_numpy(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """SSIM per pixel with 3x3 means over reflection-padded (C, H, W) images."""
    def mean3(a):
        a = np.pad(a, ((0, 0), (1, 1), (1, 1)), mode="reflect")
        return sliding_window_view(a, (3, 3), axis=(1, 2)).mean(axis=(-2, -1))
    mx, my = mean3(x), mean3(y)
    vx, vy = mean3(x * x) - mx * mx, mean3(y * y) - my * my
    cxy = mean3(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    return ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx ** 2 + my ** 2 + c1) * (vx + vy + c2))


def test_ssim_matches_numpy_reference(rng):
    x = rng.random((2, 3, 13, 17))
    y = np.clip(x + 0.2 * rng.standard_normal(x.shape), 0, 1)
    got = ssim(torch.from_numpy(x), torch.from_numpy(y)).numpy()
    for b in range(2):
        np.testing.assert_allclose(got[b], _ssim_numpy(x[b], y[b]), rtol=1e-10, atol=1e-12)
    same = ssim_dissimilarity(torch.from_numpy(x), torch.from_numpy(x))
    assert float(same.abs().max()) < 1e-12
    assert 0.05 < float(ssim_dissimilarity(torch.from_numpy(x), torch.from_numpy(y)).mean()) < 1


def test_photometric_error_weights():
    x = torch.full((1, 3, 8, 8), 0.5)
    y = torch.full((1, 3, 8, 8), 0.7)      # flat images: SSIM term from the means alone
    s = float(ssim_dissimilarity(x, y).mean())
    got = photometric_error(x, y)
    np.testing.assert_allclose(got.numpy(), 0.85 * s + 0.15 * 0.2, rtol=1e-5)
    np.testing.assert_allclose(photometric_error(x, y, 0.0).numpy(), 0.2, rtol=1e-5)


def test_smoothness_closed_forms():
    w, h, a = 16, 8, 0.3
    ramp = (a * torch.arange(w, dtype=torch.float64)).expand(1, 1, h, w)
    flat = torch.zeros(1, 3, h, w, dtype=torch.float64)
    assert float(smoothness_loss(ramp, flat)) == pytest.approx(a)
    edge = flat.clone()
    edge[..., w // 2:] = 1.0                     # a vertical edge damps the x term there
    want = a * ((w - 2) + math.exp(-1)) / (w - 1)
    assert float(smoothness_loss(ramp, edge)) == pytest.approx(want)
    assert float(smoothness_loss(torch.ones(1, 1, h, w), edge)) == 0.0


# -- the warp on a synthetic rectified pair ----------------------------------------------------
def _tensors(fr):
    left = to_float(torch.from_numpy(fr["left"][None]))
    right = to_float(torch.from_numpy(fr["right"][None]))
    return left, right


@pytest.fixture(scope="module")
def pair():
    return render_pair(None)


def test_warp_with_true_disparity_reproduces_the_other_view(pair):
    cam = camera()
    left, right = _tensors(pair)
    u = torch.arange(cam.width, dtype=torch.float32)
    for target, source, depth, direction in ((left, right, pair["depth"], 1.0),
                                             (right, left, pair["depth_right"], -1.0)):
        disp = disparity_px_from_depth(torch.from_numpy(depth)[None, None], cam.fx, BASELINE_M)
        u_src = u - direction * disp[0, 0]
        valid = (u_src >= 0) & (u_src <= cam.width - 1)
        valid[:, :2] = valid[:, -2:] = False
        valid[:2] = valid[-2:] = False
        warped = warp_horizontal(source, disp, direction)
        err = (warped - target).abs().mean(1)[0][valid].mean()
        ident = (source - target).abs().mean(1)[0][valid].mean()
        wrong = (warp_horizontal(source, disp * 1.3, direction) - target).abs().mean(1)[0][valid]
        pe = photometric_error(warped, target)[0, 0][valid].mean()
        assert err < 0.003 and pe < 0.002, (float(err), float(pe))  # 5% off: 0.006, 0.0025
        assert ident > 8 * err and wrong.mean() > 4 * err
        assert valid.float().mean() > 0.8


def test_flipped_pairs_keep_the_stereo_sign(pair):
    """make_batch's direction, with flips and either side as target, warps source onto target."""
    cam = camera()
    left_u8 = torch.from_numpy(pair["left"][None])
    right_u8 = torch.from_numpy(pair["right"][None])
    geo = StereoGeometry(BASELINE_M, cam.fx, cam.fx, cam.size)
    depth = {True: pair["depth"], False: pair["depth_right"]}
    for tl in (True, False):
        for flip in (False, True):
            b = make_batch(left_u8, right_u8, torch.tensor([0]), torch.tensor([tl]),
                           torch.tensor([flip]), geo)
            d = torch.from_numpy(depth[tl])[None, None]
            d = d.flip(-1) if flip else d
            disp = disparity_px_from_depth(d, b["focal_px"], b["baseline_m"])
            assert float(b["direction"][0]) == (1.0 if tl != flip else -1.0)
            good = warp_horizontal(b["source"], disp, b["direction"])
            bad = warp_horizontal(b["source"], disp, -b["direction"])
            core = (slice(None), slice(None), slice(4, -4), slice(24, -24))
            e_good = float((good - b["target"]).abs()[core].mean())
            e_bad = float((bad - b["target"]).abs()[core].mean())
            assert e_good < 0.01 and e_bad > 5 * e_good, (tl, flip, e_good, e_bad)
            assert torch.equal(b["image"], b["target"])


def test_stereo_loss_prefers_the_true_depth(pair):
    cam = camera()
    left, right = _tensors(pair)
    conf = BaselineConfig(min_depth=1.0, max_depth=100.0)
    depth = torch.from_numpy(pair["depth"])[None, None]

    def sigmoid_for(z):   # inverse of disp_to_depth
        return (1 / z - 1 / conf.max_depth) / (1 / conf.min_depth - 1 / conf.max_depth)

    def pyramid(z):
        return [torch.nn.functional.interpolate(sigmoid_for(z), scale_factor=0.5 ** s,
                                                mode="area") if s else sigmoid_for(z)
                for s in range(4)]
    torch.manual_seed(0)
    true = stereo_loss(pyramid(depth), left, right, cam.fx, BASELINE_M, 1.0, conf)
    const = stereo_loss(pyramid(torch.full_like(depth, float(depth.median()))), left, right,
                        cam.fx, BASELINE_M, 1.0, conf)
    assert float(true["photometric"]) < 0.5 * float(const["photometric"])
    assert float(true["loss"]) < float(const["loss"])
    no_mask = stereo_loss(pyramid(depth), left, right, cam.fx, BASELINE_M, 1.0,
                          BaselineConfig(min_depth=1.0, automask=False))
    assert float(no_mask["photometric"]) >= float(true["photometric"])


def test_color_jitter():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 8, 8, generator=g) * 0.6 + 0.2
    one, zero = torch.ones(2), torch.zeros(2)
    torch.testing.assert_close(color_jitter(x, one, one, one, zero), x, atol=1e-6, rtol=0)
    torch.testing.assert_close(color_jitter(x, one, one, one, one), x, atol=1e-5, rtol=0)
    torch.testing.assert_close(color_jitter(x, one * 1.2, one, one, zero), (x * 1.2).clamp(0, 1))
    grey = color_jitter(x, one, one, zero, zero)
    assert float((grey - grey.mean(1, keepdim=True)).abs().max()) < 1e-6
    shifted = color_jitter(x, one, one, one, one * 0.1)
    assert float((shifted - x).abs().mean()) > 1e-3


# -- model -------------------------------------------------------------------------------------
def test_encoder_decoder_shapes():
    net = DepthNet(encoder_width=8, decoder_channels=(4, 4, 8, 8, 16))
    assert net.encoder.num_ch_enc == (8, 8, 16, 32, 64)
    feats = net.encoder(torch.rand(2, 3, 64, 96))
    assert [tuple(f.shape[1:]) for f in feats] == [(8, 32, 48), (8, 16, 24), (16, 8, 12),
                                                   (32, 4, 6), (64, 2, 3)]
    with torch.no_grad():
        disps = net(torch.rand(2, 3, 64, 96))
    assert [tuple(d.shape) for d in disps] == [(2, 1, 64 // 2 ** s, 96 // 2 ** s) for s in range(4)]
    assert all(float(d.min()) > 0 and float(d.max()) < 1 for d in disps)
    with pytest.raises(InputError, match="5 positive"):
        DepthDecoder((8, 8, 16, 32, 64), (4, 4, 8))
    with pytest.raises(InputError, match="num_scales"):
        DepthDecoder((8, 8, 16, 32, 64), num_scales=5)
    with pytest.raises(InputError, match="encoder width"):
        ResnetEncoder(0)


def _torchvision_resnet18_state_dict(seed: int = 0) -> dict[str, torch.Tensor]:
    """The key names and shapes of torchvision's ``resnet18().state_dict()``, written out."""
    g = torch.Generator().manual_seed(seed)
    sd: dict[str, torch.Tensor] = {}

    def bn(prefix, c):
        sd[f"{prefix}.weight"] = torch.rand(c, generator=g)
        sd[f"{prefix}.bias"] = torch.rand(c, generator=g)
        sd[f"{prefix}.running_mean"] = torch.rand(c, generator=g)
        sd[f"{prefix}.running_var"] = torch.rand(c, generator=g) + 0.5
        sd[f"{prefix}.num_batches_tracked"] = torch.tensor(7)
    sd["conv1.weight"] = torch.randn(64, 3, 7, 7, generator=g)
    bn("bn1", 64)
    cin = 64
    for i, c in enumerate((64, 128, 256, 512), start=1):
        for j in range(2):
            p = f"layer{i}.{j}"
            sd[f"{p}.conv1.weight"] = torch.randn(c, cin if j == 0 else c, 3, 3, generator=g)
            bn(f"{p}.bn1", c)
            sd[f"{p}.conv2.weight"] = torch.randn(c, c, 3, 3, generator=g)
            bn(f"{p}.bn2", c)
            if j == 0 and i > 1:
                sd[f"{p}.downsample.0.weight"] = torch.randn(c, cin, 1, 1, generator=g)
                bn(f"{p}.downsample.1", c)
        cin = c
    sd["fc.weight"] = torch.randn(1000, 512, generator=g)
    sd["fc.bias"] = torch.randn(1000, generator=g)
    return sd


def test_imagenet_weights_load_from_a_torchvision_state_dict(tmp_path):
    sd = _torchvision_resnet18_state_dict()
    assert len(sd) == 122                      # torchvision resnet18: 62 parameters + 60 buffers
    path = tmp_path / "resnet18.pth"
    torch.save(sd, path)
    enc = ResnetEncoder(64)
    load_imagenet_weights(enc, path)
    assert torch.equal(enc.layer3[0].downsample[0].weight, sd["layer3.0.downsample.0.weight"])
    assert torch.equal(enc.bn1.running_var, sd["bn1.running_var"])
    wrapped = tmp_path / "wrapped.pth"         # {"state_dict": {"module.<key>": ...}}
    torch.save({"state_dict": {f"module.{k}": v for k, v in sd.items()}}, wrapped)
    enc2 = ResnetEncoder(64)
    load_imagenet_weights(enc2, wrapped)
    assert torch.equal(enc2.conv1.weight, sd["conv1.weight"])
    assert "layer1.0.conv1.weight" in enc2.state_dict() and "fc.weight" not in enc2.state_dict()


def test_build_model_loads_imagenet_weights(tmp_path):
    path = tmp_path / "resnet18.pth"
    sd = _torchvision_resnet18_state_dict(seed=3)
    torch.save(sd, path)
    net = build_model(preset("tiny", {"encoder_width": 64, "imagenet_weights": str(path)}))
    assert torch.equal(net.encoder.layer4[1].conv2.weight, sd["layer4.1.conv2.weight"])
    fresh = build_model(preset("tiny", {"encoder_width": 64, "imagenet_weights": str(path)}),
                        load_weights=False)
    assert not torch.equal(fresh.encoder.conv1.weight, sd["conv1.weight"])


def test_imagenet_weights_errors(tmp_path):
    enc = ResnetEncoder(64)
    with pytest.raises(InputError, match="not found"):
        load_imagenet_weights(enc, tmp_path / "none.pth")
    garbage = tmp_path / "garbage.pth"
    garbage.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="not a readable torch state dict"):
        load_imagenet_weights(enc, garbage)
    notdict = tmp_path / "list.pth"
    torch.save([torch.zeros(1)], notdict)
    with pytest.raises(InputError, match="expected a state dict"):
        load_imagenet_weights(enc, notdict)
    other = tmp_path / "other.pth"
    torch.save({"conv1.weight": torch.zeros(64, 3, 7, 7)}, other)
    with pytest.raises(InputError, match="missing keys"):
        load_imagenet_weights(enc, other)
    full = tmp_path / "r18.pth"
    torch.save(_torchvision_resnet18_state_dict(), full)
    with pytest.raises(InputError, match="encoder_width=64"):
        load_imagenet_weights(ResnetEncoder(16), full)


# -- configuration -----------------------------------------------------------------------------
def test_presets_and_strict_overrides():
    d = preset("default")
    assert (d.width, d.height, d.min_depth, d.max_depth, d.lr) == (640, 192, 0.1, 100.0, 1e-4)
    assert d.decoder_channels == (16, 32, 64, 128, 256) and d.smoothness_weight == 1e-3
    t = preset("tiny", {"epochs": "3", "decoder_channels": "4,4,8,8,16", "flip": "false"})
    assert (t.epochs, t.decoder_channels, t.flip, t.width) == (3, (4, 4, 8, 8, 16), False, 128)
    with pytest.raises(InputError, match="unknown baseline preset"):
        preset("huge")
    with pytest.raises(InputError, match=r"unknown setting\(s\) \['epoch'\]"):
        preset("tiny", {"epoch": "3"})


@pytest.mark.parametrize("bad, match", [
    ({"width": 100}, "multiples of 32"),
    ({"height": 32}, "at least 64"),
    ({"min_depth": 5.0, "max_depth": 1.0}, "min_depth < max_depth"),
    ({"decoder_channels": (1, 2, 3)}, "decoder_channels"),
    ({"num_scales": 0}, "num_scales"),
    ({"epochs": 0}, "must be >= 1"),
    ({"lr": -1.0}, "lr > 0"),
])
def test_config_rejects_impossible_values(bad, match):
    with pytest.raises(InputError, match=match):
        BaselineConfig(**bad)
