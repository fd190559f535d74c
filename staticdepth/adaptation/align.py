"""Stage align: every frame of ``base`` and ``ft`` aligned to the agents' plane (METHOD.md 4).

``align.mode`` (ground, upright or the paper's Eq. 2) with unit camera height (the outputs
``align`` and ``ft-align`` are in units of the camera height); the predicted plane is fitted on the feet's hull (eroded by
``align.erode_px``, default W/80) minus the frame's agents, unless that leaves fewer than 50
pixels; with ``align.agents_at_contact`` each agent then takes the plane depth at its contact
(people whose foot is hidden: from their top and fitted height, ``align.hidden_contact``).
What depends only on the camera, the plane and the static image (rays, the plane's depth, the
image of the vertical, the colour feet) is computed once per run: one ``AlignCamera`` that every
frame's alignment is given. :func:`align_prediction` is the streamed, resumable per-frame writer
that ``staticdepth align --sequence`` uses too. A prediction whose inverse depth over the walked
ground the plane does not explain (R^2 under ``align.min_ground_r2``: a network that does not see
the ground) is not aligned: its output is the plane's depth with the agents at their contact
(:func:`plane_frame`), and the summary says so.
"""
from __future__ import annotations

import contextlib
from typing import Callable, Mapping

import numpy as np

from staticdepth.adaptation.common import Agents, Workspace
from staticdepth.adaptation.config import AdaptConfig
from staticdepth.geometry.agent_plane import AgentPlane
from staticdepth.geometry.alignment import (agents_at_contact, align_depth, ground_fit_r2,
                                            ground_mask_from_feet, plane_depth)
from staticdepth.geometry.alignment_upright import AlignCamera
from staticdepth.progress import progress

OUTPUTS = {"align": "base", "ft-align": "ft"}
GROUND_R2_FRAMES = 8        # adaptation frames whose ground R^2 decides align.min_ground_r2

AlignFrame = Callable[[int, np.ndarray], np.ndarray]


def align_prediction(ws: Workspace, jobs: Mapping[str, tuple[str, AlignFrame]], config_hash: str,
                     attrs: Mapping | None = None, stage: str = "align",
                     rewrite: bool = False) -> None:
    """Write each output ``out`` of ``jobs = {out: (source prediction, f(i, map) -> map)}``
    frame by frame; outputs complete with ``config_hash`` are skipped (unless ``rewrite``),
    interrupted ones resume."""
    writers = {out: ws.pred_writer(out, config_hash, {"source": src, **dict(attrs or {})},
                                   chunk=8, rewrite=rewrite) for out, (src, _) in jobs.items()}
    if all(w.done for w in writers.values()):
        return ws.skip(stage)
    with contextlib.ExitStack() as stack, ws.reader() as r:
        for w in writers.values():
            stack.enter_context(w)
        start = min(w.written for w in writers.values() if not w.done)
        for i in progress(range(start, ws.n), total=ws.n - start, desc=stage):
            for out, (src, fn) in jobs.items():
                w = writers[out]
                if not w.done and i >= w.written:
                    w.write(i, fn(i, r.prediction(src, i)))
            ws.count(stage)


def ground_region(conf: AdaptConfig, ws: Workspace, feet: np.ndarray) -> np.ndarray:
    """(H, W) bool: the feet's hull eroded by ``align.erode_px`` (default W/80)."""
    erode = ws.width / 80.0 if conf.align.erode_px is None else conf.align.erode_px
    return ground_mask_from_feet(feet, ws.width, ws.height, erode)


def upright_options(align) -> dict:
    """align_depth's keywords of the ``upright`` mode from an AlignConfig."""
    recede = (align.recede_min, align.recede_max) if align.recede_max > 0 else None
    return {"shape": align.shape, "jump_rel": align.jump_rel, "recede": recede,
            "fill": align.fill, "contact_range": align.contact_range,
            "max_pull": np.inf if align.max_pull is None else align.max_pull,
            "recede_push": np.inf if align.recede_push is None else align.recede_push,
            "walked_ratio": np.inf if align.walked_ratio is None else align.walked_ratio,
            "occlude": align.occlude, "step_occlude": align.step_occlude,
            "plane_bound": align.plane_bound}


def person_heights(conf: AdaptConfig, plane: AgentPlane):
    """The people's fitted heights for ``agents_at_contact`` (None with ``align.hidden_contact
    = lowest`` or no person track)."""
    from staticdepth.geometry.agent_contact import PersonHeights

    return PersonHeights.from_plane(plane) if conf.align.hidden_contact == "top" else None


def static_image(r, frames) -> np.ndarray:
    """(H, W, C) float 0-1: the median of the left images of ``frames`` (at most 64, evenly
    spread) of an open SequenceReader: the static camera's scene without its agents."""
    frames = np.asarray(frames)[np.linspace(0, len(frames) - 1, min(len(frames), 64)).astype(int)]
    # one stack at the peak: filled frame by frame, then partitioned in place (overwrite_input)
    first = r.left(int(frames[0]))
    stack = np.empty((len(frames),) + first.shape, first.dtype)
    stack[0] = first
    for k, i in enumerate(frames[1:], 1):
        stack[k] = r.left(int(i))
    return np.median(stack, 0, overwrite_input=True) / 255.0


def align_image(align, r) -> np.ndarray | None:
    """The image an ``AlignConfig`` reads (``uses_image``): the static scene over the open
    SequenceReader's adaptation split (a sequence without one: every frame); None when off."""
    if not align.uses_image:
        return None
    frames = r.split("adapt")
    return static_image(r, frames if len(frames) else range(len(r)))


def aligned_frame(conf: AdaptConfig, K: np.ndarray, normal: np.ndarray, ground: np.ndarray,
                  instances: np.ndarray, rows: np.ndarray, Z: np.ndarray,
                  plane_bound: bool = False, image: np.ndarray | None = None,
                  heights=None, camera: AlignCamera | None = None) -> np.ndarray:
    """One frame's depth ``Z`` aligned as adapt does it (units of the camera height).
    ``plane_bound``: ``align.plane_bound`` applies (the align stage's outputs pass it; the pseudo
    labels do not: labels with it made the fine-tuned U-Net's ft-align worse, docs/gains.md);
    ``image``: the static scene (:func:`static_image`) for ``align.colour_foot``, likewise;
    ``heights``: :func:`person_heights` (people with a hidden foot placed from their top);
    ``camera``: the run's ``AlignCamera(K, W, H, normal, 1.0[, image])`` (:func:`run_camera`;
    else one is built per frame), whose own ``camera.image`` is then the ``image``."""
    m = instances > 0
    # the frame's agents leave the ground mask, unless they would leave too little of it
    agent_mask = m if np.count_nonzero(ground & ~m) >= 50 else None
    opts = {**upright_options(conf.align), "plane_bound": plane_bound and conf.align.plane_bound}
    if image is not None and conf.align.colour_foot:    # align outputs only, as plane_bound
        opts["image"] = image
    A = align_depth(Z, K, normal, 1.0, ground, agent_mask=agent_mask, mode=conf.align.mode,
                    snap_rel=conf.align.snap_rel, camera=camera, **opts).depth
    if conf.align.agents_at_contact:
        A = agents_at_contact(A, K, normal, 1.0, instances, rows, conf.pseudo_labels,
                              heights=heights, camera=camera)[0]
    return A


def run_camera(conf: AdaptConfig, ws: Workspace, plane: AgentPlane) -> AlignCamera:
    """The run's ``AlignCamera``: the sequence's camera, the plane with unit camera height and,
    when the alignment reads it (:func:`align_image`), the static image."""
    image = None
    if conf.align.uses_image:
        with ws.reader() as r:
            image = align_image(conf.align, r)
    return AlignCamera(ws.K, ws.width, ws.height, plane.normal, 1.0, image)


def r2_frames(split, n: int, frames: int = GROUND_R2_FRAMES) -> list[int]:
    """The frames whose ground R^2 decides ``align.min_ground_r2``: ``frames`` evenly spread
    over the adaptation ``split`` (over all ``n`` frames without one)."""
    split = np.asarray(split if len(split) else np.arange(n))
    if not len(split):
        return []
    k = np.unique(np.linspace(0, len(split) - 1, min(frames, len(split))).astype(int))
    return [int(i) for i in split[k]]


def median_r2(values) -> float:
    """The median of the finite R^2 values (NaN when none: too little ground to judge)."""
    r2 = [x for x in values if np.isfinite(x)]
    return float(np.median(r2)) if r2 else float("nan")


def ground_r2(ws: Workspace, agents: Agents, src: str, ground: np.ndarray,
              camera: AlignCamera, frames: int = GROUND_R2_FRAMES) -> float:
    """The median over ``frames`` adaptation frames (:func:`r2_frames`) of
    :func:`~staticdepth.geometry.alignment.ground_fit_r2` of prediction ``src`` over the
    walked ``ground`` less the frame's agents: how well the network sees the agents' ground."""
    with ws.reader() as r:
        return median_r2(ground_fit_r2(r.prediction(src, i), ground & (agents.instances(i) == 0),
                                       camera) for i in r2_frames(ws.adapt_split, ws.n, frames))


def plane_frame(conf: AdaptConfig, K: np.ndarray, normal: np.ndarray, ground: np.ndarray,
                instances: np.ndarray, rows: np.ndarray, heights=None,
                camera: AlignCamera | None = None) -> np.ndarray:
    """One frame as the plane alone describes it (units of the camera height): every pixel the
    plane's depth along its ray (:func:`~staticdepth.geometry.alignment.plane_depth`), then each
    agent at its contact as :func:`aligned_frame` does; for a network that does not see the
    ground (``align.min_ground_r2``)."""
    h, w = instances.shape
    camera = camera if camera is not None else AlignCamera(K, w, h, normal, 1.0)
    A = plane_depth(camera.check(K, normal, 1.0, w, h), ground)
    if conf.align.agents_at_contact:
        A = agents_at_contact(A, K, normal, 1.0, instances, rows, conf.pseudo_labels,
                              heights=heights, camera=camera)[0]
    return A


def run(conf: AdaptConfig, ws: Workspace, agents: Agents, plane: AgentPlane, feet: np.ndarray,
        config_hash: str) -> dict:
    """Writes ``align`` and ``ft-align``; returns, for the summary, each output's
    ``ground_r2`` (:func:`ground_r2` of its source) and the outputs that took the plane alone
    (``plane_only``: under ``align.min_ground_r2``)."""
    ground = ground_region(conf, ws, feet)
    heights = person_heights(conf, plane)
    camera = run_camera(conf, ws, plane)
    r2 = {out: ground_r2(ws, agents, src, ground, camera) for out, src in OUTPUTS.items()}
    plane_only = [out for out in OUTPUTS if r2[out] < conf.align.min_ground_r2]
    for out in plane_only:
        ws.log(f"warning: the {OUTPUTS[out]} prediction does not see the agents' ground (its "
               f"inverse depth over the walked ground: R^2 {r2[out]:.3f} against the plane's, "
               f"under align.min_ground_r2 {conf.align.min_ground_r2:g}); {out} is the plane's "
               f"depth with the agents at their contact, without the network")

    def job(out: str) -> AlignFrame:
        if out in plane_only:
            return lambda i, Z: plane_frame(conf, ws.K, plane.normal, ground,
                                            agents.instances(i), agents.rows(i),
                                            heights=heights, camera=camera)
        return lambda i, Z: aligned_frame(conf, ws.K, plane.normal, ground, agents.instances(i),
                                          agents.rows(i), Z, plane_bound=True,
                                          image=camera.image, heights=heights, camera=camera)

    align_prediction(ws, {out: (src, job(out)) for out, src in OUTPUTS.items()}, config_hash,
                     {"stage": "adapt", "metric": False, "units": "camera heights"})
    return {"ground_r2": {out: (None if not np.isfinite(v) else round(v, 4))
                          for out, v in r2.items()}, "plane_only": plane_only}
