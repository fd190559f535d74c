"""Hints about a stereo pair the matcher cannot give itself: a disparity range that clips the
scene, and swapped views.

Both read the distinct, row-consistent feature matches of the rectification check
(:func:`staticdepth.stereo.rectify.measure_rectification`), whose disparities do not depend on
the matcher's range, and the matcher's own output (how many pixels sit at the range's limit).
"""
from __future__ import annotations

import numpy as np

from staticdepth.stereo.rectify import RectificationCheck

# A scene is clipped when more than this share of the features lies beyond the range, or of the
# measured pixels at its last two disparities (SGBM's cost minimum pinned at the limit).
CLIPPED_FEATURES = 0.01
CLIPPED_PIXELS = 0.01
# Views are swapped when most features have a negative disparity.
SWAPPED_FEATURES = 0.6


def suggested_range(disparity_px: float) -> int:
    """A ``--max-disparity`` covering ``disparity_px`` with 10 % margin, a multiple of 16."""
    return int(16 * np.ceil(1.1 * disparity_px / 16))


def swapped_views(check: RectificationCheck | None) -> str | None:
    """The finding (without a hint: the options to exchange are the caller's) when most matched
    features have a negative disparity, else None."""
    d = np.asarray(check.disparities if check is not None else [], np.float64)
    if d.size < 20:
        return None
    negative = float(np.mean(d < -0.5))
    if negative <= SWAPPED_FEATURES:
        return None
    return (f"the views look swapped: {100 * negative:.0f}% of the matched features have a "
            "negative disparity (the right image matches better as the left)")


def stereo_warnings(check: RectificationCheck | None, num_disparities: int,
                    disparity: np.ndarray | None = None) -> list[str]:
    """Warnings (one line each) for a pair matched with ``num_disparities`` px of range.

    ``disparity``: the matcher's left disparity of the pair (NaN/inf/<=0 = invalid), optional.
    """
    out: list[str] = []
    d = np.asarray(check.disparities if check is not None else [], np.float64)
    swapped = swapped_views(check)
    if swapped:
        return [f"{swapped}; exchange --left and --right"]
    if d.size >= 20:
        beyond = float(np.mean(d > num_disparities))
        if beyond > CLIPPED_FEATURES:
            need = suggested_range(float(np.percentile(d, 99.5)))
            out.append(f"the disparity range clips the scene: {100 * beyond:.1f}% of the matched "
                       f"features lie beyond {num_disparities} px (up to {d.max():.0f} px); try "
                       f"--max-disparity {need} (or a smaller --min-depth)")
            return out
    if disparity is not None:
        disp = np.asarray(disparity, np.float64)
        valid = np.isfinite(disp) & (disp > 0)
        if valid.any():
            at_limit = float(np.mean(disp[valid] >= num_disparities - 2))
            if at_limit > CLIPPED_PIXELS:
                out.append(f"the disparity range may clip the scene: {100 * at_limit:.1f}% of the "
                           f"measured pixels sit at its limit ({num_disparities} px); try a "
                           f"larger --max-disparity (or a smaller --min-depth)")
    return out
