"""Stage pseudo_labels: each adaptation frame's label from the base inverse depth and its agents.

With ``pseudo_labels.dense_mode`` the aligned labels take that mode's depth on the static pixels
it keeps stable over the split (:func:`staticdepth.pseudo_labels.stable_depth`); with
``pseudo_labels.untrusted`` the static pixels it does not keep stable (measured with
``dense_mode``, else ``align.mode``) take the base network's value or leave the loss; with
``pseudo_labels.grazing`` agents whose contact's plane depth is less certain than the base's
depth take the base's (:func:`staticdepth.pseudo_labels.grazing_agents`).
Written to ``<SEQ>.h5.adapt/labels.h5`` (one (H, W) float32 label per frame of the adaptation
split, with the number of relabelled agent pixels per frame in its ``rows``).
"""
from __future__ import annotations

import numpy as np

from staticdepth.adaptation.common import Agents, Workspace
from staticdepth.adaptation.config import AdaptConfig
from staticdepth.geometry.agent_plane import AgentPlane
from staticdepth.progress import progress
from staticdepth.pseudo_labels import (aligned_pseudo_label, contact_label_std, grazing_agents,
                                       network_space, plane_depth_rel_std, plane_pseudo_label,
                                       pseudo_label, trusted_label)

ROWS = np.dtype([("frame", np.int32), ("agent_pixels", np.int64)])


def run(conf: AdaptConfig, ws: Workspace, agents: Agents, config_hash: str,
        plane: AgentPlane | None = None, feet: np.ndarray | None = None) -> int:
    """Write the labels; returns the number of agent pixels relabelled.

    ``pseudo_labels.source = "plane"`` reads each agent's label from the agents' ``plane`` (mapped
    into the network's space by a fit over the ground region of ``feet``); ``"aligned"`` labels
    every pixel with the frame's alignment (``align.mode``, agents at their contact) mapped back
    into the network's space the same way (a frame where that map does not exist - the network's
    ground does not recede against the plane - gets the paper's labels, as with "plane"). With
    ``untrusted`` other than ``label`` the map is fitted over the trusted pixels instead
    (:func:`staticdepth.pseudo_labels.trusted_label`; the ground's when they give none), so a
    frame whose ground does not recede still gets shift-free labels (the paper's labels carry the
    network's shift, which the scale-only loss cannot take); only a frame with neither map falls
    back to them. A base network under ``align.min_ground_r2`` (its ground is noise, and its
    ``align`` output the plane alone) is labelled with the plane's map (:func:`plane_label`)."""
    pl = conf.pseudo_labels
    if pl.source == "plane":
        from staticdepth.adaptation.align import ground_region
        from staticdepth.geometry.projection import ray_grid

        plane_inv = (ray_grid(ws.K, ws.width, ws.height) @ np.asarray(plane.normal)
                     ).astype(np.float32)
        ground = ground_region(conf, ws, feet)

        def label_frame(i, inv):
            return plane_pseudo_label(inv, agents.instances(i), agents.rows(i), plane_inv, ground,
                                      pl, label_ground=pl.label_ground)
    elif pl.source == "aligned":
        from staticdepth.adaptation.align import (aligned_frame, ground_region, person_heights,
                                                  plane_frame)
        from staticdepth.geometry.alignment import depth_from_inverse
        from staticdepth.geometry.projection import ray_grid

        plane_inv = (ray_grid(ws.K, ws.width, ws.height) @ np.asarray(plane.normal)
                     ).astype(np.float32)
        ground = ground_region(conf, ws, feet)
        label_std = (plane_depth_rel_std(ws.K, plane.normal, plane.normal_std_deg, ws.width,
                                         ws.height, pl.contact_row_px)
                     if pl.grazing != "off" else None)
        dense: list = []            # computed on the first frame labelled (not when skipped)
        heights = person_heights(conf, plane)
        # a base network that does not see the ground (align.min_ground_r2) learns the plane's
        # depth, as its `align` output is, instead of its own alignment
        plane_only = below_ground_bar(conf, ws, agents, plane, ground)

        def label_frame(i, inv):
            inst = agents.instances(i)
            if plane_only:      # every pixel the plane's, one scale: the network's median
                A = plane_frame(conf, ws.K, plane.normal, ground, inst, agents.rows(i),
                                heights=heights)
                return plane_label(inv, A)
            A = aligned_frame(conf, ws.K, plane.normal, ground, inst, agents.rows(i),
                              depth_from_inverse(inv), heights=heights)
            if (pl.dense_mode or pl.untrusted in ("base", "depth", "ignore")) and not dense:
                dense.extend(_dense(conf, ws, agents, plane, ground))
            if pl.dense_mode:           # stable pixels of the dense mode, off the frame's agents
                A = np.where(dense[1] & (inst == 0), dense[0], A)
            if pl.untrusted != "label":     # agents and stable static pixels, shift-free
                trusted = np.ones(inst.shape, bool) if pl.untrusted == "aligned" else (
                    dense[1] | (inst > 0))
                label = trusted_label(inv, A, trusted, pl.untrusted)
                if label is None:   # no map over them: the ground's, as aligned_pseudo_label
                    _, fit = network_space(inv, plane_inv, ground & (inst == 0), "aligned")
                    if fit is None:     # neither (an untrained network): the paper's labels,
                        # which carry its shift (no frame of the independent scenes i1-i4, h1)
                        return pseudo_label(inv, inst, agents.rows(i), pl)
                    label = trusted_label(inv, A, trusted, pl.untrusted, fit=fit)
                if label_std is not None:   # agents whose contact grazes the ground
                    std, on_agents = contact_label_std(label_std, inst, agents.rows(i), pl)
                    label = grazing_agents(label, inv, std, on_agents, pl.grazing)
                return label, trusted & np.isfinite(label)
            label, m = aligned_pseudo_label(inv, A, plane_inv, ground & (inst == 0))
            if not m.any():     # the network's ground does not recede: its own contact values
                return pseudo_label(inv, inst, agents.rows(i), pl)
            return label, m
    else:
        def label_frame(i, inv):
            return pseudo_label(inv, agents.instances(i), agents.rows(i), pl)
    split = ws.adapt_split
    w = ws.frame_writer("labels.h5", n=len(split), shape=(ws.height, ws.width),
                        dtype=np.float32, config_hash=config_hash, rows_dtype=ROWS, chunk=16,
                        attrs={"first_frame": split.start})
    if w.done:
        ws.skip("pseudo_labels")
    else:
        with w, ws.frame_file("inverse-base.h5") as inv:
            for k in progress(range(w.start, len(split)), desc="pseudo labels"):
                i = split[k]
                label, m = label_frame(i, inv[i])
                # the agents' labelled pixels (the mask is every labelled pixel with "aligned")
                on_agents = int((m & (agents.instances(i) > 0)).sum())
                w.write(k, label, np.array([(k, on_agents)], ROWS))
                ws.count("pseudo_labels")
    with ws.frame_file("labels.h5") as f:
        return int(f._f["rows"]["agent_pixels"].sum())


def below_ground_bar(conf: AdaptConfig, ws: Workspace, agents: Agents, plane: AgentPlane,
                     ground: np.ndarray) -> bool:
    """Whether the base prediction's ground R^2 (:func:`staticdepth.adaptation.align.ground_r2`)
    is under ``align.min_ground_r2``: its align output is then the plane alone, and so are its
    labels' maps."""
    from staticdepth.adaptation.align import ground_r2
    from staticdepth.geometry.alignment_upright import AlignCamera

    if conf.align.min_ground_r2 <= 0:
        return False
    camera = AlignCamera(ws.K, ws.width, ws.height, plane.normal, 1.0)
    return bool(ground_r2(ws, agents, "base", ground, camera) < conf.align.min_ground_r2)


def plane_label(inv: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A frame's labels from the plane's map ``A`` (:func:`~staticdepth.adaptation.align.
    plane_frame`) for a base network under ``align.min_ground_r2``: ``c / A`` on every pixel, ``c``
    the network's median inverse depth times the map's median depth (its fit to a network whose
    ground is noise would be noise; the loss takes a scale, ``si``, or a scale and a shift,
    ``ssi``), and the mask of pixels labelled."""
    ok = np.isfinite(A) & (A > 0) & np.isfinite(inv) & (inv > 0)
    if not ok.any():
        return np.full(A.shape, np.nan, np.float32), ok
    c = np.float32(np.median(inv[ok]) * np.median(A[ok]))
    return np.where(ok, c / np.where(ok, A, 1), np.nan).astype(np.float32), ok


def _dense(conf: AdaptConfig, ws: Workspace, agents: Agents, plane: AgentPlane, ground: np.ndarray):
    """``pseudo_labels.dense_mode``'s alignment of the base prediction on ``dense_frames`` frames
    spread evenly over the adaptation split: (its per-pixel median depth, the mask of pixels it
    keeps stable within ``dense_spread``) - :func:`staticdepth.pseudo_labels.stable_depth`."""
    from dataclasses import replace

    from staticdepth.adaptation.align import aligned_frame, person_heights
    from staticdepth.geometry.alignment import depth_from_inverse
    from staticdepth.pseudo_labels import stable_depth

    pl = conf.pseudo_labels
    dconf = replace(conf, align=replace(conf.align, mode=pl.dense_mode or conf.align.mode))
    split = ws.adapt_split
    picks = np.unique(np.linspace(0, len(split) - 1, min(pl.dense_frames, len(split))).round()
                      .astype(int))
    depths, static = [], []
    heights = person_heights(dconf, plane)
    with ws.frame_file("inverse-base.h5") as inv:
        for k in progress(picks, desc="stable labels"):
            i = split[k]
            inst = agents.instances(i)
            depths.append(aligned_frame(dconf, ws.K, plane.normal, ground, inst, agents.rows(i),
                                        depth_from_inverse(inv[i]), heights=heights))
            static.append(inst == 0)
    return stable_depth(np.stack(depths), np.stack(static), pl.dense_spread)
