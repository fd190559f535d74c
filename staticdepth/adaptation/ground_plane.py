"""Stage ground_plane: the agents' plane from the adaptation split (METHOD.md section 2).

Streams (instance map, rows) pairs of the adaptation frames into the tracker (only observation
rows are kept), fits :func:`staticdepth.geometry.agent_plane.fit_agent_plane`, and writes
``<SEQ>.h5.adapt/ground_plane.json``: the plane (in units of the camera height), its tracks'
classes, the feet of every agent of the split (the ground region the alignment fits the predicted
plane in), the stage hash and the sequence identity. A plane whose normal is too uncertain for
alignment (:func:`staticdepth.geometry.agent_plane_gate.plane_gate`: the bootstrap and the
Laplace uncertainty, both in the file) is flagged with the tracks and frames it would need.
"""
from __future__ import annotations

import json
import os
from dataclasses import replace

import numpy as np

from staticdepth.adaptation.common import Agents, Workspace
from staticdepth.adaptation.config import AdaptConfig
from staticdepth.adaptation.scale import known_camera_height
from staticdepth.errors import InputError
from staticdepth.fileio import atomic_write_json
from staticdepth.geometry.agent_plane import AgentPlane, fit_agent_plane
from staticdepth.geometry.agent_plane_gate import plane_gate
from staticdepth.ground_plane import bootstrap_bar

FILE = "ground_plane.json"


def _load(ws: Workspace, config_hash: str) -> tuple[AgentPlane, np.ndarray] | None:
    path = ws.path(FILE)
    if not os.path.exists(path):
        return None
    try:
        with open(path) as f:
            d = json.load(f)
    except (OSError, json.JSONDecodeError):
        return None
    if d.get("config_hash") != config_hash or d.get("sequence_id") != ws.identity:
        return None
    plane = AgentPlane.from_dict(d["plane"], path)
    classes = {int(k): int(v) for k, v in d["track_classes"].items()}
    plane = replace(plane, extra={**plane.extra, "classes": np.array([classes[int(t)]
                                                                      for t in plane.track_ids])})
    return plane, np.asarray(d["feet"], dtype=np.float64).reshape(-1, 2)


def plane_config(conf: AdaptConfig, camera_height_m: float | None = None):
    """The plane settings; with the motion detector, ``classes="auto"`` means people only: its
    classes are shape guesses (upright = person), and a car taken for a person or a person for a
    car gets the wrong body model (independent scenes, benchmarks/bench_motion_plane.py: i4
    2.8 deg off with every class, 0.5 with people). A known ``camera_height_m`` (given, or the
    sequence's) enters the joint fit as a prior (``plane.known_height_sd``) unless
    ``plane.known_height_m`` is set."""
    plane = conf.plane
    if conf.detector.name == "motion" and plane.classes == "auto":
        plane = replace(plane, classes=(0,))
    return plane.with_known_height(camera_height_m)


def run(conf: AdaptConfig, ws: Workspace, agents: Agents, config_hash: str
        ) -> tuple[AgentPlane, np.ndarray]:
    """(plane without a camera height, foot points (M, 2) of the adaptation split)."""
    from staticdepth import tracking

    done = _load(ws, config_hash)
    if done is not None:
        ws.skip("ground_plane")
        return done
    split = ws.adapt_split
    # Instance maps always: ground-truth track ids are kept, and the occlusion test (feet or head
    # touching another instance: riders, people behind cars, umbrellas) needs the masks.
    pairs = ((agents.instances(i), agents.rows(i)) for i in split)
    obs = tracking.observations_from_instances(pairs, conf.tracking)
    ws.count("ground_plane", len(split))
    if len(obs) < 3:
        raise InputError(f"only {len(obs)} usable agent observations in the adaptation split: "
                         "the ground plane needs tracked agents (check the detector)")
    known = known_camera_height(conf, ws.camera_height_m)
    pconf = plane_config(conf, None if known is None else known[0])
    plane = fit_agent_plane(ws.K, obs, pconf, bootstrap_bar(pconf.bootstrap))
    if "left_out" in plane.extra:
        lo = plane.extra["left_out"]
        ws.log(f"ground plane: {lo['group']} left out (leaving them out moved the normal by "
               f"{lo['misfit_deg']:.1f} deg > plane.max_class_misfit_deg)")
    # The ground region covered by the agents' feet: every agent of the adaptation split (the
    # plane fit keeps only clean person tracks; the region should not shrink with that filter).
    feet = [np.stack([r["foot_u"], r["foot_v"]], 1) for r in
            (agents.rows(i) for i in split) if len(r)]
    feet = [f[f[:, 1] >= 0] for f in feet]
    feet = np.concatenate(feet) if feet else np.zeros((0, 2))
    n_in = int(np.count_nonzero(plane.inliers))
    gate = plane_gate(plane) if np.isfinite(plane.normal_std_deg) else None
    if gate is None and n_in >= 3 and conf.plane.bootstrap == 0:
        ws.log(f"warning: the ground plane rests on {n_in} agent track(s); its uncertainty was "
               "not measured (plane.bootstrap=0), so neither the plane nor the metric depth is "
               "checked")
    elif n_in < 5 or gate is None:
        ws.log(f"warning: the ground plane rests on {n_in} agent track(s) (uncertainty "
               f"{plane.normal_std_deg:.2f} deg): use more adaptation frames or a better detector")
    elif not gate.ok:       # flagged, not stopped: the scale stage gates the metric depth
        ws.log(f"warning: {gate.message}; adapt goes on with it (alignment and metric scale "
               "inherit its error)")
    classes = np.asarray(plane.extra.get("classes", np.full(len(plane.track_ids), -1)))
    os.makedirs(ws.dir, exist_ok=True)
    atomic_write_json(ws.path(FILE), {
        "config_hash": config_hash, "sequence_id": ws.identity, "plane": plane.to_dict(),
        "track_classes": {str(int(t)): int(c) for t, c in zip(plane.track_ids, classes)},
        "feet": feet.tolist()})
    return _load(ws, config_hash)
