"""Camera height from the agents' height distributions, and the gate on a plane's uncertainty.

Camera height: each inlier track of a class group with a height distribution (people: 90% adults
N(1.70, 0.09) m and 10% children N(1.25, 0.15) m; two-wheelers with riders, cars, buses/trucks:
:data:`staticdepth.geometry.agent_shape.GROUPS`) has ``s_j = H_j / d``. The camera height d is the
maximum of the likelihood ``prod_j p_class(d s_j) d`` (a log-spaced grid, then a parabola), so
children and tall outliers weigh by their probability instead of biasing a mean. Its uncertainty
combines a bootstrap over the tracks (the spread of heights) with the plane's own ``d/H``
uncertainty.

Gate: :func:`plane_gate` says whether a plane is good enough for alignment (the normal's
uncertainty at most ``max_normal_std_deg``, :data:`GATE_STD_DEG` by default, and at least
``min_tracks`` inlier tracks) and, when not, how many inlier tracks it would need: the uncertainty
falls as ``1 / sqrt(tracks)``, so ``tracks * (std / limit)^2``; with agents arriving at a steady
rate the frames needed scale by the same factor. The joint model's uncertainty combines the
bootstrap over tracks with the fit's data-only Laplace uncertainty
(``AgentPlane.normal_std_parts``, :mod:`staticdepth.geometry.agent_plane_boot`); the message names
both. That std covers the error as a 2-D Gaussian's RMS angle does (masks at 1 px: 67% of cameras
within 1 std and 95% within 2 on seeds 0-19, 59% and 97% held out on 20-39, against 63% and 98%
expected). It is the quadrature sum of the bootstrap, the class misfit and the Laplace that it
replaced (gated at 1 degree) over sqrt(2), so the default limit is 1 / sqrt(2) degree: the
verdicts stay those of the sum, and at the limit the error exceeds 1 degree with probability
``exp(-(1 / std)^2)`` = 14%.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.agent_shape import GROUPS, group_of_class

# the default limit on the normal's std (deg): 1 degree is 1.41 std, exceeded with probability 14%
# (see the module doc)
GATE_STD_DEG = 1.0 / math.sqrt(2.0)
CLASS_SETS = {"people": (0, -1), "vehicles": (1, 2, 3, 5, 7), "all": None}


def class_set(name: str) -> tuple[int, ...] | None:
    """Class ids of a ``--classes`` name (people, vehicles, all; all = None)."""
    if name not in CLASS_SETS:
        raise InputError(f"unknown class set {name!r} (use {', '.join(CLASS_SETS)})")
    return CLASS_SETS[name]


def _loglik(d: np.ndarray, s: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """(len(d),) log-likelihood of camera heights d for tracks s (J,) of class groups (J,)."""
    H = d[:, None] * s[None, :]
    total = np.zeros_like(H)
    for g, grp in enumerate(GROUPS):
        m = groups == g
        if not m.any():
            continue
        p = sum(w / (sd * math.sqrt(2 * math.pi)) * np.exp(-0.5 * ((H[:, m] - mu) / sd) ** 2)
                for w, mu, sd in grp.heights)
        total[:, m] = np.log(np.maximum(p, 1e-300))
    return total.sum(1) + len(s) * np.log(d)


def camera_height_ml(s: np.ndarray, groups: np.ndarray) -> float:
    """Maximum-likelihood camera height (m) from track scales s (J,) = H_j / d and their groups."""
    med = float(np.median([GROUPS[g].typical_height[0] for g in groups]) / np.median(s))
    grid = med * np.exp(np.linspace(-0.7, 0.7, 281))
    ll = _loglik(grid, s, groups)
    k = int(np.clip(np.argmax(ll), 1, len(grid) - 2))
    y0, y1, y2 = ll[k - 1:k + 2]
    den = y0 - 2 * y1 + y2
    off = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    step = math.log(grid[1] / grid[0])
    return float(grid[k] * math.exp(float(np.clip(off, -1, 1)) * step))


def camera_height_from_agents(plane, classes: tuple[int, ...] | None = (0, -1),
                              bootstrap: int = 200, seed: int = 0) -> tuple[float, float, int]:
    """(camera height m, its standard deviation m, tracks used) from the plane's inlier tracks of
    ``classes`` (None = every class). Raises InputError when no such track exists."""
    cls = np.asarray(plane.extra.get("classes", np.full(len(plane.track_ids), -1)))
    use = plane.inliers & (np.ones(len(cls), bool) if classes is None
                           else np.isin(cls, list(classes)))
    if not use.any():
        raise InputError("no inlier track of the requested classes to scale the camera height with")
    s, groups = plane.track_scale[use], group_of_class(cls[use])
    d = camera_height_ml(s, groups)
    rng = np.random.default_rng(seed)
    rel = 0.0
    if len(s) >= 3 and bootstrap > 0:
        boots = []
        for _ in range(bootstrap):
            k = rng.integers(0, len(s), len(s))
            boots.append(camera_height_ml(s[k], groups[k]))
        rel = float(np.std(boots, ddof=1)) / d
    elif len(s) < 3:
        rel = float("nan")
    if math.isfinite(plane.d_over_h_std) and plane.d_over_agent_height > 0:
        rel = math.hypot(rel, plane.d_over_h_std / plane.d_over_agent_height)
    return d, d * rel, int(use.sum())


def with_camera_height_from_agents(plane, agent_height_m: float | None = None, seed: int = 0):
    """``plane`` with its camera height from its agents, the one rule of ``ground-plane`` and
    ``adapt``: one fixed agent height ``agent_height_m`` when given, else the per-class height
    distributions (people's inlier tracks, else every class's) with a bootstrap uncertainty.
    Raises InputError when no inlier track can give it."""
    if agent_height_m is not None:
        from staticdepth.geometry.agent_plane import camera_height_from_prior

        return plane.with_camera_height(camera_height_from_prior(plane, agent_height_m),
                                        f"agent height prior {agent_height_m:g} m")
    for name in ("people", "all"):
        try:
            d, sd, k = camera_height_from_agents(plane, CLASS_SETS[name], seed=seed)
        except InputError:
            continue
        return plane.with_camera_height(d, f"height distributions of {name} ({k} tracks)", sd)
    raise InputError("no inlier agent track to take the camera height from (give the camera "
                     "height)")


@dataclass(frozen=True)
class PlaneGate:
    """Verdict on a plane: ``ok``; the normal's uncertainty (deg) and inlier tracks it rests on;
    ``tracks_needed`` inlier tracks for the limit (estimated from the 1/sqrt(n) scaling) and
    ``frames_factor`` = how many times more frames that takes; ``message`` one line."""

    ok: bool
    normal_std_deg: float
    max_normal_std_deg: float
    tracks: int
    tracks_needed: int
    frames_factor: float
    message: str

    def to_dict(self) -> dict:
        return {"ok": self.ok, "normal_std_deg": _num(self.normal_std_deg),
                "max_normal_std_deg": self.max_normal_std_deg, "tracks": self.tracks,
                "tracks_needed": self.tracks_needed, "frames_factor": _num(self.frames_factor),
                "message": self.message}


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _parts(plane) -> str:
    """`` (bootstrap B, Laplace L)`` when the plane has them (joint model), else empty."""
    q = getattr(plane, "normal_std_parts", {})
    named = [(name, q[k]) for name, k in (("bootstrap", "bootstrap_std_deg"),
                                          ("class misfit", "class_misfit_deg"),
                                          ("Laplace", "laplace_std_deg"))
             if k in q and (k != "class_misfit_deg" or q[k] > 0)]
    return f" ({', '.join(f'{n} {v:.2f}' for n, v in named)})" if len(named) > 1 else ""


def plane_gate(plane, max_normal_std_deg: float = GATE_STD_DEG, min_tracks: int = 3) -> PlaneGate:
    """Whether ``plane`` (an AgentPlane) is good enough for alignment; see the module doc.

    A plane without a finite uncertainty (bootstrap off, or fewer than 3 inlier tracks) is
    refused: at least ``max(min_tracks, 2 * tracks)`` tracks are asked for."""
    if not max_normal_std_deg > 0:
        raise InputError(f"the normal uncertainty limit must be positive, got {max_normal_std_deg}")
    tracks = int(np.count_nonzero(plane.inliers))
    std = float(plane.normal_std_deg)
    if not math.isfinite(std) or tracks < min_tracks:
        need = max(min_tracks, 2 * tracks)
        return PlaneGate(False, std, max_normal_std_deg, tracks, need, need / max(tracks, 1),
                         f"ground plane too uncertain: {tracks} inlier track(s), uncertainty "
                         f"unknown; need at least {need} tracks (about "
                         f"{need / max(tracks, 1):.1f}x the frames)")
    parts = _parts(plane)
    if std <= max_normal_std_deg:
        return PlaneGate(True, std, max_normal_std_deg, tracks, tracks, 1.0,
                         f"ground plane accepted: normal uncertainty {std:.2f} deg{parts} <= "
                         f"{max_normal_std_deg:.2g} deg over {tracks} inlier tracks")
    factor = (std / max_normal_std_deg) ** 2
    need = int(math.ceil(tracks * factor))
    return PlaneGate(False, std, max_normal_std_deg, tracks, need, factor,
                     f"ground plane too uncertain: normal uncertainty {std:.2f} deg{parts} > "
                     f"{max_normal_std_deg:.2g} deg over {tracks} inlier tracks; need about {need} "
                     f"tracks ({factor:.1f}x the frames)")
