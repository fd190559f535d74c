"""The ``onnx`` matcher against tiny torch stereo networks built and exported here.

Every contract style (padding with odd sizes, fixed size with resize, negative sign, flow channel,
stacked input, two stages) is checked against the same network run in torch on inputs prepared by
hand in this file, and on synthetic pairs with a known disparity.
"""
from __future__ import annotations

import json
import warnings

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")
ort = pytest.importorskip("onnxruntime")
import torch.nn as nn  # noqa: E402
import torch.nn.functional as F  # noqa: E402

from staticdepth.cli import main  # noqa: E402
from staticdepth.errors import InputError  # noqa: E402
from staticdepth.geometry.camera import Camera, StereoRig  # noqa: E402
from staticdepth.stereo.contracts import CONTRACTS, Contract, load_contract  # noqa: E402
from staticdepth.stereo.match import create_matcher  # noqa: E402
from staticdepth.stereo.matchers.onnx import OnnxMatcher  # noqa: E402
from staticdepth.stereo.pipeline import StereoConfig, StereoPipeline  # noqa: E402

D = 8            # disparities the toy networks search
MEAN = np.array([0.485, 0.456, 0.406], np.float32)
STD = np.array([0.229, 0.224, 0.225], np.float32)


def soft_argmin(left, right, beta=30.0):
    """Expected disparity (N, 1, H, W) of a winner-take-all cost volume over 0..D-1 px."""
    costs = [(left - right).abs().mean(1, keepdim=True)]
    for k in range(1, D):
        shifted = F.pad(right, (k, 0))[:, :, :, :-k]         # shifted[u] = right[u - k]
        costs.append((left - shifted).abs().mean(1, keepdim=True))
    p = torch.softmax(-beta * torch.cat(costs, 1), 1)
    return (p * torch.arange(D, dtype=torch.float32).view(1, D, 1, 1)).sum(1, keepdim=True)


class Disp(nn.Module):          # positive disparity (N, 1, H, W)
    def forward(self, left, right):
        return soft_argmin(left, right)


class NegFlow(nn.Module):       # a flow field (N, 2, H, W), x-flow = -disparity in channel 1
    def forward(self, left, right):
        d = soft_argmin(left, right)
        return torch.cat([torch.zeros_like(d), -d], 1)


class TwoOutputs(nn.Module):    # RAFT-Stereo style: (low-res flow, full-res -disparity)
    def forward(self, left, right):
        d = soft_argmin(left, right)
        return F.avg_pool2d(d, 2), -d


class Stacked(nn.Module):       # HITNet style: one tensor, left channels then right channels
    def __init__(self, c):
        super().__init__()
        self.c = c

    def forward(self, x):
        return soft_argmin(x[:, :self.c], x[:, self.c:])


class Linear(nn.Module):        # sensitive to colour order and value scale
    def forward(self, left, right):
        w = torch.tensor([1.0, 2.0, 4.0]).view(1, 3, 1, 1)
        return 0.5 + (w * left).sum(1, keepdim=True) - 0.5 * (w * right).sum(1, keepdim=True)


class Init(nn.Module):          # CREStereo init: (N, 2, h, w) with the disparity in channel 0
    def forward(self, left, right):
        d = soft_argmin(left, right)
        return torch.cat([d, torch.zeros_like(d)], 1)


class Next(nn.Module):          # CREStereo next: uses flow_init at half resolution
    def forward(self, left, right, flow_init):
        up = 2.0 * F.interpolate(flow_init, scale_factor=2.0, mode="nearest")
        d = 0.5 * soft_argmin(left, right) + 0.5 * up[:, :1]
        return torch.cat([d, up[:, 1:]], 1)


class Combined(nn.Module):      # PINTO's merged init+next model
    def forward(self, init_left, init_right, next_left, next_right):
        return Next()(next_left, next_right, Init()(init_left, init_right))


def export(net, path, shapes, names, dynamic=True, outputs=("output",)):
    args = tuple(torch.zeros(s) for s in shapes)
    axes = {n: {2: f"h{i}", 3: f"w{i}"} for i, n in enumerate(names)} if dynamic else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(net, args, str(path), input_names=list(names),
                          output_names=list(outputs), dynamic_axes=axes, opset_version=17,
                          dynamo=False)
    return str(path)


def texture(h, w, seed=0):
    rng = np.random.default_rng(seed)
    g = cv2.GaussianBlur(rng.uniform(0, 255, (h, w, 3)).astype(np.float32), (0, 0), 0.8)
    return np.clip(g, 0, 255).astype(np.uint8)


def shifted_pair(h, w, d, seed=0):
    """Left texture and the right view of a fronto-parallel plane at disparity ``d``."""
    left = texture(h, w, seed)
    return left, np.ascontiguousarray(np.roll(left, -d, axis=1))


def nchw(x):
    return torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32))


def pad(img, mult):
    h, w = img.shape[:2]
    return cv2.copyMakeBorder(img, 0, (-h) % mult, 0, (-w) % mult, cv2.BORDER_REPLICATE)


def in_range(ref):
    return np.where((ref > 0) & (ref <= D), ref, np.nan)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("onnx")
    lr = ("left", "right")
    return {
        "disp": export(Disp(), d / "disp.onnx", [(1, 3, 8, 8)] * 2, lr),
        "negflow": export(NegFlow(), d / "negflow.onnx", [(1, 3, 8, 8)] * 2, lr),
        "raft": export(TwoOutputs(), d / "raft.onnx", [(1, 3, 8, 8)] * 2, lr,
                       outputs=("flow_low", "flow_up")),
        "fixed": export(Disp(), d / "fixed.onnx", [(1, 3, 24, 32)] * 2, lr, dynamic=False),
        "stacked": export(Stacked(1), d / "stacked.onnx", [(1, 2, 8, 8)], ("input",)),
        "linear": export(Linear(), d / "linear.onnx", [(1, 3, 8, 8)] * 2, lr),
        "init": export(Init(), d / "init.onnx", [(1, 3, 8, 8)] * 2, lr),
        "next": export(Next(), d / "next.onnx", [(1, 3, 16, 16)] * 2 + [(1, 2, 8, 8)],
                       lr + ("flow_init",)),
        "combined": export(Combined(), d / "combined.onnx",
                           [(1, 3, 16, 24)] * 2 + [(1, 3, 32, 48)] * 2,
                           ("init_left", "init_right", "next_left", "next_right"),
                           dynamic=False, outputs=("next_output",)),
    }


def run(models, key, contract, size, **kw):
    return OnnxMatcher(num_disparities=D, image_size=size, model=models[key], contract=contract,
                       **kw)


def test_padding_multiple_with_odd_size_matches_torch_and_truth(models):
    left, right = shifted_pair(29, 37, 3)
    m = OnnxMatcher(num_disparities=D, image_size=(37, 29), model=models["disp"],
                    contract={"color": "rgb", "scale": "0-255", "pad_multiple": 8})
    assert m.net_hw == (32, 40)
    out = m.match(left, right)
    with torch.no_grad():
        ref = Disp()(nchw(pad(left, 8)), nchw(pad(right, 8)))[0, 0, :29, :37].numpy()
    np.testing.assert_allclose(out.disparity, in_range(ref), atol=1e-4)
    assert np.array_equal(out.valid, np.isfinite(out.disparity))
    assert np.median(out.disparity[:, D:]) == pytest.approx(3.0, abs=0.02)


def test_negative_sign_and_flow_channel(models):
    left, right = shifted_pair(20, 30, 2, seed=1)
    c = load_contract("raft-stereo", {"pad_multiple": 4, "output_index": 0, "channel": 1})
    m = OnnxMatcher(num_disparities=D, image_size=(30, 20), model=models["negflow"], contract=c)
    with torch.no_grad():
        ref = -NegFlow()(nchw(pad(left, 4)), nchw(pad(right, 4)))[0, 1, :20, :30].numpy()
    np.testing.assert_allclose(m.match(left, right).disparity, in_range(ref), atol=1e-4)
    # the shipped raft-stereo contract: last output (flow_up), channel 0, sign -1, pad 32
    r = OnnxMatcher(num_disparities=D, image_size=(30, 20), model=models["raft"],
                    contract="raft-stereo")
    assert r.net_hw == (32, 32)
    with torch.no_grad():
        ref = -TwoOutputs()(nchw(pad(left, 32)), nchw(pad(right, 32)))[1][0, 0, :20, :30].numpy()
    got = r.match(left, right).disparity
    np.testing.assert_allclose(got, in_range(ref), atol=1e-4)
    assert np.nanmedian(got[:, D:]) == pytest.approx(2.0, abs=0.02)


def test_fixed_input_size_resizes_and_rescales(models):
    left, right = shifted_pair(30, 40, 5, seed=2)
    m = OnnxMatcher(num_disparities=D, image_size=(40, 30), model=models["fixed"],
                    contract={"pad_multiple": 8})
    assert m.net_hw == (24, 32) and m.resize
    L = cv2.resize(left, (32, 24), interpolation=cv2.INTER_LINEAR)
    R = cv2.resize(right, (32, 24), interpolation=cv2.INTER_LINEAR)
    with torch.no_grad():
        small = Disp()(nchw(L), nchw(R))[0, 0].numpy()
    ref = cv2.resize(small, (40, 30), interpolation=cv2.INTER_LINEAR) * (40 / 32)
    np.testing.assert_allclose(m.match(left, right).disparity, in_range(ref), atol=1e-4)


def test_stacked_grey_input_zero_one(models):
    left, right = shifted_pair(16, 24, 2, seed=3)
    c = load_contract("hitnet", {"pad_multiple": 8})
    m = OnnxMatcher(num_disparities=D, image_size=(24, 16), model=models["stacked"], contract=c)
    grey = [cv2.cvtColor(x, cv2.COLOR_RGB2GRAY).astype(np.float32)[None, None] / 255
            for x in (left, right)]
    with torch.no_grad():
        ref = Stacked(1)(torch.from_numpy(np.concatenate(grey, 1)))[0, 0].numpy()
    np.testing.assert_allclose(m.match(left, right).disparity, in_range(ref), atol=1e-4)


@pytest.mark.parametrize("color,scale", [("rgb", "0-255"), ("bgr", "0-1"), ("bgr", "imagenet"),
                                         ("rgb", "imagenet")])
def test_colour_order_and_value_scale(models, color, scale):
    rng = np.random.default_rng(4)
    left, right = (rng.integers(0, 256, (12, 16, 3), dtype=np.uint8) for _ in range(2))
    m = OnnxMatcher(num_disparities=10_000, image_size=(16, 12), model=models["linear"],
                    contract={"color": color, "scale": scale, "pad_multiple": 4})

    def prep(img):
        x = img.astype(np.float32)
        if color == "bgr":
            x = x[..., ::-1]
        if scale == "0-1":
            x = x / 255
        elif scale == "imagenet":
            mean, std = (MEAN[::-1], STD[::-1]) if color == "bgr" else (MEAN, STD)
            x = (x / 255 - mean) / std
        return nchw(x)

    with torch.no_grad():
        ref = Linear()(prep(left), prep(right))[0, 0].numpy()
    got = m.match(left, right).disparity
    expect = np.where((ref > 0) & (ref <= 10_000), ref, np.nan)
    np.testing.assert_allclose(got, expect, rtol=1e-5, atol=1e-3)
    assert np.isnan(got).any() and np.isfinite(got).any()    # both signs: the range check bites


def test_two_stage_init_next(models):
    left, right = shifted_pair(30, 44, 4, seed=5)
    m = OnnxMatcher(num_disparities=D, image_size=(44, 30), model=models["next"],
                    init_model=models["init"], contract=load_contract(
                        "crestereo-init-next", {"pad_multiple": 8, "color": "rgb"}))
    assert m.net_hw == (32, 48) and m.coarse_hw == (16, 24)
    L, R = pad(left, 16), pad(right, 16)
    Lh, Rh = (cv2.resize(x, (24, 16), interpolation=cv2.INTER_LINEAR) for x in (L, R))
    with torch.no_grad():
        coarse = Init()(nchw(Lh), nchw(Rh))
        ref = Next()(nchw(L), nchw(R), coarse)[0, 0, :30, :44].numpy()
    got = m.match(left, right).disparity
    np.testing.assert_allclose(got, in_range(ref), atol=1e-4)
    assert np.nanmedian(got[:, D:-D]) == pytest.approx(4.0, abs=0.1)


def test_two_stage_combined_fixed_size_bgr(models):
    left, right = shifted_pair(30, 40, 4, seed=6)
    m = OnnxMatcher(num_disparities=D, image_size=(40, 30), model=models["combined"])  # guessed
    assert m.contract.name == "crestereo-combined" and m.contract.color == "bgr"
    assert m.net_hw == (32, 48) and m.coarse_hw == (16, 24)
    L, R = (cv2.resize(x, (48, 32), interpolation=cv2.INTER_LINEAR)[..., ::-1]
            for x in (left, right))
    Lh, Rh = (cv2.resize(np.ascontiguousarray(x), (24, 16), interpolation=cv2.INTER_LINEAR)
              for x in (L, R))
    with torch.no_grad():
        out = Combined()(nchw(Lh), nchw(Rh), nchw(L), nchw(R))[0, 0].numpy()
    ref = cv2.resize(out, (40, 30), interpolation=cv2.INTER_LINEAR) * (40 / 48)
    np.testing.assert_allclose(m.match(left, right).disparity, in_range(ref), atol=1e-4)


def test_left_right_check_removes_occlusions(models):
    h, w, a, b, d_bg, d_fg = 24, 48, 22, 34, 2, 6
    bg, fg = texture(h, w, 7), texture(h, w, 8)
    left = bg.copy()
    left[:, a:b] = fg[:, a:b]
    right = np.roll(bg, -d_bg, axis=1)
    right[:, a - d_fg:b - d_fg] = fg[:, a:b]
    m = OnnxMatcher(num_disparities=D, image_size=(w, h), model=models["disp"],
                    contract={"pad_multiple": 8}, lr_check=True, lr_px=0.5)
    out = m.match(left, right)
    occluded = out.valid[:, a - (d_fg - d_bg):a]           # background hidden in the right view
    clean = np.zeros((h, w), bool)
    clean[:, D:a - D] = True
    assert occluded.mean() < 0.3
    assert out.valid[clean].mean() > 0.95
    assert np.nanmax(np.abs(out.disparity[clean] - d_bg)) < 0.5
    # dense mode keeps the in-range values the check rejected, ``valid`` still says which
    dense = OnnxMatcher(num_disparities=D, image_size=(w, h), model=models["disp"], dense=True,
                        contract={"pad_multiple": 8}, lr_check=True, lr_px=0.5).match(left, right)
    assert np.array_equal(dense.valid, out.valid)
    assert np.isfinite(dense.disparity).sum() > np.isfinite(out.disparity).sum()


def test_pipeline_and_registry(models, tmp_path):
    left, right = shifted_pair(29, 37, 3, seed=9)
    cam = Camera.from_intrinsics(50.0, 50.0, 18.0, 14.0, 37, 29)
    rig = StereoRig.rectified(cam, 0.2)
    options = {"model": models["raft"], "contract": "raft-stereo"}
    pipe = StereoPipeline(rig, StereoConfig(matcher="onnx", num_disparities=16, max_depth_m=1e6,
                                            options=options))
    res = pipe.process(left, right)
    inner = res.disparity[:, D:]
    assert np.nanmedian(inner) == pytest.approx(3.0, abs=0.02)
    ok = res.disparity > 0.01
    np.testing.assert_allclose(res.depth[ok], 50.0 * 0.2 / res.disparity[ok], rtol=1e-5)
    assert ok.sum() > 0.9 * ok.size
    assert pipe.provenance()["matcher"]["contract"]["name"] == "raft-stereo"
    assert isinstance(create_matcher("onnx", num_disparities=16, image_size=(37, 29),
                                     options=options), OnnxMatcher)
    # the CLI on one rectified pair
    lp, rp, out = tmp_path / "l.png", tmp_path / "r.png", tmp_path / "d.npy"
    cv2.imwrite(str(lp), left[..., ::-1])
    cv2.imwrite(str(rp), right[..., ::-1])
    rc = main(["stereo", "--rectified", "--left", str(lp), "--right", str(rp), "--max-disparity",
               "16", "--matcher", "onnx", "--model", models["raft"], "--contract", "raft-stereo",
               "--disparity-out", str(out)])
    assert rc == 0
    np.testing.assert_allclose(np.load(out), res.disparity, atol=1e-4, equal_nan=True)


def test_contract_from_json_file(models, tmp_path):
    path = tmp_path / "mine.json"
    path.write_text(json.dumps({"color": "rgb", "pad_multiple": 4, "output": "output",
                                "channel": 1, "sign": -1}))
    left, right = shifted_pair(20, 30, 2, seed=10)
    m = OnnxMatcher(num_disparities=D, image_size=(30, 20), model=models["negflow"],
                    contract=str(path))
    assert m.contract.name == "mine"
    assert np.nanmedian(m.match(left, right).disparity[:, D:]) == pytest.approx(2.0, abs=0.02)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"colour": "rgb"}))
    with pytest.raises(InputError, match="colour") as e:
        load_contract(str(bad))
    assert str(bad) in str(e.value)


def test_shipped_contracts_are_consistent():
    assert set(CONTRACTS) >= {"crestereo", "crestereo-combined", "crestereo-init-next", "hitnet",
                              "raft-stereo"}
    assert CONTRACTS["crestereo-combined"].two_stage and not CONTRACTS["crestereo"].two_stage
    assert CONTRACTS["raft-stereo"].sign == -1.0
    assert CONTRACTS["hitnet"].channels == 1


def test_errors(models, tmp_path):
    size = (16, 12)
    with pytest.raises(InputError, match="not found") as e:
        OnnxMatcher(num_disparities=D, image_size=size, model=tmp_path / "none.onnx")
    assert "none.onnx" in str(e.value)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(InputError, match="cannot load") as e:
        OnnxMatcher(num_disparities=D, image_size=size, model=junk)
    assert "junk.onnx" in str(e.value)
    with pytest.raises(InputError, match="unknown ONNX contract"):
        run(models, "disp", "crestereo-xl", size)
    with pytest.raises(InputError, match=r"feeds the input\(s\) \['input'\]") as e:
        run(models, "disp", "hitnet", size)
    assert models["disp"] in str(e.value)
    with pytest.raises(InputError, match="does not feed") as e:
        run(models, "next", "crestereo", size)
    with pytest.raises(InputError, match="init"):
        run(models, "next", "crestereo-init-next", size)
    with pytest.raises(InputError, match="takes no init_model"):
        run(models, "disp", "crestereo", size, init_model=models["init"])
    with pytest.raises(InputError, match="unknown onnx matcher option"):
        run(models, "disp", "crestereo", size, stride=2)
    with pytest.raises(InputError, match="reads the output 'flow'"):
        run(models, "disp", "crestereo", size, output="flow")
    with pytest.raises(InputError, match="output number 3"):
        run(models, "disp", "crestereo", size, output_index=3)
    with pytest.raises(InputError, match="channel 2"):
        run(models, "negflow", "crestereo", size, channel=2).match(
            *shifted_pair(12, 16, 1))
    with pytest.raises(InputError, match="color must be one of"):
        Contract(color="yuv")
    with pytest.raises(InputError, match="both coarse"):
        Contract(coarse_left_input="a")
    with pytest.raises(InputError, match="needs a model"):
        OnnxMatcher(num_disparities=D, image_size=size)
    with pytest.raises(InputError, match="built for 16x12"):
        run(models, "disp", "crestereo", size).match(*shifted_pair(10, 16, 1))
    with pytest.raises(InputError, match="unknown device"):
        run(models, "disp", "crestereo", size, device="tpu")
    if "CUDAExecutionProvider" in ort.get_available_providers():
        assert run(models, "disp", "crestereo", size, device="cuda").session.get_providers()[0] \
            == "CUDAExecutionProvider"
    else:
        with pytest.raises(InputError, match="no CUDA provider"):
            run(models, "disp", "crestereo", size, device="cuda")
    assert main(["stereo", "--rectified", "--left", "x.png", "--right", "y.png",
                 "--max-disparity", "16", "--matcher", "onnx", "--disparity-out", "d.npy"]) == 2
