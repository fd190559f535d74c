"""The alignment's per-camera constants (``alignment_upright.AlignCamera``): what depends only on
the camera, the plane and the static image, built once per run and given to every frame.

Its constants against closed forms (the rays ``K^-1 [u, v, 1]``, the plane's inverse depth
``n . r / d``, the image of the vertical: the line from each pixel to the vertical's vanishing
point ``K n``); frames of the independent renderer (tests/indep_scenes.py) aligned as adapt does
with one camera for all of them equal, to the bit, each aligned alone, with the static image's
colour feet walked once; a camera given a frame of another camera, plane, size or image is
refused."""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth.errors import InputError
from staticdepth.geometry import alignment_upright as au
from staticdepth.geometry.alignment import agents_at_contact, align_depth, align_upright
from staticdepth.geometry.alignment_upright import AlignCamera, upright_depth
from staticdepth.geometry.projection import ray_grid

W, H = 160, 80


def _camera(pitch_deg: float = 80.0, roll_deg: float = 4.0):
    """A skewed K and a unit normal pointing down into the ground: the vertical's vanishing
    point lies inside the image when the camera looks down steeply."""
    K = np.array([[0.8 * W, 0.7, (W - 1) / 2], [0, 0.75 * W, (H - 1) / 2], [0, 0, 1.0]])
    t, r = math.radians(pitch_deg), math.radians(roll_deg)
    return K, np.array([math.sin(r), math.cos(r) * math.cos(t), math.cos(r) * math.sin(t)])


def test_the_constants_are_the_closed_forms():
    K, n = _camera()
    d = 3.5
    cam = AlignCamera(K, W, H, 2.0 * n, d)          # a normal of any length: made unit
    v, u = np.mgrid[0:H, 0:W]
    pix = np.stack([u, v, np.ones_like(u)], -1).astype(np.float64)
    rays = np.linalg.solve(K, pix[..., None])[..., 0]
    np.testing.assert_allclose(cam.rays, rays, rtol=1e-12, atol=1e-12)
    assert cam.q.dtype == np.float32
    np.testing.assert_allclose(cam.q, rays @ n / d, rtol=1e-6)
    # to the bit as the alignment computed it for each frame before it had a camera
    assert np.array_equal(cam.q, (ray_grid(K, W, H) @ (cam.normal / (
        np.linalg.norm(cam.normal) * d))).astype(np.float32))
    np.testing.assert_allclose(cam.unit, n, rtol=1e-15)
    # down the vertical a pixel moves towards the vanishing point K n: du/dv along that line,
    # none for the rows below the nadir's image (moving down the vertical moves up there)
    vp = K @ n
    u_vp, v_vp = vp[0] / vp[2], vp[1] / vp[2]
    assert 0 < v_vp < H - 1                          # both kinds of rows are in the image
    below = v > v_vp + 1e-6
    assert np.isnan(cam.du[below]).all() and np.isfinite(cam.du[v < v_vp - 1e-6]).all()
    np.testing.assert_allclose(cam.du[~below], ((u_vp - u) / (v_vp - v))[~below], rtol=1e-9,
                               atol=1e-12)
    # shared by every frame: read-only, and computed once
    with pytest.raises(ValueError):
        cam.q[0, 0] = 1.0
    assert cam.q is cam.q and cam.du is cam.du and cam.walk(3) is cam.walk(3)


def test_the_normalised_camera_is_the_unit_normals_and_shares_the_rays():
    K, n = _camera()
    cam = AlignCamera(K, W, H, 1.3 * n, 1.0)
    unit = cam.normalised()
    assert unit is not cam and unit.rays is cam.rays and unit is cam.normalised()
    assert np.array_equal(unit.normal, cam.normal / np.linalg.norm(cam.normal))
    # the plane is the same: its inverse depth agrees up to rounding
    np.testing.assert_allclose(unit.q, cam.q, rtol=1e-6)
    level = AlignCamera(K, W, H, [0.0, 1.0, 0.0], 1.0)   # normalising changes nothing: itself
    assert level.normalised() is level


def test_a_dropped_camera_is_freed_at_once():
    """No reference cycle: a camera built for one call holds that frame's constants (MBs) and
    must go with the call, not wait for the garbage collector."""
    import gc
    import weakref

    K, n = _camera()
    gc.disable()
    try:
        for normal in (n / np.linalg.norm(n), 1.3 * n):
            cam = AlignCamera(K, W, H, normal, 1.0)
            cam.normalised().walk(3)
            assert cam.q is not None and cam.normalised().du is not None
            ref, ref_unit = weakref.ref(cam), weakref.ref(cam.normalised())
            del cam
            assert ref() is None and ref_unit() is None
    finally:
        gc.enable()


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Three frames of the independent scene i4 (160x80): a network-like prediction (inverse
    depth up to scale and shift, with a ramped error), the agents, the walked ground (the near
    true ground) and the left image as the static scene."""
    from staticdepth.dataset.h5 import SequenceReader
    from tests.indep_scenes import SCENES, write_scene

    path = write_scene(str(tmp_path_factory.mktemp("cam") / "i4.h5"), SCENES[3], frames=3,
                       width=W, height=H)
    with SequenceReader(path) as r:
        K, mount = r.camera.K, r.meta.mounting
        out = []
        for i in range(3):
            Z = r.depth(i)
            yy = np.linspace(0.0, 1.0, H)[:, None]
            pred = (1.0 / (0.5 / Z + 0.01 + 0.02 * yy)).astype(np.float32)
            plane = mount.height_m / (ray_grid(K, W, H) @ mount.normal)
            inst = r.instances(i)
            ground = (np.abs(Z - plane) < 0.01 * Z) & (inst == 0)
            ground[: H // 2] = False
            out.append((pred, inst, r.agents(i), ground))
        image = r.left(0) / 255.0
    # a normal whose length is not 1: align_depth goes on with the unit normal's camera
    return K, 1.3 * np.asarray(mount.normal, np.float64), image, out


def test_one_camera_for_every_frame_aligns_each_as_alone(frames, monkeypatch):
    from staticdepth.adaptation.align import aligned_frame, upright_options
    from staticdepth.adaptation.config import AdaptConfig

    K, n, image, fs = frames
    conf = AdaptConfig()
    assert conf.align.mode == "upright" and conf.align.colour_foot and conf.align.occlude
    walks = []
    real = au.static_colour_feet

    def counted(*a):
        walks.append(1)
        return real(*a)

    monkeypatch.setattr(au, "static_colour_feet", counted)
    cam = AlignCamera(K, W, H, n, 1.0, image)
    assert cam.normalised() is not cam
    shared, alone = [], []
    for pred, inst, rows, ground in fs:
        kw = dict(mode="upright", agent_mask=inst > 0, snap_rel=conf.align.snap_rel,
                  **upright_options(conf.align))
        info_c, info_a = {}, {}
        shared.append(align_depth(pred, K, n, 1.0, ground, image=cam.image, info=info_c,
                                  camera=cam, **kw).depth)
        alone.append(align_depth(pred, K, n, 1.0, ground, image=image, info=info_a,
                                 **kw).depth)
        assert info_c.keys() == info_a.keys()
        for k in info_a:
            assert np.array_equal(info_c[k], info_a[k], equal_nan=True), k
        assert info_a["moved"].sum() > 100 and info_a["colour_foot"].any()   # the rules fired
        a = aligned_frame(conf, K, n, ground, inst, rows, pred, plane_bound=True,
                          image=cam.image, camera=cam)
        b = aligned_frame(conf, K, n, ground, inst, rows, pred, plane_bound=True, image=image)
        assert np.array_equal(a, b, equal_nan=True)
        assert not np.array_equal(a, shared[-1], equal_nan=True)     # agents at their contact
    for x, y in zip(shared, alone):
        assert np.array_equal(x, y, equal_nan=True)
    assert not np.array_equal(shared[0], shared[1], equal_nan=True)  # the frames differ
    # the static image's colour feet: walked once for the camera's frames (the first one and its
    # aligned_frame), once per call without it (there: hashed, and kept since the image is one)
    assert len(walks) == 1 + 2 * len(fs)


def test_a_camera_is_refused_for_another_camera_plane_size_or_image(frames):
    K, n, image, fs = frames
    pred, inst, rows, ground = fs[0]
    cam = AlignCamera(K, W, H, n, 1.0, image)
    assert cam.check(K.tolist(), list(n), 1, W, H) is cam          # the same values: itself
    K2 = K.copy()
    K2[0, 0] = np.nextafter(K2[0, 0], np.inf)
    n2 = n.copy()
    n2[2] = np.nextafter(n2[2], 0.0)
    for args in ((K2, n, 1.0), (K, n2, 1.0), (K, n, np.nextafter(1.0, 2.0))):
        with pytest.raises(InputError, match="another camera or plane"):
            align_depth(pred, *args, ground, mode="upright", camera=cam)
        with pytest.raises(InputError, match="another camera or plane"):
            agents_at_contact(pred, *args, inst, rows, camera=cam)
    with pytest.raises(InputError, match="another camera or plane"):       # another size
        align_depth(pred[:, 1:], K, n, 1.0, ground[:, 1:], mode="ground", camera=cam)
    # align_depth passes its modes the unit normal's camera: the raw one is not theirs
    unit = n / np.linalg.norm(n)
    with pytest.raises(InputError, match="another camera or plane"):
        align_upright(pred, K, unit, 1.0, ground, camera=cam)
    with pytest.raises(InputError, match="another camera or plane"):
        upright_depth(pred, K, unit, 1.0, ground, cam.q, camera=cam)
    # a camera holding the static image takes no other image, not even a copy
    with pytest.raises(InputError, match="static image"):
        align_depth(pred, K, n, 1.0, ground, mode="upright", image=image.copy(), camera=cam)
    with pytest.raises(InputError, match="static image"):
        AlignCamera(K, W, H, n, 1.0, image[:, 1:])
