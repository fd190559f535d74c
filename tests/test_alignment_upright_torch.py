"""The exportable upright alignment (geometry/alignment_upright_torch.py) against the numpy one
(geometry/alignment_upright.py), on a frame of the independent generator (tests/indep_scenes.py).

The prediction is the frame's true depth through a MiDaS-like inverse-depth scale and shift, with
every structure (facades, walls, poles, crates) 25-35% too near and multiplicative noise: the
upright mode re-anchors a third of the image, so the march, the walk to the foot, the recession
test and the row fill all decide something. Measured (i1, 320x160): ONNX vs numpy max relative
difference 3e-5, max absolute 1.3e-3 camera heights on depths up to ~50 (float32 output).
The colour foot (``image=``) on a closed-form crate in front of a wall and on i1 with its rendered
image (adapt's defaults: 2453 pixels moved by the rule; eager twin vs numpy max relative
difference 3.5e-7; i2-i4: 682-1824 pixels, <= 1e-6)."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from staticdepth.geometry.alignment import align_depth
from staticdepth.geometry.alignment_upright_torch import UprightAlignment, follow

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")   # the ONNX exporter's


@pytest.fixture(scope="module")
def frame():
    from staticdepth.evaluate import region_masks
    from tests.indep_scenes import SCENES, Scene

    spec = SCENES[0]
    sc = Scene(spec, 320, 160)
    f = sc.render(3)
    gt, K = f["depth"], sc.camera.K
    t = math.radians(spec.pitch_deg)
    n = np.array([0.0, math.cos(t), math.sin(t)])
    reg = region_masks(gt, f["instances"], f["agents"], K, (n, spec.height_m), 80.0)
    rng = np.random.default_rng(0)
    inv = 2.0 / np.where(np.isfinite(gt), gt, 80.0) + 0.03
    inv[reg["structures"]] *= rng.uniform(1.25, 1.35)
    inv *= np.exp(rng.normal(0, 0.02, inv.shape))
    G = reg["ground"] & (gt < 14)
    return (1 / inv).astype(np.float32), K, n, G, reg


@pytest.fixture(scope="module")
def flat_frame(frame):
    """The frame with its ground 8-14 m flat (it does not recede: a network that fails on the
    view, as the U-Net of bench_gains), so that the walked-region rule has ground to take."""
    Z, K, n, G, reg = frame
    from tests.indep_scenes import SCENES, Scene

    gt = Scene(SCENES[0], 320, 160).render(3)["depth"]
    Zf = Z.copy()
    band = reg["ground"] & (gt >= 8) & (gt < 14)
    Zf[band] = np.median(Z[reg["ground"] & (np.abs(gt - 8) < 0.3)])
    return Zf, K, n, G, reg


def _rel(a, b):
    return np.abs(a - b) / b


@pytest.mark.parametrize("kw", [{}, {"shape": "vertical"}, {"recede": None},
                                {"fill": False, "max_pull": 2.0, "contact_range": 1.2,
                                 "recede_push": 1.5},
                                {"fill": True, "max_pull": 1.5, "contact_range": None}])
def test_torch_upright_matches_numpy(frame, kw):
    Z, K, n, G, reg = frame
    ref = align_depth(Z, K, n, 1.0, G, mode="upright", **kw).depth
    ground = align_depth(Z, K, n, 1.0, G, mode="ground").depth
    assert np.mean(_rel(ref, ground) > 1e-3) > 0.1           # upright did change the frame
    out = UprightAlignment(K, 320, 160, n, 1.0, G, **kw)(torch.from_numpy(Z)).numpy()
    assert out.dtype == np.float32 and out.shape == Z.shape
    assert _rel(out, ref).max() < 1e-5, _rel(out, ref).max()


def _onnx_session(mod, Z, tmp_path):
    """The module traced on the frame ``Z``, exported to ONNX and opened in onnxruntime."""
    import onnxruntime as ort

    tmp_path.mkdir(parents=True, exist_ok=True)
    path = str(tmp_path / "u.onnx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(mod, (torch.from_numpy(Z),), path, input_names=["z"], opset_version=17,
                          dynamo=False)
    return ort.InferenceSession(path, providers=["CPUExecutionProvider"])


def test_upright_exports_to_onnx(frame, tmp_path):
    from staticdepth.geometry.alignment_torch import alignment_module

    Z, K, n, G, _ = frame
    mod = alignment_module("upright", K, 320, 160, n, 1.0, G, snap_rel=0.1, jump_rel=0.08,
                           plane_bound=True)      # adapt's default: the plane's bound too
    assert isinstance(mod, UprightAlignment)
    sess = _onnx_session(mod, Z, tmp_path)
    for s_f, t_f in [(1.0, 0.0), (3.0, 0.02)]:             # each frame its own scale and shift
        Zf = (1.0 / (s_f / Z + t_f)).astype(np.float32)
        ref = align_depth(Zf, K, n, 1.0, G, mode="upright", plane_bound=True).depth
        got = sess.run(None, {"z": Zf})[0]
        assert _rel(got, ref).max() < 1e-4 and np.abs(got - ref).max() < 5e-3, (
            _rel(got, ref).max(), np.abs(got - ref).max())


@pytest.mark.parametrize("kw", [{"walked_ratio": 1.3},
                                {"walked_ratio": 1.1, "max_pull": 2.0, "contact_range": 2.0,
                                 "recede_push": 2.0, "fill": False}])
def test_torch_upright_walked_rule_matches_numpy(flat_frame, kw):
    Z, K, n, G, reg = flat_frame
    ref = align_depth(Z, K, n, 1.0, G, mode="upright", **kw).depth
    off = align_depth(Z, K, n, 1.0, G, mode="upright", **{**kw, "walked_ratio": np.inf}).depth
    assert np.mean(_rel(ref, off)[G] > 1e-3) > 0.1        # the rule did change the walked region
    out = UprightAlignment(K, 320, 160, n, 1.0, G, **kw)(torch.from_numpy(Z)).numpy()
    assert _rel(out, ref).max() < 1e-5, _rel(out, ref).max()


def test_pointer_doubling_reaches_each_chains_end():
    # chains 0 -> 1 -> 2 -> 3 (end), 4 (end), 5 -> 4, 6 -> 5
    link = torch.tensor([1, 2, 3, 3, 4, 4, 5])
    assert follow(link, 2).tolist() == [3, 3, 3, 3, 4, 4, 4]
    assert follow(link, 1).tolist() == [2, 3, 3, 3, 4, 4, 4]   # too few doublings: not there


def test_torch_upright_plane_bound_matches_numpy(frame):
    """align.plane_bound in the graph: the structures 3x too far (beyond what max_pull lets a
    contact pull back) are bounded by the plane's depth along their rays, as in numpy."""
    Z, K, n, G, reg = frame
    Zf = Z.copy()
    Zf[reg["structures"]] *= 3.0
    kw = {"max_pull": 2.0, "contact_range": 2.0, "recede_push": 2.0, "walked_ratio": 1.2,
          "fill": False}
    ref = align_depth(Zf, K, n, 1.0, G, mode="upright", plane_bound=True, **kw).depth
    off = align_depth(Zf, K, n, 1.0, G, mode="upright", **kw).depth
    assert np.mean(_rel(ref, off) > 1e-3) > 0.01           # the bound did bind
    out = UprightAlignment(K, 320, 160, n, 1.0, G, plane_bound=True, **kw)(
        torch.from_numpy(Zf)).numpy()
    assert _rel(out, ref).max() < 1e-5, _rel(out, ref).max()


def test_torch_upright_second_pass_matches_numpy(frame):
    """An aligned map aligned again (ft-align's case, tests/test_align_idempotent.py), with
    adapt's defaults: the runs that walk on over their snapped lowest pixels to the contact they
    stand on (keep_rel) are the same in the graph."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    Z, K, n, G, reg = frame
    kw = upright_options(build_config({}).align)
    once = align_depth(Z, K, n, 1.0, G, mode="upright", **kw).depth
    ref = align_depth(once, K, n, 1.0, G, mode="upright", **kw).depth
    off = align_depth(once, K, n, 1.0, G, mode="upright", keep_rel=None, **kw).depth
    assert np.mean(_rel(ref, off) > 1e-3) > 0.01           # the walk on decided something
    out = UprightAlignment(K, 320, 160, n, 1.0, G, **kw)(torch.from_numpy(once)).numpy()
    assert _rel(out, ref).max() < 1e-5, _rel(out, ref).max()


def test_upright_onnx_walks_any_number_of_contacts(frame, tmp_path):
    """Only the contacts walk (a NonZero index list in the graph): traced on one frame, the ONNX
    graph follows frames with other contacts, here an aligned map aligned again (adapt's
    defaults: the keep_rel walk on decides) and another frame of the scene, as numpy does."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config
    from tests.indep_scenes import SCENES, Scene

    Z, K, n, G, reg = frame
    kw = upright_options(build_config({}).align)
    mod = UprightAlignment(K, 320, 160, n, 1.0, G, **kw)
    sess = _onnx_session(mod, Z, tmp_path)
    once = align_depth(Z, K, n, 1.0, G, mode="upright", **kw).depth
    gt = Scene(SCENES[0], 320, 160).render(9)["depth"]
    other = (1.0 / (2.0 / np.where(np.isfinite(gt), gt, 80.0) + 0.03)).astype(np.float32)
    counts = set()
    for Zf in (Z, once, other):
        ref = align_depth(Zf, K, n, 1.0, G, mode="upright", **kw)
        counts.add(int((ref.depth != align_depth(Zf, K, n, 1.0, G, mode="ground").depth).sum()))
        got = sess.run(None, {"z": Zf})[0]
        with torch.no_grad():
            eager = mod(torch.from_numpy(Zf)).numpy()
        assert _rel(got, eager).max() < 1e-4, _rel(got, eager).max()     # float32 rounding
        assert _rel(got, ref.depth).max() < 1e-4, _rel(got, ref.depth).max()
    assert len(counts) == 3                     # three frames with different runs re-anchored


def test_upright_onnx_follows_a_frame_without_contacts(frame, tmp_path):
    """A frame whose every pixel is the plane's ground (a steep 45 degree view: no horizon, no
    structure) leaves the NonZero index list empty: the graph traced on a frame with a wall, and
    the one traced on the empty frame, both give numpy's result on either frame."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config
    from staticdepth.geometry.projection import ray_grid

    _, K, _, _, _ = frame
    t = math.radians(45.0)
    n = np.array([0.0, math.cos(t), math.sin(t)])
    q = ray_grid(K, 320, 160) @ n                        # the plane's inverse depth (d = 1)
    flat = (1.0 / q).astype(np.float32)
    wall = flat.copy()
    wall[40:100, 100:140] = flat[100, 120]               # a wall standing on row 100
    G = flat < 3.0
    kw = upright_options(build_config({}).align)
    mod = UprightAlignment(K, 320, 160, n, 1.0, G, **kw)
    refs = [align_depth(Zf, K, n, 1.0, G, mode="upright", **kw).depth for Zf in (flat, wall)]
    ground = [align_depth(Zf, K, n, 1.0, G, mode="ground").depth for Zf in (flat, wall)]
    assert (refs[0] == ground[0]).all()                  # no run re-anchored on the flat frame
    assert (refs[1] != ground[1]).sum() > 1000           # the wall's run is
    for i, traced in enumerate((wall, flat)):
        sess = _onnx_session(mod, traced, tmp_path / str(i))
        for Zf, ref in zip((flat, wall), refs):
            got = sess.run(None, {"z": Zf})[0]
            assert _rel(got, ref).max() < 1e-4, (i, _rel(got, ref).max())


# -- the colour foot (image=: geometry/colour_foot_torch.py) -------------------------------------
def _adapt_upright():
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    return upright_options(build_config({}).align)          # adapt's defaults, colour foot's too


def _crate_scene():
    """A crate 5 m ahead (2 m tall, 1.2 m wide, 1.5 m right) in front of a wall 10 m ahead, seen
    by a camera 3 m up looking down 25 deg (tests/billboard_scene.py, closed form): the network
    sees the scene without the crate, so the crate's upper part carries the wall's depth and its
    run takes the wall's contact (2x too far); the image shows the crate's own colour down to its
    foot (tests/test_align_near.py's post, here a crate in RGB)."""
    from billboard_scene import billboard_camera

    W, H = 160, 100
    K, n, z_ground, billboard = billboard_camera(3.0, 25.0, W, H, 100.0)
    z_wall, wall = billboard(10.0, 8.0, 6.0)
    z_crate, wide = billboard(5.0, 8.0, 2.0)
    crate = wide & (np.abs((np.arange(W)[None, :] - K[0, 2]) / 100.0 * z_crate - 1.5) < 0.6)
    behind = np.where(wall, z_wall, z_ground)
    depth = np.where(crate, z_crate, behind)
    net = (np.where(np.isfinite(behind), behind, 200.0) * 0.5).astype(np.float32)
    ground = ~wall & ~crate & (z_ground < 60)
    stripes = 0.25 + 0.1 * ((np.arange(H)[:, None] // 4) % 2)
    img = np.repeat(np.where(wall, stripes, 0.6)[..., None], 3, -1)
    img[crate] = [0.8, 0.5, 0.2]
    return K, n, depth, net, ground, crate, img


def test_torch_colour_foot_matches_numpy_on_a_crate(tmp_path):
    K, n, depth, net, ground, crate, img = _crate_scene()
    kw = _adapt_upright()
    info: dict = {}
    ref = align_depth(net, K, n, 3.0, ground, mode="upright", image=img, info=info, **kw).depth
    off = align_depth(net, K, n, 3.0, ground, mode="upright", **kw).depth
    up = crate & info["traced"]
    assert up.sum() > 100 and (info["colour_foot"] & crate).sum() > 100    # the rule fired
    assert np.median(off[up] / depth[up]) > 1.9                   # the wall's contact: 10 / 5
    assert abs(np.median(ref[up] / depth[up]) - 1) < 0.03         # its own foot
    mod = UprightAlignment(K, 160, 100, n, 3.0, ground, image=img, **kw)
    out = mod(torch.from_numpy(net)).numpy()
    assert _rel(out, ref).max() < 1e-5, _rel(out, ref).max()
    sess = _onnx_session(mod, net, tmp_path)
    for s_f, t_f in [(1.0, 0.0), (2.0, 0.01)]:             # each frame its own scale and shift
        Zf = (1.0 / (s_f / net + t_f)).astype(np.float32)
        ref = align_depth(Zf, K, n, 3.0, ground, mode="upright", image=img, **kw).depth
        got = sess.run(None, {"z": Zf})[0]
        assert _rel(got, ref).max() < 1e-4, _rel(got, ref).max()


def test_torch_colour_foot_matches_numpy_on_an_indep_scene(frame, tmp_path):
    """i1 (structures 25-35% too near) with its rendered image: the rule moves thousands of
    pixels; the graph, eager and exported, moves the same."""
    from tests.indep_scenes import SCENES, Scene

    Z, K, n, G, reg = frame
    img = Scene(SCENES[0], 320, 160).render(3)["left"] / 255.0
    kw = _adapt_upright()
    ref = align_depth(Z, K, n, 1.0, G, mode="upright", image=img, **kw).depth
    off = align_depth(Z, K, n, 1.0, G, mode="upright", **kw).depth
    assert (ref != off).sum() > 1000
    mod = UprightAlignment(K, 320, 160, n, 1.0, G, image=img, **kw)
    out = mod(torch.from_numpy(Z)).numpy()
    assert _rel(out, ref).max() < 1e-5, _rel(out, ref).max()
    got = _onnx_session(mod, Z, tmp_path).run(None, {"z": Z})[0]
    assert _rel(got, ref).max() < 1e-4, _rel(got, ref).max()


def test_colour_bins_are_ground_coloureds():
    """The graph's histogram over the constant bins gives ground_coloured's answer (at the rule's
    FOOT_LEVELS) for any ground mask and share."""
    from staticdepth.geometry.alignment_upright import FOOT_LEVELS
    from staticdepth.geometry.alignment_vertical import ground_coloured
    from staticdepth.geometry.colour_foot_torch import colour_bins

    rng = np.random.default_rng(1)
    img = rng.uniform(0, 1, (30, 40, 3)) ** 3                 # many bins, unevenly filled
    bins, k = colour_bins(img)
    assert 20 < k <= FOOT_LEVELS ** 3 and bins.min() == 0 and bins.max() == k - 1
    for share in (0.001, 0.01, 0.03):
        g = rng.random((30, 40)) < 0.3
        hist = np.bincount(bins[g.ravel()], minlength=k)
        mine = (hist[bins] >= share * g.sum()).reshape(30, 40)
        assert np.array_equal(mine, ground_coloured(img, g, share, FOOT_LEVELS))
        assert 0 < mine.sum() < mine.size


def test_torch_colour_foot_leaves_the_walked_grounds_colour(monkeypatch):
    """tests/test_align_near.py's smooth road: a band the network keeps flat is traced like a
    wall and its colour runs on to a lane marking; its colour is the walked ground's (the frame's
    histogram in the graph), so neither version pulls it; with that test off, the lawn test
    (the road's colour comes back below the marking, on the frame's snapped pixels) keeps the
    band's median in both; with both off both pull it. The twin matches numpy in each case."""
    import staticdepth.geometry.alignment_upright as au
    import staticdepth.geometry.alignment_vertical as av
    import staticdepth.geometry.colour_foot_torch as cft
    from billboard_scene import billboard_camera

    K, n, z_ground, _ = billboard_camera(3.0, 25.0, 160, 100, 100.0)
    rows = np.arange(100)[:, None] * np.ones((1, 160))
    finite = np.isfinite(z_ground)
    band = finite & (rows >= 40) & (rows < 50)
    net = np.where(finite, z_ground, 200.0) * 0.5
    net = np.where(band, net[49:50, :], net).astype(np.float32)
    img = np.where(~finite, 0.8, np.where(finite & (rows == 58), 0.95, 0.6))
    ground = finite & (z_ground < 60)
    kw = _adapt_upright()
    off = align_depth(net, K, n, 3.0, ground, mode="upright", **kw).depth
    # 2.0: no pixel is ground-coloured; a RESUME_DIFF of -1: no colour ever comes back
    for share, resume in ((au.FOOT_GROUND_SHARE, av.RESUME_DIFF), (2.0, av.RESUME_DIFF),
                          (2.0, -1.0)):
        monkeypatch.setattr(au, "FOOT_GROUND_SHARE", share)
        monkeypatch.setattr(cft, "FOOT_GROUND_SHARE", share)
        monkeypatch.setattr(av, "RESUME_DIFF", resume)
        ref = align_depth(net, K, n, 3.0, ground, mode="upright", image=img, **kw).depth
        assert (np.median(ref[band] / off[band]) < 0.95) == (resume < 0)
        out = UprightAlignment(K, 160, 100, n, 3.0, ground, image=img, **kw)(
            torch.from_numpy(net)).numpy()
        assert _rel(out, ref).max() < 1e-5, (share, _rel(out, ref).max())


def test_torch_colour_foot_keeps_a_lawn_on_the_plane(tmp_path):
    """tests/test_align_near.py's lawn with a paper on it: the lawn test is static (the image's
    runs) and reads the frame's snapped pixels in the graph; the twin and its ONNX export match
    numpy there."""
    from test_align_near import _lawn_scene

    K, n, z, net, walked, lawn, img = _lawn_scene()
    kw = _adapt_upright()
    info: dict = {}
    ref = align_depth(net, K, n, 3.0, walked, mode="upright", image=img, info=info, **kw).depth
    assert info["colour_foot"].any() and not (info["colour_foot"] & info["snapped"] & lawn).any()
    mod = UprightAlignment(K, 160, 100, n, 3.0, walked, image=img, **kw)
    out = mod(torch.from_numpy(net)).numpy()
    assert _rel(out, ref).max() < 1e-5, _rel(out, ref).max()
    got = _onnx_session(mod, net, tmp_path).run(None, {"z": net})[0]
    assert _rel(got, ref).max() < 1e-4, _rel(got, ref).max()
