"""The report's panels: labelled, with colour bars in metres, in the pipeline's order.

Order: the input frame; ground-truth depth; each prediction in the order the method makes them
(base -> ft -> align -> ft-align -> metric -> stereo baseline), depth then relative error; the
ground planes (true, from the agents, and the plane of the base prediction) as iso-depth lines
labelled in metres; the agents' recent tracks. Depth colours follow inverse depth (turbo, near =
red) over one range per sequence (the ground truth's 2nd-98th percentile; without ground truth,
the metric predictions' together), so panels compare; a relative prediction's panel has its own
range and a bar labelled relative.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import cv2
import numpy as np

from staticdepth.dataset.inspect import colorize_depth

PIPELINE_ORDER = ("base", "ft", "align", "ft-align", "align-metric", "ft-align-metric",
                  "stereo-baseline")
PLANE_COLOURS = {"true": (40, 220, 40), "agents": (255, 160, 0), "predicted": (230, 40, 230)}
PLANE_CAPTIONS = {"true": "green true", "agents": "orange from the agents",
                  "predicted": "magenta the base prediction's plane, its orientation only: "
                               "scaled to the agents' height"}
NICE_M = (0.5, 1, 2, 3, 5, 7, 10, 15, 20, 30, 50, 70, 100, 150, 200, 300)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def pipeline_sorted(names: Sequence[str]) -> list[str]:
    """Prediction names in the method's order; unknown names after, alphabetically."""
    rank = {n: i for i, n in enumerate(PIPELINE_ORDER)}
    return sorted(names, key=lambda n: (rank.get(n, len(rank)), n))


def outlined_text(img: np.ndarray, text: str, org: tuple[int, int], colour, scale: float = 0.35
                  ) -> None:
    """``text`` in ``colour`` with a dark outline, readable on any background (in place)."""
    cv2.putText(img, text, org, FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, FONT, scale, tuple(int(c) for c in colour), 1, cv2.LINE_AA)


def label(tile: np.ndarray, text: str) -> np.ndarray:
    """A title strip above the tile (RGB uint8), the tile unchanged below it."""
    strip = np.full((18, tile.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, text, (3, 13), FONT, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([strip, tile], axis=0)


def _bar(colours: np.ndarray, ticks: Sequence[tuple[float, str]], caption: str) -> np.ndarray:
    """A colour bar (colours (W, 3) RGB) with tick labels at fractions of its width."""
    w = len(colours)
    bar = np.full((34, w, 3), 255, np.uint8)
    bar[2:14] = colours[None]
    placed: list[tuple[int, int]] = []
    # the ends first (they carry the range), then the others where their labels fit
    for t, text in sorted(ticks, key=lambda tt: min(tt[0], 1 - tt[0]) > 1e-9):
        x = int(round(t * (w - 1)))
        (tw, _), _ = cv2.getTextSize(text, FONT, 0.35, 1)
        x0 = int(np.clip(x - tw / 2, 0, w - tw))
        if any(x0 < b + 8 and a < x0 + tw + 8 for a, b in placed):   # 8 px apart
            continue
        placed.append((x0, x0 + tw))
        bar[14:18, x:x + 1] = 0
        cv2.putText(bar, text, (x0, 28), FONT, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    (cw, _), _ = cv2.getTextSize(caption, FONT, 0.35, 1)
    if caption and cw < w // 3:
        cv2.putText(bar, caption, (w - cw - 2, 12), FONT, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
    return bar


def depth_colour_bar(width: int, near_m: float, far_m: float, caption: str = "depth m"
                     ) -> np.ndarray:
    """The bar of :func:`colorize_depth` over [near_m, far_m] (inverse depth), ticks in metres."""
    t = np.linspace(0, 1, width)
    d = 1.0 / (1.0 / far_m + t * (1.0 / near_m - 1.0 / far_m))
    colours = colorize_depth(d[None, :], near_m, far_m)[0]
    pos = lambda v: (1.0 / v - 1.0 / far_m) / (1.0 / near_m - 1.0 / far_m)  # noqa: E731
    ticks = [(pos(v), f"{v:g}") for v in NICE_M if near_m < v < far_m]
    ticks = [(0.0, f"{far_m:.3g}"), *ticks, (1.0, f"{near_m:.3g}")]  # the ends: the range
    return _bar(colours, ticks, caption)


def error_colour_bar(width: int, vmax: float = 0.5) -> np.ndarray:
    t = np.linspace(0, 1, width)
    colours = cv2.applyColorMap((t * 255).astype(np.uint8)[None, :],
                                cv2.COLORMAP_HOT)[0, :, ::-1]
    ticks = [(v / vmax, f"{v:g}") for v in (0, 0.1, 0.2, 0.3, 0.4, 0.5) if v < vmax]
    return _bar(np.ascontiguousarray(colours), [*ticks, (1.0, f">={vmax:g}")], "")


def depth_range(depth: np.ndarray) -> tuple[float, float] | None:
    d = np.asarray(depth, np.float64)
    ok = np.isfinite(d) & (d > 0)
    if not ok.any():
        return None
    near, far = float(np.percentile(d[ok], 2)), float(np.percentile(d[ok], 98))
    return near, max(far, near * 1.01)


def depth_panel(depth: np.ndarray, title: str, rng: tuple[float, float] | None) -> np.ndarray:
    """Colourised depth with its title and colour bar; ``rng`` None = the map's own range
    (relative predictions: the bar then reads in the prediction's own units)."""
    own = rng is None
    rng = rng or depth_range(depth)
    if rng is None:
        return label(np.zeros(depth.shape + (3,), np.uint8), title + " (no valid pixel)")
    img = colorize_depth(depth, *rng)
    bar = depth_colour_bar(depth.shape[1], *rng, caption="relative" if own else "depth m")
    return np.concatenate([label(img, title), bar], axis=0)


def error_panel(error_rgb: np.ndarray, title: str) -> np.ndarray:
    return np.concatenate([label(error_rgb, title), error_colour_bar(error_rgb.shape[1])], axis=0)


def draw_planes(image: np.ndarray, K: np.ndarray, planes: Mapping[str, tuple[np.ndarray, float]],
                depths_m: Sequence[float] = (5, 10, 20, 40)) -> np.ndarray:
    """Iso-depth lines of each ground plane (one colour per plane), each line labelled with its
    depth in metres; a legend in the corner."""
    from staticdepth.geometry.plane import plane_depth_map

    out = image.copy()
    h, w = image.shape[:2]
    for k, (name, (n, d)) in enumerate(planes.items()):
        z = plane_depth_map(K, np.asarray(n, float), float(d), w, h)
        colour = PLANE_COLOURS.get(name, (255, 255, 255))
        for zc in depths_m:
            inside = (np.nan_to_num(z, nan=1e9) < zc).astype(np.uint8)
            line = (inside > 0) & (cv2.erode(inside, np.ones((3, 3), np.uint8),
                                             borderType=cv2.BORDER_REPLICATE) == 0)
            vs, us = np.nonzero(line)
            if not len(vs):
                continue
            out[vs, us] = colour
            # label each line near a column of its own, so the planes' labels do not overlap
            j = np.argmin(np.abs(us - w * (0.3 + 0.22 * k)))
            outlined_text(out, f"{zc:g} m", (int(us[j]) + 2, int(vs[j]) - 3), colour)
    # the legend on a white card in the top-left corner
    names = list(planes)
    card_w = 18 + max((cv2.getTextSize(n, FONT, 0.4, 1)[0][0] for n in names), default=0)
    out[2:6 + 14 * len(names), 2:4 + card_w] = 255
    for k, name in enumerate(names):
        colour = PLANE_COLOURS.get(name, (255, 255, 255))
        cv2.rectangle(out, (4, 5 + 14 * k), (14, 13 + 14 * k), colour, -1)
        cv2.putText(out, name, (18, 14 + 14 * k), FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def draw_tracks(image: np.ndarray, agents: np.ndarray, frame: int, last: int = 6,
                max_tracks: int = 25) -> np.ndarray:
    """The foot points of the ``last`` frames up to ``frame``, one colour per track (at most
    ``max_tracks``: the longest), the newest position as a larger dot."""
    out = (image.astype(np.float32) * 0.6 + 255 * 0.4).astype(np.uint8)   # faded backdrop
    rows = agents[(agents["foot_v"] >= 0) & (agents["track_id"] >= 0)
                  & (agents["frame"] <= frame) & (agents["frame"] > frame - last)]
    tracks, counts = np.unique(rows["track_id"], return_counts=True)
    keep = tracks[np.argsort(-counts, kind="stable")][:max_tracks]
    palette = cv2.applyColorMap(np.linspace(0, 255, max(len(keep), 1)).astype(np.uint8)[:, None],
                                cv2.COLORMAP_HSV)[:, 0, ::-1]
    for colour, tid in zip(palette, keep):
        r = rows[rows["track_id"] == tid]
        r = r[np.argsort(r["frame"])]
        pts = np.stack([r["foot_u"], r["foot_v"]], 1).round().astype(np.int32)
        c = tuple(int(x) * 3 // 4 for x in colour)
        cv2.polylines(out, [pts.reshape(-1, 1, 2)], False, c, 1, cv2.LINE_AA)
        cv2.circle(out, (int(pts[-1][0]), int(pts[-1][1])), 3, c, -1, cv2.LINE_AA)
    return out


def predicted_plane(pred: np.ndarray, K: np.ndarray, agents: np.ndarray, d: float,
                    width: int, height: int) -> tuple[np.ndarray, float] | None:
    """The plane of a (relative) prediction over the ground the agents' feet cover, scaled to
    ``d`` (only its orientation is meaningful); None when it cannot be fitted."""
    from staticdepth.errors import InputError
    from staticdepth.geometry.alignment import fit_predicted_plane, ground_mask_from_feet

    rows = agents[agents["foot_v"] >= 0]
    try:
        mask = ground_mask_from_feet(np.stack([rows["foot_u"], rows["foot_v"]], 1), width,
                                     height, width / 80.0)
        n, _ = fit_predicted_plane(pred, K, mask)
    except InputError:
        return None
    return np.asarray(n, float), float(d)


def panel_grid(panels: Sequence[np.ndarray], columns: int = 2, gap: int = 6) -> np.ndarray:
    """Panels (RGB) in rows of ``columns``, padded white to a common size."""
    h = max(p.shape[0] for p in panels)
    w = max(p.shape[1] for p in panels)
    cells = []
    for p in panels:
        c = np.full((h + gap, w + gap, 3), 255, np.uint8)
        c[:p.shape[0], :p.shape[1]] = p
        cells.append(c)
    while len(cells) % columns:
        cells.append(np.full_like(cells[0], 255))
    rows = [np.concatenate(cells[i:i + columns], axis=1) for i in range(0, len(cells), columns)]
    return np.concatenate(rows, axis=0)


def metric_definitions() -> list[str]:
    """One line per metric, as computed by :mod:`staticdepth.metrics`."""
    return ["SiLog = mean(d^2) - mean(d)^2, d = ln(pred) - ln(gt) (no square root, no x100)",
            "AbsRel = mean(|pred - gt| / gt); SqRel = mean((pred - gt)^2 / gt); "
            "RMSE = sqrt(mean((pred - gt)^2)) in metres",
            "protocols: median = each frame's prediction scaled by median(gt) / median(pred) "
            "(Table 1); metric = no rescaling (Table 3)",
            "pixels: the evaluation split's frames, where the ground truth is valid and below the "
            "depth cap"]


def summary_planes(summary: Mapping[str, Any] | None) -> dict[str, tuple[np.ndarray, float]]:
    planes: dict[str, tuple[np.ndarray, float]] = {}
    for name in ("agents", "predicted"):
        p = (summary or {}).get("planes", {}).get(name)
        if p is not None:
            planes[name] = (np.asarray(p["normal"], float), float(p["d"]))
    return planes
