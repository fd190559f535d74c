"""The near-nadir checks of a ground-plane fit (:mod:`staticdepth.geometry.agent_plane`).

Seen from above, upright agents' head-foot axes are short and converge near the image centre: the
pitch/roll parametrisation degenerates and fits land tens of degrees off. A fit is refused (one
``InputError`` line) when the head-foot axes' vanishing point or the fitted normal puts the pitch
above ``max_pitch_deg``, or when the fitted plane puts more than 5% of the inlier feet on or above
its horizon.
"""
from __future__ import annotations

import math

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.agent_cylinder import AgentObservations
from staticdepth.geometry.camera import pitch_roll_from_normal


def check_nadir(n: np.ndarray, conf, what: str = "the fit") -> None:
    """Refuse a (near-)nadir camera: from above, upright agents' head-foot axes are short and
    converge near the image centre, the pitch/roll parametrisation degenerates and the fit lands
    tens of degrees off (tapered walkers at 86-90 degrees: 38-70 degrees off, measured)."""
    pitch = pitch_roll_from_normal(n)[0]
    if pitch > conf.max_pitch_deg or math.hypot(n[0], n[1]) < 1e-6:
        raise InputError(f"near-nadir camera (or a failed fit): {what} puts the pitch at "
                         f"{pitch:.0f} deg, above max_pitch_deg {conf.max_pitch_deg:g}; seen from "
                         "above, the agents' head-foot axes cannot fix the ground plane's tilt")


def check_fitted_plane(n: np.ndarray, conf, obs: AgentObservations,
                       inliers: np.ndarray) -> None:
    """The near-nadir checks of a fitted (``joint``/``exact``) plane: its pitch, and its inlier
    tracks' feet below its horizon."""
    check_nadir(n, conf)
    _check_feet_below_horizon(obs.rays[inliers[obs.idx]] @ n)


def _check_feet_below_horizon(depression: np.ndarray, share: float = 0.05) -> None:
    """Refuse a plane that puts more than ``share`` of the inlier feet on or above its horizon
    (``depression``: foot rays dotted with the normal; a standing agent's foot is on the ground,
    below the horizon). Near-nadir box fits do this: a thin-walker camera at 90 degrees was fitted
    at 2 degrees, 88 off, with a third of the feet above the horizon (measured)."""
    above = float(np.mean(depression <= 0)) if len(depression) else 0.0
    if above > share:
        raise InputError(f"no ground plane fits the agents (near-nadir camera?): the fit puts "
                         f"{100 * above:.0f}% of the inlier feet above its horizon")
