"""Grazing contacts (issue 19): the plane's depth at a contact, its expected error from the
contact row and the normal's uncertainty, and the agents whose label is less certain than the
base's depth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from staticdepth.errors import InputError
from staticdepth.pseudo_labels import PseudoLabelConfig, grazing_agents, plane_depth_rel_std

F, W, H = 100.0, 64, 48
K = np.array([[F, 0, 31.5], [0, F, 23.5], [0, 0, 1.0]])


def test_level_camera_row_error_closed_form():
    # a level camera at height h sees ground row v at Z = f h / (v - c_y): dZ / Z = dv / (v - c_y)
    rel = plane_depth_rel_std(K, [0.0, 1.0, 0.0], 0.0, W, H, row_px=2.0)
    v = np.arange(H) - K[1, 2]
    below = v > 0
    np.testing.assert_allclose(rel[below, 10], 2.0 / v[below], rtol=1e-5)
    assert np.isnan(rel[~below]).all()          # at and above the horizon: no depth


def test_level_camera_tilt_error_closed_form():
    # a pitch error s moves the ray's angle below the horizon, alpha = atan((v - c_y) / f),
    # by s: Z = h / tan(alpha), dZ / Z = s / (sin alpha cos alpha), which at the image's centre
    # column and alpha -> 0 is s f / (v - c_y); off-centre |r - (n.r) n| = sqrt(x^2 + 1)
    s_deg = 0.5
    rel = plane_depth_rel_std(K, [0.0, 1.0, 0.0], s_deg, W, H, row_px=0.0)
    v, u = 40, 60
    x = (u - K[0, 2]) / F
    assert rel[v, u] == pytest.approx(math.radians(s_deg) * math.hypot(x, 1.0) * F
                                      / (v - K[1, 2]), rel=1e-5)
    a = math.atan((v - K[1, 2]) / F)
    centre = plane_depth_rel_std(K, [0.0, 1.0, 0.0], s_deg, W + 1, H, row_px=0.0)[v, 32]
    assert centre == pytest.approx(math.radians(s_deg) / (math.sin(a) * math.cos(a)), rel=0.05)


def test_tilted_camera_grows_toward_horizon_and_quadrature():
    t = math.radians(15.0)
    n = [0.0, math.cos(t), math.sin(t)]
    both = plane_depth_rel_std(K, n, 0.4, W, H, row_px=1.0)
    row = plane_depth_rel_std(K, n, 0.0, W, H, row_px=1.0)
    tilt = plane_depth_rel_std(K, n, 0.4, W, H, row_px=0.0)
    np.testing.assert_allclose(both[-1], np.hypot(row[-1], tilt[-1]), rtol=1e-5)
    col = both[:, 32]
    fin = np.isfinite(col)
    assert np.all(np.diff(col[fin]) < 0)        # nearer the horizon (smaller v): larger error


def test_grazing_agents_base_and_blend():
    # two agents: labels y = 1 / depth; the base is the truth up to a scale 2 with 10% spread on
    # the agents; agent 2's contact grazes (its label's expected error 0.5 > the base's 0.1)
    y = np.full((4, 6), 0.2, np.float32)
    agents = np.zeros_like(y, bool)
    agents[:, :3] = agents[:, 3:] = True
    inv = y / 2.0
    inv[:2, :3] *= 1.1
    inv[2:, :3] /= 1.1
    std = np.where(np.arange(6) < 3, 0.01, 0.5).astype(np.float32)[None].repeat(4, 0)
    out = grazing_agents(y, inv, std, agents, "base")
    c = np.median(y / inv)                      # the base at the labels' scale
    np.testing.assert_allclose(out[:, :3], y[:, :3])            # trusted: its label
    np.testing.assert_allclose(out[:, 3:], c * inv[:, 3:], rtol=1e-6)
    sb = np.median(np.abs(y[agents] / (c * inv[agents]) - 1))
    blend = grazing_agents(y, inv, std, agents, "blend")
    w = sb ** 2 / (0.5 ** 2 + sb ** 2)
    np.testing.assert_allclose(blend[0, 4], y[0, 4] ** w * (c * inv[0, 4]) ** (1 - w), rtol=1e-5)
    assert abs(blend[0, 0] - y[0, 0]) < 0.02 * y[0, 0]          # a certain label barely moves
    np.testing.assert_array_equal(grazing_agents(y, inv, std, agents, "off"), y)
    # the other pixels are never touched
    y2 = y.copy()
    y2[:, :] = 0.3
    out2 = grazing_agents(y2, inv, std, np.zeros_like(agents), "base")
    np.testing.assert_array_equal(out2, y2)


def test_bad_settings():
    with pytest.raises(InputError, match="grazing"):
        PseudoLabelConfig(grazing="always")
    with pytest.raises(InputError, match="contact_row_px"):
        PseudoLabelConfig(contact_row_px=-1.0)


def _rows(ids, cls=0):
    from staticdepth.dataset.schema import AGENT_DTYPE

    rows = np.zeros(len(ids), AGENT_DTYPE)
    rows["instance_id"] = ids
    rows["class_id"] = cls
    return rows


def test_contact_not_seen_is_infinitely_uncertain():
    from staticdepth.pseudo_labels import contact_label_std

    inst = np.zeros((H, W), np.uint16)
    inst[26:36, 5:8] = 1            # free-standing: contact seen at row 35
    inst[30:40, 20:23] = 2          # hidden: another agent right below its lowest pixel
    inst[40:45, 18:26] = 3
    inst[40:, 40:44] = 4            # cut off by the image's last row
    plane = plane_depth_rel_std(K, [0.0, 1.0, 0.0], 0.0, W, H, row_px=0.1)
    std, agents = contact_label_std(plane, inst, _rows([1, 2, 3, 4]))
    np.testing.assert_array_equal(agents, inst > 0)
    np.testing.assert_allclose(std[inst == 1], 0.1 / (35 - K[1, 2]), rtol=1e-5)
    np.testing.assert_allclose(std[inst == 3], 0.1 / (44 - K[1, 2]), rtol=1e-5)
    assert np.isinf(std[inst == 2]).all() and np.isinf(std[inst == 4]).all()
    # an unseen contact leaves the loss with "ignore", takes the base with "blend"
    y = np.full((H, W), 0.25, np.float32)
    checker = (np.add.outer(np.arange(H), np.arange(W)) % 2).astype(np.float32)
    inv = y * np.float32(0.5) * (1 + 0.1 * checker)     # the base: 5-10% off on every agent
    out = grazing_agents(y, inv, std, agents, "ignore")
    assert np.isnan(out[inst == 2]).all() and np.isnan(out[inst == 4]).all()
    np.testing.assert_array_equal(out[(inst == 1) | (inst == 3) | (inst == 0)],
                                  y[(inst == 1) | (inst == 3) | (inst == 0)])
    blend = grazing_agents(y, inv, std, agents, "blend")
    c = np.median(y[agents] / inv[agents])
    np.testing.assert_allclose(blend[inst == 4], c * inv[inst == 4], rtol=1e-6)
