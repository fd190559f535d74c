"""Stage scale: metric outputs ``align-metric`` and ``ft-align-metric`` (METHOD.md section 5).

The camera height: ``scale.camera_height_m``, else the sequence's (unless
``scale.sequence_height`` is false), else the agents (per-class height distributions, or one
fixed ``scale.agent_height_m``; the same rule as ``ground-plane``).
The aligned maps are in units of the camera height, so ``metric_scale = plane`` multiplies them
by H_c; ``anchor`` uses the temporal median of the per-frame anchor-pixel scales instead (frames
whose anchor an agent covers are skipped, unless every frame's is). Both scales are reported.
One pass over the frames measures the anchors, a second writes the metric maps.
Gate: when the plane normal's and the camera height's uncertainty make the metric depth's relative
error over the agents' feet larger than ``scale.max_rel_error``
(:func:`staticdepth.geometry.scale.metric_check`), no metric map is written and the reason is
returned (a wrong metric depth is worse than none); a plane without an uncertainty (fewer than 3
inlier tracks) is only flagged.
"""
from __future__ import annotations

import numpy as np

from staticdepth.adaptation.align import OUTPUTS as ALIGNED
from staticdepth.adaptation.common import Agents, Workspace
from staticdepth.adaptation.config import AdaptConfig
from staticdepth.geometry.agent_plane import AgentPlane
from staticdepth.geometry.agent_plane_gate import with_camera_height_from_agents
from staticdepth.geometry.scale import metric_check, scale_from_anchor, temporal_scale
from staticdepth.progress import progress


def known_camera_height(conf: AdaptConfig, sequence_height_m: float | None
                        ) -> tuple[float, str] | None:
    """(camera height in metres, "given" or "sequence"), or None: the agents give it.
    ``sequence_height_m``: the sequence's stored height (None: it has none)."""
    s = conf.scale
    if s.camera_height_m is not None:
        return s.camera_height_m, "given"
    if sequence_height_m is not None and s.sequence_height:
        return sequence_height_m, "sequence"
    return None


def with_camera_height(conf: AdaptConfig, ws: Workspace, plane: AgentPlane) -> AgentPlane:
    known = known_camera_height(conf, ws.camera_height_m)
    if known is not None:
        return plane.with_camera_height(*known)
    return with_camera_height_from_agents(plane, conf.scale.agent_height_m, seed=conf.plane.seed)


def anchor_scales(ws: Workspace, agents: Agents, plane: AgentPlane) -> dict[str, float]:
    """Temporal anchor scale of each aligned prediction."""
    per: dict[str, list[float]] = {name: [] for name in ALIGNED}
    per_any: dict[str, list[float]] = {name: [] for name in ALIGNED}
    with ws.reader() as r:
        for i in progress(range(ws.n), desc="anchor scale"):
            m = agents.instances(i) > 0
            for name in ALIGNED:
                A = r.prediction(name, i)
                s = scale_from_anchor(A, ws.K, plane.normal, plane.camera_height_m, agent_mask=m)
                per[name].append(s.scale)
                if not np.isfinite(s.scale):     # kept for when agents cover every anchor
                    s = scale_from_anchor(A, ws.K, plane.normal, plane.camera_height_m)
                per_any[name].append(s.scale)
            ws.count("scale")
    return {name: temporal_scale(per[name] if np.isfinite(per[name]).any() else per_any[name])
            for name in ALIGNED}


def check(conf: AdaptConfig, ws: Workspace, plane: AgentPlane, feet: np.ndarray
          ) -> tuple[bool, str | None]:
    """(refuse the metric maps, why or a warning); see the module doc."""
    given = plane.camera_height_source in ("given", "sequence")
    return metric_check(ws.K, plane.normal, plane.normal_std_deg, feet, plane.camera_height_m,
                        None if given else plane.camera_height_std_m, conf.scale.max_rel_error,
                        unmeasured=conf.plane.bootstrap == 0)


def run(conf: AdaptConfig, ws: Workspace, agents: Agents, plane: AgentPlane, config_hash: str
        ) -> tuple[dict[str, float], dict[str, float]]:
    """Write the metric maps; returns (scale used, anchor scale) per aligned prediction."""
    outs = {f"{name}-metric": name for name in ALIGNED}
    if all(ws.pred_done(o, config_hash) for o in outs):
        ws.skip("scale")
        with ws.reader() as r:
            attrs = {name: r.prediction_attrs(o) for o, name in outs.items()}
        return ({n: float(a["scale"]) for n, a in attrs.items()},
                {n: float(a["anchor_scale"]) for n, a in attrs.items()})
    anchor = anchor_scales(ws, agents, plane)
    scales = {name: (anchor[name] if conf.scale.metric_scale == "anchor"
                     else float(plane.camera_height_m)) for name in ALIGNED}
    for o, name in outs.items():
        w = ws.pred_writer(o, config_hash, {"stage": "adapt", "metric": True, "source": name,
                                            "scale": scales[name], "anchor_scale": anchor[name],
                                            "camera_height_m": plane.camera_height_m}, chunk=8)
        if w.done:
            continue
        with w, ws.reader() as r:
            for i in progress(range(w.start, ws.n), desc=o):
                w.write(i, r.prediction(name, i) * np.float32(scales[name]))
    return scales, anchor
