"""Report panels: colour bars read the depth they colour, planes and tracks are drawn, order."""
from __future__ import annotations

import numpy as np

from staticdepth import report_figures as rf
from staticdepth.dataset import schema
from staticdepth.dataset.inspect import colorize_depth
from staticdepth.geometry import Camera, Mounting, plane_depth_map


def test_depth_colour_bar_matches_the_colours_of_the_map():
    bar = rf.depth_colour_bar(300, 2.0, 50.0)
    assert bar.shape == (34, 300, 3)
    # the column where 1/d sits between 1/50 and 1/2 has the colour colorize_depth gives d
    for d in (3.0, 10.0, 30.0):
        t = (1 / d - 1 / 50.0) / (1 / 2.0 - 1 / 50.0)
        col = bar[8, int(round(t * 299))].astype(int)
        ref = colorize_depth(np.array([[d]]), 2.0, 50.0)[0, 0].astype(int)
        assert np.abs(col - ref).max() <= 12
    assert np.any(bar[20:] < 128)            # tick labels printed under the bar


def test_pipeline_order_and_panels():
    names = ["stereo-baseline", "ft", "zeta", "align-metric", "base", "ft-align", "align"]
    assert rf.pipeline_sorted(names) == ["base", "ft", "align", "ft-align", "align-metric",
                                         "stereo-baseline", "zeta"]
    p = rf.depth_panel(np.full((40, 80), 5.0), "x", (2.0, 20.0))
    assert p.shape == (18 + 40 + 34, 80, 3)
    grid = rf.panel_grid([p, p, p], columns=2)
    assert grid.shape[1] == 2 * (80 + 6) and grid.shape[0] == 2 * (p.shape[0] + 6)


def test_planes_and_tracks_are_drawn():
    cam = Camera.from_fov(160, 80, 90)
    mnt = Mounting.from_pitch_roll(5.0, 30.0)
    img = np.zeros((80, 160, 3), np.uint8)
    drawn = rf.draw_planes(img, cam.K, {"true": (mnt.normal, mnt.height_m)})
    green = np.all(drawn == rf.PLANE_COLOURS["true"], axis=2)
    z = plane_depth_map(cam.K, mnt.normal, mnt.height_m, 160, 80)[:, 80]
    row10 = int(np.nonzero(np.nan_to_num(z, nan=1e9) < 10)[0].min())   # 10 m at the centre
    assert green[row10 - 1:row10 + 2, 70:90].any(axis=0).all()     # the 10 m line crosses there
    assert green[:, 0].sum() <= 4 and green[-1].sum() <= 4        # no line along the frame
    ag = schema.empty_agents(30)
    ag["frame"] = np.repeat(np.arange(15), 2)
    ag["track_id"] = np.tile([1, 2], 15)
    ag["foot_u"] = np.where(ag["track_id"] == 1, 20 + ag["frame"] * 5, 140 - ag["frame"] * 5)
    ag["foot_v"] = 60
    out = rf.draw_tracks(img, ag, frame=14, last=5)
    changed = np.any(out != out[0, 0], axis=2)
    cols = np.nonzero(changed[60])[0]
    # only the last 5 frames (10..14) of each track: u in 70..90 and 70..90 from the other side
    assert cols.min() >= 20 + 10 * 5 - 4 and cols.max() <= 140 - 10 * 5 + 4
