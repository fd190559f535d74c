"""``upright`` with ``occlude``: a run does not reach the ground through one of the frame's agents.

A blurred network gives an agent standing in front of a wall depths continuous with the wall's,
so the wall's run went down through the agent to the agent's feet: the wall above the agent took
the agent's contact, nearer than its own foot. With ``occlude`` the run ends at the agent and
takes the ratio of the same wall beside it (whose foot is visible)."""
from __future__ import annotations

import numpy as np

from billboard_scene import billboard_camera
from staticdepth.geometry.alignment import align_depth

W, H, F = 160, 100, 100.0


def _scene(cam_height=1.5, pitch_deg=10.0, wall_m=14.0, wall_h=5.0, agent_m=6.0):
    """True depth, ground / wall / agent masks of a low camera: a wall (|lateral| < 6 m) and one
    agent (|lateral| < 0.4 m, 1.8 m tall) in front of its middle; sky 200 m."""
    K, n, z_ground, billboard = billboard_camera(cam_height, pitch_deg, W, H, F)
    z_wall, wall = billboard(wall_m, 6.0, wall_h)
    z_agent, agent = billboard(agent_m, 0.4, 1.8)
    depth = np.where(agent, z_agent, np.where(wall, z_wall, z_ground))
    wall &= ~agent
    depth[~np.isfinite(depth)] = 200.0
    ground = ~wall & ~agent & (z_ground < 60)
    return K, n, depth.astype(np.float32), ground, wall, agent


def _blurred(depth, wall, agent, wall_error=1.5):
    """The network: exact but the wall ``wall_error`` x too far, and each agent column a ramp
    from the wall's depth above it down to the agent's foot (no step a run would stop at)."""
    pred = depth.copy()
    pred[wall] *= wall_error
    for u in np.flatnonzero(agent.any(0)):
        rows = np.flatnonzero(agent[:, u])
        top, foot = rows[0], rows[-1]
        above = pred[top - 1, u]
        pred[rows, u] = np.geomspace(above, depth[foot, u], len(rows))
    return pred


def test_the_scene_is_what_the_test_needs():
    K, n, Z, ground, wall, agent = _scene()
    cols = np.flatnonzero(agent.any(0))
    top = np.flatnonzero(agent[:, cols[len(cols) // 2]])[0]
    assert wall[:top, cols].any(0).all()        # the wall stands above the agent's head
    pred = _blurred(Z, wall, agent)
    steps = np.abs(np.diff(np.log(pred[:, cols]), axis=0))
    assert steps[agent[1:, cols] & agent[:-1, cols]].max() < 0.08   # no depth step in the ramp


def _aligned(pred, K, n, ground, agent, **kw):
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    opts = {**upright_options(build_config({}).align), **kw}      # adapt's defaults
    return align_depth(pred, K, n, 1.5, ground, agent_mask=agent, mode="upright", **opts).depth


def _rel(A, Z, m):
    return float(np.median(np.abs(A[m] - Z[m]) / Z[m]))


def test_a_wall_behind_an_agent_keeps_its_own_contact():
    """The network puts the wall 30% too near (a 1.5x too far one is refused by max_pull either
    way); each agent column ramps from the wall's depth to the agent's foot."""
    from staticdepth.adaptation.align import upright_options
    from staticdepth.adaptation.config import build_config

    assert upright_options(build_config({}).align)["occlude"]      # the default
    K, n, Z, ground, wall, agent = _scene()
    pred = _blurred(Z, wall, agent, wall_error=0.7)
    cols = np.flatnonzero(agent.any(0))
    behind = wall & np.isin(np.arange(W), cols)[None, :]     # the wall above the agent's head
    beside = wall & ~behind
    assert behind.sum() > 50
    off = _aligned(pred, K, n, ground, agent, occlude=False)
    on = _aligned(pred, K, n, ground, agent)
    # the wall beside the agent stands on its own foot either way (within a row of it)
    assert _rel(off, Z, beside) < 0.04 and _rel(on, Z, beside) == _rel(off, Z, beside)
    assert _rel(off, Z, behind) > 0.25   # through the agent: the agent's contact (6 m, not 14)
    assert _rel(on, Z, behind) < 0.04    # cut at the agent: the wall beside it's ratio
    # without an agent mask (an exported graph) there is nothing to cut: the former result
    assert np.array_equal(align_depth(pred, K, n, 1.5, ground, mode="upright").depth,
                          align_depth(pred, K, n, 1.5, ground, mode="upright",
                                      occlude=True).depth)


def test_the_cut_wall_aligned_again_stays():
    """ft-align aligns an aligned map again (tests/test_align_idempotent.py): the wall behind the
    agent, placed by its neighbours' ratio, keeps its place in a second pass."""
    K, n, Z, ground, wall, agent = _scene()
    once = _aligned(_blurred(Z, wall, agent, wall_error=0.7), K, n, ground, agent)
    twice = _aligned(once, K, n, ground, agent)
    assert _rel(once, Z, wall) < 0.04
    assert np.max(np.abs(twice[wall] - once[wall]) / once[wall]) < 0.01
