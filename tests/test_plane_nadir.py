"""Near-nadir cameras (70-90 degrees pitch) on the independent generators (issue 13): the
ground-plane fit must refuse them with a one-line reason, or the gate must refuse the plane, or
the plane must be correct. Seen from above, the lowest and highest silhouette rows of a body are
no longer its foot and head, and a per-track scale absorbs the rest, so an unchecked fit lands
tens of degrees off (measured before the checks: wide cylinders 7-58 degrees, thin boxes at 90
degrees 85-88 degrees off with a bootstrap uncertainty of 0.26, i.e. accepted by the gate)."""
from __future__ import annotations

import numpy as np
import pytest

from plane_generators import scene
from staticdepth.errors import InputError
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.agent_plane_gate import plane_gate
from staticdepth.geometry.plane import angle_between_deg

FAST = AgentPlaneConfig(bootstrap=0, column_weight=1.0)


@pytest.mark.parametrize("kind,pitch", [("thin", 70.0), ("thin", 80.0), ("thin", 90.0),
                                        ("tapered", 70.0), ("tapered", 80.0)])
def test_box_detections_near_nadir_are_refused(kind, pitch):
    """Boxes carry no head column, so only the fit itself can tell: at 70-80 degrees the fitted
    pitch is above max_pitch_deg; at 90 the fit lands near a horizontal camera and puts a third
    of the feet above its horizon, which no standing agent can be. With the boxes' widths fitted
    (their sides), thin seed 1 at 90 degrees passed the fit 73 degrees off; since the shoulder
    ring starts at the box's width (agent_plane_sides.py) seeds 0 and 2 pass it instead, 57 and
    59 degrees off, no longer near a horizontal camera, and the gate refuses them (bootstrap of 5:
    11.5 and 14.8 degrees); seed 1, refused by the fit until box7's changes (the ring radii's
    estimated spread, the wide start's starts; which of the two was not measured), now passes it
    too and the gate refuses it: all three are refused."""
    if (kind, pitch) == ("thin", 90.0):
        conf = AgentPlaneConfig(bootstrap=5, column_weight=1.0)
        got = [_refused_or_correct(scene(kind, seed, detection="box", pitch_deg=pitch), conf)
               for seed in (0, 1, 2)]
        assert got == ["gate", "gate", "gate"], got
        return
    for seed in (0, 1, 2):
        s = scene(kind, seed, detection="box", pitch_deg=pitch)
        with pytest.raises(InputError, match="near-nadir camera") as e:
            fit_agent_plane(s.K, s.obs, FAST)
        assert "\n" not in str(e.value), (seed, str(e.value))


def test_feet_above_the_horizon_are_refused_but_normal_cameras_pass():
    """The horizon check refuses the thin boxes at 90 degrees by that reason when their rows
    alone are fitted (sides unknown: the fit lands near a horizontal camera, 11% of the feet above
    its horizon; with the sides it lands elsewhere and the gate refuses it, see above) and leaves
    normal cameras (10-50 degrees, boxes) fitted within 1 degree."""
    s = scene("thin", 0, detection="box", pitch_deg=90.0)
    rows_only = s.obs.copy()
    rows_only["left"], rows_only["right"] = np.nan, np.nan
    with pytest.raises(InputError, match="above its horizon"):
        fit_agent_plane(s.K, rows_only, FAST)
    for seed in (0, 2):
        s = scene("thin", seed, detection="box")
        p = fit_agent_plane(s.K, s.obs, FAST)
        assert angle_between_deg(p.normal, s.normal) < 1.0, seed


def _refused_or_correct(s, conf) -> str:
    """'fit' / 'gate' when refused by the fit / by the gate, else 'correct' (within 2 degrees);
    raises AssertionError for an accepted wrong plane."""
    try:
        p = fit_agent_plane(s.K, s.obs, conf)
    except InputError as e:
        assert "near-nadir camera" in str(e) and "\n" not in str(e), str(e)
        return "fit"
    if not plane_gate(p).ok:
        return "gate"
    err = angle_between_deg(p.normal, s.normal)
    assert err <= 2.0, (err, p.normal_std_deg)
    return "correct"


def test_wide_cylinders_near_nadir_are_refused_by_the_fit_or_the_gate():
    """Wide cylinders (masks and boxes) at 70, 80, 90 degrees, 12 tracks: refused or correct.
    Masks of seeds 1-2 are refused by the fit (fitted pitch or the axes' vanishing point); the
    accepted fits are wrong (boxes at 90, seed 1: 69 degrees off) but their bootstrap uncertainty
    makes the gate refuse them; seed 2's box fit now refuses itself. Seed 0 (slow, not run here) passes the fit
    at every pitch (masks 7-57 degrees off, boxes 12-35 degrees) and the gate refuses it too (bootstrap
    uncertainty 1.7-11.8 degrees, measured with 5 resamples)."""
    conf = AgentPlaneConfig(bootstrap=5, column_weight=1.0)
    seen = []
    for pitch in (70.0, 80.0, 90.0):
        for seed in (1, 2):
            seen.append(_refused_or_correct(scene("cylinder", seed, pitch_deg=pitch,
                                                  n_tracks=12), conf))
    assert set(seen) == {"fit"}, seen
    boxes = [_refused_or_correct(scene("cylinder", seed, detection="box", pitch_deg=90.0,
                                       n_tracks=12), conf) for seed in (1, 2)]
    # with the boxes' widths, seed 2 is refused by the fit itself (was: by the gate)
    assert boxes == ["gate", "fit"], boxes


def test_tapered_and_ellipsoid_boxes_near_nadir_are_refused_by_the_gate():
    """Boxes of tapered and ellipsoid walkers at 80-90 degrees pass the fit 19-61 degrees off;
    their bootstrap uncertainty (15-28 degrees, 5 resamples) makes the gate refuse them (the
    ellipsoids at 80 degrees are refused by the fit itself since the shoulder ring starts at the
    box's width). Also
    measured, not run here: tapered seed 0 at 90 (42 off, 8.2), ellipsoid seed 0 at 70, 80, 90
    (7, 33, 33 off; 3.0, 11.8, 4.4)."""
    conf = AgentPlaneConfig(bootstrap=5, column_weight=1.0)
    got = [_refused_or_correct(scene(kind, 1, detection="box", pitch_deg=pitch), conf)
           for kind, pitch in (("tapered", 90.0), ("ellipsoid", 80.0), ("ellipsoid", 90.0))]
    assert got == ["gate", "fit", "gate"], got
