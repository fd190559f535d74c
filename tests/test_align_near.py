"""``upright`` with ``image`` (the colour foot, benchmarks/bench_near_structures.py): a thin post
the network does not resolve, in front of a far wall.

The network sees what stands behind the post: the ground behind its lower part (which then
recedes like the ground and is taken for it) and the far wall behind its upper part, so that part's
run walks down the wall to the wall's foot and stands 15 m away instead of 6 m. The image shows
the post's own colour down to its foot: with the colour foot, the traced part stands on the
vertical through that foot. The camera looks down 25 deg, so the post, off the optical axis, slants
across the image's columns as the vertical does. A closed-form scene (tests/billboard_scene.py);
the image is drawn from its masks."""
from __future__ import annotations

import types

import numpy as np

from billboard_scene import billboard_camera
from staticdepth.geometry.alignment import align_upright

W, H, F = 160, 100, 100.0
CAM = 3.0


def _scene(post_grey=0.9, mortar=None, post_z=6.0, post_h=2.5, post_x=3.0):
    """True depth, the network's (the scene without the post, half the scale), the ground mask,
    the masks of the far wall and the post, and the image: a wall 15 m away (|lateral| < 8 m,
    6 m tall), a post 6 m away, 3 m to the right, 0.1 m either side, 2.5 m tall; luminance
    ground 0.6, wall 0.25 with stripes of 0.1 every 4 rows (under the rule's 0.2), post
    ``post_grey``; ``mortar``: the ground's every 7th row (from row 3) that luminance; ``post_z``:
    the post's distance (m), ``post_h`` its height, ``post_x`` its lateral offset."""
    K, n, z_ground, billboard = billboard_camera(CAM, 25.0, W, H, F)
    z_far, far = billboard(15.0, 8.0, 6.0)
    z_post, wide = billboard(post_z, 8.0, post_h)
    u = np.arange(W)[None, :]
    lateral = (u - K[0, 2]) / F * z_post
    post = wide & (np.abs(lateral - post_x) < 0.1)
    behind = np.where(far, z_far, z_ground)
    depth = np.where(post, z_post, behind)
    depth[~np.isfinite(depth)] = 200.0
    net = np.where(np.isfinite(behind), behind, 200.0) * 0.5
    ground = ~far & ~post & (z_ground < 60)
    rows = np.arange(H)[:, None]
    img = np.where(far, 0.25 + 0.1 * ((rows // 4) % 2), 0.6)
    if mortar is not None:
        img = np.where(~far & (rows % 7 == 3), mortar, img)
    img = np.where(post, post_grey, img)
    return K, n, depth.astype(np.float32), net.astype(np.float32), ground, far & ~post, post, img


def _aligned(pred, K, n, ground, **kw):
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    opts = {**upright_options(build_config({}).align), **kw}      # adapt's defaults
    return align_upright(pred, K, n, CAM, ground, **opts).depth


def test_the_scene_is_what_the_test_needs():
    K, n, Z, net, ground, far, post = _scene()[:7]
    assert post.sum() > 80 and far.sum() > 2000
    # the post slants across the columns: its lowest and highest pixels 5+ columns apart
    v, u = np.nonzero(post)
    assert abs(u[v == v.max()].mean() - u[v == v.min()].mean()) > 5
    # its upper part stands in front of the wall, its lower part in front of the ground
    assert (post & np.roll(far, 2, axis=1)).sum() > 20 and (post & np.roll(ground, 2, 1)).sum() > 20


def test_a_post_the_network_does_not_see_stands_on_its_colour_foot():
    K, n, Z, net, ground, far, post, img = _scene()
    info: dict = {}
    off = _aligned(net, K, n, ground, info=info)
    on = _aligned(net, K, n, ground, image=img)
    upper = post & info["traced"]
    assert upper.sum() > 20
    # without the rule the post's upper part takes the far wall's contact: 15 / 6 = 2.5 x too far
    assert np.median(off[upper] / Z[upper]) > 2.3
    # with it, the vertical through the post's foot: exact up to the pixel grid
    assert np.median(np.abs(on[upper] / Z[upper] - 1)) < 0.03
    # the far wall's colour ends at its own foot: where its trace reached that foot it does not
    # move; along its slanted side edges the trace, one column per row, fell off the wall onto
    # the ground above the wall's foot (pushed 1.1-2.1 x): those stand on their foot now
    err_off, err_on = np.abs(off[far] / Z[far] - 1), np.abs(on[far] / Z[far] - 1)
    moved = on[far] != off[far]
    assert 0 < moved.mean() < 0.05 and np.all(err_off[moved] > 0.1)
    assert np.all(err_on[moved] < 0.03) and np.median(err_on) < 0.03


def test_a_post_of_the_grounds_colour_has_no_foot():
    """Its colour run goes on down the ground to the image's bottom: no foot, it stays where
    the trace put it (2.5 x too far: the rule needs the image to show the foot)."""
    K, n, Z, net, ground, far, post, img = _scene(post_grey=0.6)
    off = _aligned(net, K, n, ground)
    on = _aligned(net, K, n, ground, image=img)
    assert np.array_equal(on[post], off[post])
    assert np.median(on[post & (off / Z > 2)] / Z[post & (off / Z > 2)]) > 2.3


def test_a_post_near_a_ground_colour_stands_on_its_foot(monkeypatch):
    """A dark post (0.36) on a pavement (0.6) with dark mortar lines (0.30, a seventh of its
    rows): the post shares the mortar's colour bin at 8 levels per channel, so that test took it
    for the ground's colour and left it 2.5 x too far (the independent scenes' grey poles and
    walls on grey pavements, docs/gains.md fourteenth round); at ``FOOT_LEVELS`` (16) its bin is
    its own and it stands on its foot."""
    import staticdepth.geometry.alignment_upright as au
    from staticdepth.geometry.alignment_vertical import ground_coloured

    K, n, Z, net, ground, far, post, img = _scene(post_grey=0.36, mortar=0.30)
    info: dict = {}
    off = _aligned(net, K, n, ground, info=info)
    upper = post & info["traced"]
    assert upper.sum() > 20 and np.median(off[upper] / Z[upper]) > 2.3
    # the mortar is common on the walked ground at both bin sizes, the post only at 8 levels
    for levels, coloured in ((8, True), (16, False)):
        gc = ground_coloured(img, ground, au.FOOT_GROUND_SHARE, levels)
        assert gc[(np.arange(H)[:, None] % 7 == 3) & ground].all()
        assert gc[post].all() == coloured and gc[post].any() == coloured
    on = _aligned(net, K, n, ground, image=img)
    assert au.FOOT_LEVELS == 16
    assert np.median(np.abs(on[upper] / Z[upper] - 1)) < 0.03
    monkeypatch.setattr(au, "FOOT_LEVELS", 8)
    coarse = _aligned(net, K, n, ground, image=img)
    assert np.array_equal(coarse[post], off[post])


def test_a_post_far_in_front_of_the_wall_stands_on_its_foot(monkeypatch):
    """A post 4 m away (1.5 m to the right) in front of the 15 m wall: its traced part takes the
    wall's contact, 3.75 x too far, and its foot is that much nearer. The pull limit
    (``FOOT_PULL``, 10) lets it stand there; at the former limit, 3, the rule refused it (the
    independent scenes' poles in front of far facades, docs/gains.md fourteenth round)."""
    import staticdepth.geometry.alignment_upright as au

    K, n, Z, net, ground, far, post, img = _scene(post_z=4.0, post_x=1.5)
    info: dict = {}
    off = _aligned(net, K, n, ground, info=info)
    upper = post & info["traced"]
    assert upper.sum() > 20 and np.median(off[upper] / Z[upper]) > 3.5
    on = _aligned(net, K, n, ground, image=img)
    assert au.FOOT_PULL == 10.0
    assert np.median(np.abs(on[upper] / Z[upper] - 1)) < 0.03
    monkeypatch.setitem(au.upright_depth.__kwdefaults__, "foot_pull", 3.0)
    limited = _aligned(net, K, n, ground, image=img)
    assert np.median(limited[upper] / Z[upper]) > 3.5


def test_the_static_images_colour_feet_are_walked_once_and_kept():
    """``alignment_vertical.static_colour_feet``: every pixel's colour foot, once per (image,
    vertical, threshold), reused by every frame's ``colour_foot`` (a static camera's median image).
    Truth from the scene's masks: a post pixel's foot is on the post, and the foot of one inside
    the post (its row neighbours on the post too) at the post's bottom row, where it meets the
    ground (an edge pixel's walk may leave the slanted, 3-pixel-wide post)."""
    from staticdepth.geometry import alignment_vertical as av
    from staticdepth.geometry.alignment_upright import FOOT_DIFF

    K, n, Z, net, ground, far, post, img = _scene()
    du = av.down_step(K, n, W, H)
    feet = av.static_colour_feet(img, du, FOOT_DIFF)
    pix = np.flatnonzero(post)
    f = feet[pix]
    inner = (post & np.roll(post, 1, 1) & np.roll(post, -1, 1)).ravel()[pix]
    assert post.ravel()[f].all() and inner.sum() > 30
    assert np.all(f[inner] // W == np.nonzero(post)[0].max())
    # the same contents (new arrays) are not walked again; another image is
    assert av.static_colour_feet(img.copy(), du.copy(), FOOT_DIFF) is feet
    other = np.where(post, 0.6, img)                 # the post in the ground's colour
    assert not np.array_equal(av.static_colour_feet(other, du, FOOT_DIFF)[pix], f)
    assert av.static_colour_feet(img, du, FOOT_DIFF) is feet
    # a subset walked on its own ends where the kept walk of every pixel does
    assert np.array_equal(av.colour_feet(img, du, pix, FOOT_DIFF), f)


def test_adapt_applies_the_setting_through_aligned_frame():
    """``align.colour_foot`` (on by default) is what takes the image into adapt's alignment."""
    from staticdepth.adaptation.align import aligned_frame
    from staticdepth.adaptation.config import build_config

    K, n, Z, net, ground, far, post, img = _scene()
    none = np.zeros(Z.shape, np.int32)
    rows = np.zeros(0, dtype=[("instance_id", "i4")])
    no_agents = {"align.agents_at_contact": False}                  # the scene has none
    on_conf = build_config({**no_agents, "align.colour_foot": True})
    args = (K, n, ground, none, rows, net)          # units of the camera height
    plain = aligned_frame(build_config({**no_agents, "align.colour_foot": False}), *args,
                          image=img)
    on = aligned_frame(on_conf, *args, image=img)
    assert np.array_equal(aligned_frame(on_conf, *args), plain)     # no image: no rule
    # the same maps as the rule's own test above (metres there, camera heights here)
    np.testing.assert_allclose(on * CAM, _aligned(net, K, n, ground, image=img), rtol=1e-5)
    np.testing.assert_allclose(plain * CAM, _aligned(net, K, n, ground), rtol=1e-5)
    assert not np.allclose(on, plain)


def test_the_align_command_applies_the_rule_only_with_the_frames():
    from staticdepth.adaptation.config import build_config
    from staticdepth.align import align_map

    K, n, Z, net, ground, far, post, img = _scene()
    plane = types.SimpleNamespace(normal=n)        # the command's plane file, its normal only
    on = build_config({"align.colour_foot": True}).align
    off = build_config({"align.colour_foot": False}).align
    # a single map has no frames: the default does not apply and says so
    single, info = align_map(net, K, plane, ground, align_conf=on, camera_height_m=CAM)
    assert "not applied" in info["colour_foot"]
    np.testing.assert_array_equal(single, align_map(net, K, plane, ground, align_conf=off,
                                                    camera_height_m=CAM)[0])
    # with the static image (`align --sequence`) it is adapt's rule
    seq, info = align_map(net, K, plane, ground, align_conf=on, image=img, camera_height_m=CAM)
    assert "colour_foot" not in info
    np.testing.assert_allclose(seq, _aligned(net, K, n, ground, image=img), rtol=1e-5)


def test_a_smooth_road_the_network_keeps_flat_is_not_pulled_onto_a_vertical(monkeypatch):
    """The demo's failure (docs/gains.md, eleventh round): a band of road the network keeps at
    one depth is traced like a wall; its colour runs on down to a lane marking, which would
    stand it on the vertical through the marking. The road's colour is the walked ground's, so
    the rule leaves it (alignment_upright.FOOT_GROUND_SHARE); with that test off, the lawn test
    (alignment_vertical.reaches_bottom: the road's colour comes back below the marking and goes
    on to the image's bottom) leaves the band's pixels that snapped to the plane (its lower
    half), so the band's median holds; with both off it is pulled."""
    import staticdepth.geometry.alignment_upright as au
    import staticdepth.geometry.alignment_vertical as av

    K, n, z_ground, _ = billboard_camera(CAM, 25.0, W, H, F)
    rows = np.arange(H)[:, None] * np.ones((1, W))
    finite = np.isfinite(z_ground)
    band = finite & (rows >= 40) & (rows < 50)            # kept flat by the network
    net = np.where(finite, z_ground, 200.0) * 0.5
    net = np.where(band, net[49:50, :], net)              # the band at its lowest row's depth
    img = np.where(finite & (rows == 58), 0.95, 0.6)      # a lane marking below the band
    img = np.where(~finite, 0.8, img)                     # sky
    ground = finite & (z_ground < 60)
    on = _aligned(net.astype(np.float32), K, n, ground, image=img)
    off = _aligned(net.astype(np.float32), K, n, ground)
    assert np.array_equal(on, off)
    monkeypatch.setattr(au, "FOOT_GROUND_SHARE", 2.0)   # no pixel is ground-coloured
    info: dict = {}
    lawn = _aligned(net.astype(np.float32), K, n, ground, image=img, info=info)
    snapped = band & info["snapped"]
    assert 0.3 < snapped.sum() / band.sum() < 0.7
    assert np.array_equal(lawn[snapped], off[snapped])
    assert np.median(lawn[band] / off[band]) > 0.99
    monkeypatch.setattr(av, "RESUME_DIFF", -1.0)        # no colour ever comes back
    pulled = _aligned(net.astype(np.float32), K, n, ground, image=img)
    assert np.median(pulled[band] / off[band]) < 0.95


def test_the_static_image_is_the_median_of_64_evenly_spread_frames():
    from staticdepth.adaptation.align import static_image

    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, (150, 6, 5, 3), dtype=np.uint8)
    before = frames.copy()

    class Reader:                      # static_image reads the left images only
        def __init__(self):
            self.read = []

        def left(self, i):
            self.read.append(i)
            return frames[i]              # the reader's own arrays: the median must not touch

    r = Reader()
    got = static_image(r, np.arange(10, 150))
    pick = np.linspace(10, 149, 64).astype(int)
    assert r.read == pick.tolist()
    np.testing.assert_array_equal(got, np.median(frames[pick].astype(np.float64), 0) / 255.0)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(frames, before)       # partitioned a copy, not the frames
    few = static_image(Reader(), np.array([4, 9, 20]))
    np.testing.assert_array_equal(few, np.median(frames[[4, 9, 20]].astype(np.float64), 0) / 255)


def _lawn_scene():
    """A lawn (green, +-0.03 texture per channel) in front of a walked path, to the image's
    bottom, and a sheet of paper (bright, 4 rows) lying on it; the network's depth the truth's
    at half the scale with 6% per-pixel noise on the lawn (what a network trained elsewhere
    gives a lawn: near the plane, not exactly on it). vtest.avi's lawn, in closed form."""
    K, n, z_ground, _ = billboard_camera(CAM, 30.0, W, H, F)
    rows = np.arange(H)[:, None] * np.ones((1, W), int)
    cols = np.arange(W)[None, :] * np.ones((H, 1), int)
    walked = (rows >= 30) & (rows < 55)
    lawn = rows >= 55
    rng = np.random.default_rng(0)
    img = np.full((H, W, 3), 0.55)
    img[rows < 30] = 0.5
    img[lawn] = np.array([0.22, 0.33, 0.05]) + rng.uniform(-0.03, 0.03, (int(lawn.sum()), 3))
    paper = (rows >= 80) & (rows < 84) & (np.abs(cols - 60) < 12)
    img[paper] = np.array([0.95, 0.95, 0.7])
    lawn &= ~paper
    net = np.where(np.isfinite(z_ground), z_ground, 200.0) * 0.5
    net = np.where(lawn, net * (1 + 0.06 * rng.standard_normal(net.shape)), net)
    return K, n, z_ground, net.astype(np.float32), walked, lawn, img


def test_a_lawn_is_not_stood_up_on_a_paper_lying_on_it(monkeypatch):
    """vtest.avi (the real video): the lawn in front of the walked path is not the path's
    colour, so its colour runs went down to a sheet of paper on the grass and the colour foot
    stood the lawn up there, a wall 1.8x too near (382 pixels of a frame). The lawn's colour
    comes back below the paper and goes on to the image's bottom
    (alignment_vertical.reaches_bottom), and the lawn's pixels snapped to the plane, so the rule
    leaves them; with the test off (RESUME_DIFF -1) it stands them up again."""
    import staticdepth.geometry.alignment_vertical as av

    K, n, z, net, walked, lawn, img = _lawn_scene()
    info: dict = {}
    on = _aligned(net, K, n, walked, image=img, info=info)
    monkeypatch.setattr(av, "RESUME_DIFF", -1.0)
    info_off: dict = {}
    off = _aligned(net, K, n, walked, image=img, info=info_off)
    near_off = lawn & (off / z < 0.8)
    near_on = lawn & (on / z < 0.8)
    assert near_off.sum() > 50 and (near_off & info_off["colour_foot"]).mean() > 0.9 * near_off.mean()
    assert near_on.sum() * 4 < near_off.sum()
    assert not (info["colour_foot"] & info["snapped"] & lawn).any()
    assert (info_off["colour_foot"] & info_off["snapped"] & lawn).sum() > 50
