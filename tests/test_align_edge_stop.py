"""``upright`` with ``edge_below`` (the image-edge cut benchmarks/bench_edge_stops.py measures):
a textured far wall whose foot a nearer, lower wall hides, the network blurred through the edge.

The network carries the far wall's depth down through the near wall (no step), so the far wall's
run above the near one walks on to the near wall's foot and takes its contact, 6 m instead of
14 m. The image shows the near wall's top: with the image's edges above a threshold that sits
above the far wall's stripes, the run stops there and takes the ratio of the same far wall beside
the near one (the far wall's own scale). A closed-form scene (tests/billboard_scene.py); the image
is drawn from its masks."""
from __future__ import annotations

import numpy as np

from billboard_scene import billboard_camera
from staticdepth.geometry.alignment import align_upright

W, H, F = 160, 100, 100.0
CAM = 1.5


def _scene():
    """True depth, the far wall's depth extended over the near one, and the masks: a wall 14 m
    away (|lateral| < 6 m, 5 m tall), a 1.2 m wall 6 m away in front of its middle; sky 200 m."""
    K, n, z_ground, billboard = billboard_camera(CAM, 10.0, W, H, F)
    z_far, far = billboard(14.0, 6.0, 5.0)
    z_near, near = billboard(6.0, 1.5, 1.2)
    depth = np.where(near, z_near, np.where(far, z_far, z_ground))
    far &= ~near
    depth[~np.isfinite(depth)] = 200.0
    ground = ~far & ~near & (z_ground < 60)
    return K, n, depth.astype(np.float32), z_far, ground, far, near


def _image(far, near):
    """Luminance 0-1: ground 0.5, far wall 0.3 with stripes of 0.15 contrast every 4 rows, near
    wall 0.9 (its top edge 0.45-0.6 against the far wall)."""
    img = np.full(far.shape, 0.5)
    rows = np.arange(far.shape[0])[:, None]
    img = np.where(far, 0.3 + 0.15 * ((rows // 4) % 2), img)
    return np.where(near, 0.9, img)


def _edges(img, t):
    """An edge between a pixel and the one below it (the walls' vertical edges are image
    columns: the camera has no roll and the walls face it)."""
    e = np.zeros(img.shape, bool)
    e[:-1] = np.abs(img[:-1] - img[1:]) > t
    return e


def _aligned(pred, K, n, ground, **kw):
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    opts = {**upright_options(build_config({}).align), **kw}      # adapt's defaults
    return align_upright(pred, K, n, CAM, ground, **opts).depth


def test_the_scene_is_what_the_test_needs():
    K, n, Z, z_far, ground, far, near = _scene()
    hidden = far & near.any(0)[None, :]
    assert hidden.sum() > 100 and (far & ~hidden).sum() > 300
    img = _image(far, near)
    # the near wall's top is an image edge at 0.3; the far wall's stripes are not
    top = np.zeros_like(far)
    top[:-1] = far[:-1] & near[1:]
    assert top.sum() > 10 and np.array_equal(_edges(img, 0.3) & far, top)
    assert (_edges(img, 0.1) & far & ~top).sum() > 100        # stripes above 0.1


def test_the_image_edge_cuts_the_run_the_blurred_network_carries_through():
    K, n, Z, z_far, ground, far, near = _scene()
    hidden = far & near.any(0)[None, :]
    # the network: the far wall 60% too near and carried on through the near wall (no step)
    pred = Z.copy()
    pred[far] *= 0.4
    pred[near] = 0.4 * z_far[near]
    off = _aligned(pred, K, n, ground)
    on = _aligned(pred, K, n, ground, edge_below=_edges(_image(far, near), 0.3))

    def rel(A, m):
        return float(np.median(np.abs(A[m] - Z[m]) / Z[m]))

    # beside the near wall the far wall stands on its own foot either way
    assert rel(off, far & ~hidden) < 0.04 and rel(on, far & ~hidden) < 0.04
    # above it, without the cut the run takes the near wall's foot: the plane there is 1.07 x
    # the network's (6 m / 0.4 x 14 m), the far wall stays at 0.43 of its depth
    assert np.median(off[hidden] / Z[hidden]) < 0.5
    # with the image edge the run stops at the near wall's top and takes its neighbours' ratio
    assert rel(on, hidden) < 0.04
    # a threshold under the far wall's stripes cuts its own runs too: the hidden part no better
    low = _aligned(pred, K, n, ground, edge_below=_edges(_image(far, near), 0.1))
    assert rel(low, hidden) > 0.3 and rel(low, far & ~hidden) > 0.3
