"""Pseudo labels from a network's own prediction and agent masks (METHOD.md section 1).

Each agent's label is the prediction at its ground contact, copied over its whole mask, in the
network's native inverse-depth space (so labels share its per-image scale and shift). The contact
is the lowest mask pixel (largest v; ties: the median column of that row), or with
``contact="bottom_rows"`` the median over the mask's bottom rows. Riders take their vehicle's
value, bags and umbrellas the nearest person's (:mod:`staticdepth.detectors.grouping`). Every other
pixel keeps the prediction.

With ``label_source="plane"`` (:func:`plane_pseudo_label`) the contact value is read from the
agents' ground plane instead, mapped into the network's inverse-depth space by the scale and shift
that fit the network's ground to the plane in that frame: on the independent scenes of
``tests/indep_scenes.py`` (i1, 452 person observations, built-in network) the label's error
against the person's true depth falls from 0.200 (own contact) to 0.041 (plane contact).
The default, ``source="aligned"`` (:func:`aligned_pseudo_label`), labels every pixel with the
frame's alignment mapped back into the network's space: agents and the rest of the image move
together, so the fine-tuned network's agents improve against the truth on every independent scene
with both test networks (plane labels, agents only, leave i2's agents worse: the image they sit in
keeps the network's error; docs/gains.md, fine-tuning). With ``untrusted`` (default ``base``)
adapt keeps the aligned label only on the agents and the static pixels whose alignment repeats
over the split, shift-free (:func:`trusted_label`); the rest take the base's own shape.
``untrusted="aligned"`` labels every pixel with the alignment, shift-free: with the U-Net that
fails on the view ft-align 0.139 / 0.069 / 0.146 / 0.255 -> 0.118 / 0.070 / 0.136 / 0.230 on
i1-i4 (chosen on i1, i3) but 0.127 -> 0.132 on a held-out scene, and its fine-tuned agents
worse on four of five scenes (i4 0.389 -> 0.464, base 0.460): not the default (docs/gains.md).
``grazing`` (off by default) distrusts agents whose label is less certain than the base
(:func:`grazing_agents`): on the low cameras (i4, held-out h3) the labels' tail comes from
contacts not seen (cut off by the image's edge or hidden behind another agent: 84 of 412 / 96
of 426 agent-frames, median error 0.38 / 0.53), not from grazing rays; dropping them from the
loss or blending in the base did not improve the fine-tuned agents beyond seed noise and made
built-in i4 ``ft`` worse (docs/gains.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from staticdepth.dataset.schema import ACCESSORY_CLASSES, AGENT_CLASSES
from staticdepth.detectors.grouping import label_sources
from staticdepth.errors import InputError

CONTACTS = ("lowest", "bottom_rows")
LABEL_SOURCES = ("prediction", "plane", "aligned")
UNTRUSTED = ("label", "base", "depth", "ignore", "aligned")
GRAZING = ("off", "ignore", "base", "blend")


@dataclass(frozen=True)
class PseudoLabelConfig:
    contact: str = "lowest"            # "lowest" pixel, or median over "bottom_rows"
    bottom_rows: int = 4               # rows used by "bottom_rows" (METHOD.md: 3-5)
    accessory_reach: float = 0.5       # bag-to-person distance limit, x the person's pixel height
    classes: frozenset = field(default_factory=lambda: AGENT_CLASSES | ACCESSORY_CLASSES)
    source: str = "aligned"            # "aligned": every pixel from the frame's alignment
    #                                    (aligned_pseudo_label); "prediction": agents take the
    #                                    network's own contact value (the paper's); "plane": the
    #                                    agents' plane at the contact, mapped into the network's
    #                                    space (plane_pseudo_label)
    label_ground: bool = False         # "plane": the ground pixels take the plane's value too
    dense_mode: str = ""               # "aligned": an alignment mode (e.g. "upright") whose depth
    #                                    replaces align.mode's on the static pixels it keeps
    #                                    stable over the adaptation split ("" = off)
    dense_spread: float = 0.03         # dense_mode: a pixel is stable when its depth's median
    #                                    absolute deviation over the split is <= this x its median
    dense_frames: int = 32             # dense_mode: frames (evenly spaced) measuring the spread
    untrusted: str = "base"            # "aligned": the static pixels whose label is not stable
    #                                    over the split (dense_spread, measured with dense_mode or
    #                                    else align.mode): "label" keeps it, "base" takes the base
    #                                    network's own value less its shift (its shape is kept
    #                                    there), "depth" the base's depth at the labels' scale
    #                                    (c x inv), "ignore" leaves them out of the loss; agents and
    #                                    stable pixels take s / aligned depth (shift-free);
    #                                    "aligned": no stability test, every pixel takes
    #                                    s / aligned (fitted over all of them), shift-free
    grazing: str = "off"               # agents whose label's expected error (plane_depth_rel_std
    #                                    at the contact) exceeds the base's on the frame's agents
    #                                    (grazing_agents): "ignore" leaves them out of the loss,
    #                                    "base" takes the base's depth at the labels' scale,
    #                                    "blend" their inverse-variance mix in log depth, "off"
    #                                    keeps the label (untrusted != "label" only)
    contact_row_px: float = 1.0        # grazing: the contact row's error (the lowest mask pixel's
    #                                    row and the mask's edge, half a row each)

    def __post_init__(self):
        from staticdepth.config import check_ranges

        check_ranges(self, "pseudo_labels.", {"bottom_rows": ">=1", "accessory_reach": ">=0",
                                              "dense_spread": ">=0", "dense_frames": ">=1",
                                              "contact_row_px": ">=0"})
        if self.contact not in CONTACTS:
            raise InputError(f"pseudo-label contact must be one of {CONTACTS}, got {self.contact!r}")
        if self.source not in LABEL_SOURCES:
            raise InputError(f"pseudo_labels.source must be one of {LABEL_SOURCES}, got "
                             f"{self.source!r}")
        if self.dense_mode not in ("", "ground", "eq2", "upright"):
            raise InputError(f"pseudo_labels.dense_mode must be '', ground, eq2 or upright, got "
                             f"{self.dense_mode!r}")
        if self.untrusted not in UNTRUSTED:
            raise InputError(f"pseudo_labels.untrusted must be one of {', '.join(UNTRUSTED)}, got "
                             f"{self.untrusted!r}")
        if self.grazing not in GRAZING:
            raise InputError(f"pseudo_labels.grazing must be one of {', '.join(GRAZING)}, got "
                             f"{self.grazing!r}")
        if not self.contact_row_px >= 0:
            raise InputError(f"pseudo_labels.contact_row_px must be >= 0, got "
                             f"{self.contact_row_px}")
        if not (self.dense_spread > 0 and self.dense_frames >= 2):
            raise InputError(f"need pseudo_labels.dense_spread > 0 and dense_frames >= 2 (got "
                             f"{self.dense_spread}, {self.dense_frames})")
        if not 1 <= self.bottom_rows <= 50:
            raise InputError(f"bottom_rows must be in 1..50, got {self.bottom_rows}")



PRESETS = {"paper": PseudoLabelConfig(source="prediction"),
           "robust": PseudoLabelConfig(source="prediction", contact="bottom_rows")}


def contact_value(inv_depth: np.ndarray, mask: np.ndarray, conf: PseudoLabelConfig = PRESETS["paper"]
                  ) -> float:
    """The prediction at the mask's ground contact (NaN for an empty mask)."""
    vs, us = np.nonzero(mask)
    if len(vs) == 0:
        return float("nan")
    v_low = vs.max()
    if conf.contact == "lowest":
        row_us = np.sort(us[vs == v_low])
        return float(inv_depth[v_low, row_us[(len(row_us) - 1) // 2]])
    sel = vs > v_low - conf.bottom_rows
    return float(np.median(inv_depth[vs[sel], us[sel]]))


def pseudo_label(inv_depth: np.ndarray, instances: np.ndarray, agents: np.ndarray,
                 conf: PseudoLabelConfig = PRESETS["paper"],
                 contacts: dict[int, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Label one frame.

    Args:
        inv_depth: (H, W) the network's relative inverse depth for this frame.
        instances: (H, W) uint16 instance map (0 = background).
        agents: this frame's AGENT_DTYPE rows (``instance_id``, ``class_id``).
        contacts: instance id -> contact value known otherwise (a hidden foot placed from the
            top, :func:`staticdepth.geometry.agent_contact.contacts_from_top`), used instead of
            the value at its lowest pixel.
    Returns:
        label (H, W) float32 and the boolean mask of relabelled (agent) pixels.
    """
    inv_depth = np.asarray(inv_depth, dtype=np.float32)
    if inv_depth.shape != np.shape(instances):
        raise InputError(f"prediction {inv_depth.shape} and instance map {np.shape(instances)} "
                         "differ in size")
    rows = agents[np.isin(agents["class_id"], list(conf.classes))]
    sources = label_sources(instances, rows, accessory_reach=conf.accessory_reach)
    label = inv_depth.copy()
    agent_mask = np.zeros(inv_depth.shape, bool)
    values: dict[int, float] = {}
    for iid, src in sources.items():
        if src not in values:
            values[src] = (contacts[src] if contacts and src in contacts
                           else contact_value(inv_depth, instances == src, conf))
        m = instances == iid
        label[m] = values[src]
        agent_mask |= m
    return label, agent_mask


def plane_pseudo_label(inv_depth: np.ndarray, instances: np.ndarray, agents: np.ndarray,
                       plane_inv: np.ndarray, ground_mask: np.ndarray,
                       conf: PseudoLabelConfig = PRESETS["paper"], *, label_ground: bool = False
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Label one frame from the agents' plane.

    plane_inv: (H, W) the plane's inverse depth ``n . r / d`` (any d: the fit absorbs it; <= 0
    above its horizon); ground_mask: (H, W) bool ground pixels (this frame's agents are removed).
    The network's ``inv_depth`` on the ground is fitted as ``s plane_inv + t`` (robust); each
    agent (grouped as in :func:`pseudo_label`) takes ``s plane_inv + t`` at its contact, and with
    ``label_ground`` the ground pixels take it too. Returns label and the mask of relabelled
    pixels (agents, and the ground with ``label_ground``). A frame whose ground has no positive
    slope against the plane (the network sees no receding ground) gets :func:`pseudo_label`.
    """
    inv = np.asarray(inv_depth, dtype=np.float32)
    q = np.asarray(plane_inv, dtype=np.float32)
    G = np.asarray(ground_mask, bool) & (np.asarray(instances) == 0)
    G, fit = network_space(inv, q, G, "plane")
    if fit is None:         # the network's ground does not recede here: its own contact values
        return pseudo_label(inv, instances, agents, conf)
    s, t = fit
    mapped = (np.float32(s) * q + np.float32(t)).astype(np.float32)
    plane_label, mask = pseudo_label(mapped, instances, agents, conf)
    q_contact, _ = pseudo_label(q, instances, agents, conf)
    mask &= q_contact > 0                   # contacts above the plane's horizon keep the prediction
    label = np.where(mask, plane_label, inv)
    if label_ground:
        label = np.where(G, mapped, label)
        mask = mask | G
    return label.astype(np.float32), mask


def aligned_pseudo_label(inv_depth: np.ndarray, aligned: np.ndarray, plane_inv: np.ndarray,
                         ground_mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Label one frame with its alignment, in the network's inverse-depth space.

    aligned: (H, W) the frame's aligned depth in the units of ``plane_inv`` (the plane's inverse
    depth ``n . r / d``); ground_mask: (H, W) bool ground pixels without agents. The network's
    ``inv_depth`` on the ground is fitted as ``s plane_inv + t`` (robust) and every pixel takes
    ``s / aligned + t``: pixels the alignment left as the network saw them get their own value
    back. A frame whose ground has no positive slope against the plane keeps its prediction.
    Returns the label and the mask of pixels changed by more than 1e-3 relative.
    """
    inv = np.asarray(inv_depth, dtype=np.float32)
    q = np.asarray(plane_inv, dtype=np.float32)
    A = np.asarray(aligned, dtype=np.float32)
    if inv.shape != q.shape or A.shape != q.shape:
        raise InputError(f"prediction {inv.shape}, alignment {A.shape} and plane {q.shape} "
                         "differ in size")
    _, fit = network_space(inv, q, np.asarray(ground_mask, bool), "aligned")
    if fit is None:
        return inv.copy(), np.zeros(inv.shape, bool)
    s, t = fit
    with np.errstate(divide="ignore", invalid="ignore"):
        label = np.where(np.isfinite(A) & (A > 0), np.float32(s) / A + np.float32(t), inv)
    label = label.astype(np.float32)
    with np.errstate(invalid="ignore"):
        mask = np.abs(label - inv) > 1e-3 * np.abs(inv)
    return label, mask


def trusted_label(inv_depth: np.ndarray, aligned: np.ndarray, trusted: np.ndarray,
                  untrusted: str, max_points: int = 20000,
                  fit: tuple[float, float] | None = None) -> np.ndarray | None:
    """Label one frame with its alignment on the ``trusted`` pixels only (agents, static pixels
    whose alignment repeats over the split), as shift-free inverse depth in the network's units.

    The network is fitted over every trusted pixel (robust ``inv ~ s / aligned + t``, not the
    ground alone); trusted pixels take ``s / aligned``, the others the network's own value less
    its shift, ``inv - t`` (``untrusted="base"``: its shape is kept there, relative to the
    labelled pixels; NaN where that is not positive, beyond its horizon; ``"aligned"`` too, for
    the pixels without an alignment, as adapt trusts every pixel then) or NaN (``"ignore"``: out
    of the loss), or the base's own depth ``1 / inv`` at the trusted labels' scale, ``c inv``
    (``"depth"``: the base less its shift changes the base's depth most at far pixels, where
    ``inv`` is near ``t``; not the default: docs/gains.md, seventh round). Labels are 0 at infinity, so a loss without shift (``finetune.loss=si``)
    teaches the network a ``1 / prediction`` right up to one scale. None when no map exists
    (fewer than 3 trusted pixels, or no positive slope). ``fit``: a given (s, t) instead (adapt:
    the ground's, when the trusted pixels give none)."""
    inv = np.asarray(inv_depth, np.float32)
    A = np.asarray(aligned, np.float32)
    ok = np.isfinite(A) & (A > 0) & np.isfinite(inv)
    sel = ok & np.asarray(trusted, bool)
    n = np.count_nonzero(sel)
    if fit is None:
        fit = _strided_fit(inv[sel], 1.0 / A[sel], max_points) if n >= 3 else None
        if fit is None:
            return None
    s, t = fit
    with np.errstate(divide="ignore", invalid="ignore"):
        label = np.float32(s) / A
        if untrusted == "depth":     # the base's own depth 1 / inv, at the labels' scale
            other = np.float32(_depth_scale(inv, label, sel, max_points)) * inv
        else:
            other = (inv - np.float32(t) if untrusted in ("base", "aligned")
                     else np.full(inv.shape, np.nan))
    other = np.where(other > 0, other, np.nan)
    return np.where(sel, label, other).astype(np.float32)


def plane_depth_rel_std(K: np.ndarray, normal, normal_std_deg: float, width: int, height: int,
                        row_px: float = 1.0) -> np.ndarray:
    """Each pixel's relative std of the plane's depth read at that pixel as a contact, from a
    contact row off by ``row_px`` and the normal's ``normal_std_deg``
    (:func:`staticdepth.geometry.scale.plane_depth_rel_error` over the image): (H, W) float32,
    NaN at and above the horizon (no depth)."""
    from staticdepth.geometry.projection import ray_grid
    from staticdepth.geometry.scale import plane_depth_rel_error

    return plane_depth_rel_error(K, normal, normal_std_deg, ray_grid(K, width, height),
                                 row_px).astype(np.float32)


def contact_label_std(plane_std: np.ndarray, instances: np.ndarray, agents: np.ndarray,
                      conf: PseudoLabelConfig = PRESETS["paper"]) -> tuple[np.ndarray, np.ndarray]:
    """Each agent pixel's expected relative error of its label: ``plane_std``
    (:func:`plane_depth_rel_std`) at its contact as :func:`pseudo_label` picks it, infinite
    where the contact is not seen - on the image's last row (the agent is cut off, its contact
    lies below) or right above another agent (hidden behind it): the lowest visible pixel is
    then not on the ground, and its plane depth is too far (i4: 84 of 412 agent-frames, a
    median error of 0.32-0.56 against 0.06 for the others). Returns it and the agents' mask."""
    inst = np.asarray(instances)
    hidden = np.zeros(inst.shape, np.float32)
    hidden[-1] = 1.0
    hidden[:-1] = np.maximum(hidden[:-1], inst[1:] > 0)
    std, on_agents = pseudo_label(plane_std, inst, agents, conf)
    unseen, _ = pseudo_label(hidden, inst, agents, conf)
    return np.where(unseen >= 0.5, np.float32(np.inf), std).astype(np.float32), on_agents


def grazing_agents(label: np.ndarray, inv_depth: np.ndarray, label_std: np.ndarray,
                   agents: np.ndarray, mode: str, max_points: int = 20000) -> np.ndarray:
    """The agents' labels where a grazing contact makes them worse than the base (issue 19).

    ``label``: shift-free inverse depth (:func:`trusted_label`); ``label_std``: each agent
    pixel's expected relative error of its label (:func:`plane_depth_rel_std` at its contact);
    ``agents``: (H, W) bool. The base's expected error is measured on the frame's agents without
    the truth: the median of ``|label / (c inv) - 1|``, ``c`` putting the base's depth at the
    labels' scale (:func:`_depth_scale`); agents' labels are mostly right, so it is the base's
    spread around them. ``mode="ignore"``: agents whose label std exceeds it get NaN (out of the
    loss: a network that fails on the view has no better depth to give them); ``"base"``: they
    take ``c inv``;
    ``"blend"``: every agent takes the inverse-variance mix of both in log depth, weight
    ``sb^2 / (sl^2 + sb^2)`` on the label; ``"off"``: unchanged."""
    if mode == "off":
        return label
    y = np.asarray(label, np.float32)
    inv = np.asarray(inv_depth, np.float32)
    sl = np.asarray(label_std, np.float32)
    with np.errstate(invalid="ignore"):
        ok = np.asarray(agents, bool) & np.isfinite(y) & (y > 0) & np.isfinite(inv) & (inv > 0)
    if np.count_nonzero(ok) < 3:
        return y
    base = np.float32(_depth_scale(inv, y, ok, max_points)) * inv
    sb = float(np.median(np.abs(y[ok] / base[ok] - 1.0)))
    use = ok & ~np.isnan(sl)         # inf: the contact is not seen
    out = y.copy()
    if mode in ("ignore", "base"):
        use &= sl > sb
        out[use] = np.nan if mode == "ignore" else base[use]
    else:
        w = sb * sb / (sl[use] ** 2 + sb * sb) if sb > 0 else np.ones(np.count_nonzero(use))
        out[use] = np.exp(w * np.log(y[use]) + (1.0 - w) * np.log(base[use]))
    return out.astype(np.float32)


def _depth_scale(inv: np.ndarray, label: np.ndarray, sel: np.ndarray, max_points: int) -> float:
    """The one scale c that puts the base's depth ``1 / inv`` at the trusted labels' scale: the
    median of ``label / inv`` over the trusted pixels (1 when none are usable: then every label
    is ``inv``, and the scale-only loss takes any scale)."""
    ok = sel & (inv > 0) & np.isfinite(label)
    r = (label[ok] / inv[ok])[::max(1, np.count_nonzero(ok) // max_points)]
    r = r[np.isfinite(r) & (r > 0)]
    return float(np.median(r)) if len(r) else 1.0


def stable_depth(depths: np.ndarray, static: np.ndarray, max_spread: float,
                 rows: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """The per-pixel median of ``depths`` (F, H, W) over the frames where ``static`` (F, H, W) bool
    holds (no agent there), and the mask of pixels seen static in at least half the frames whose
    median absolute deviation is at most ``max_spread`` x the median: a fixed camera sees the same
    structure in every frame, so an alignment that re-anchors it the same way each time is
    consistent, and one that jumps between contacts is not (NaN median where never static).
    Computed ``rows`` image rows at a time: each pixel's statistics are its own, and numpy's
    NaN-median of the whole stack at once held several copies of it (+208 MiB at 32 frames of
    800x400)."""
    import warnings

    depths, static = np.asarray(depths), np.asarray(static, bool)
    n, h, w = depths.shape
    med, ok = np.empty((h, w), np.float32), np.empty((h, w), bool)
    for r in range(0, h, rows):
        d = depths[:, r:r + rows]
        D = np.where(static[:, r:r + rows] & np.isfinite(d) & (d > 0), d, np.nan)
        seen = np.count_nonzero(np.isfinite(D), axis=0)
        with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)     # all-NaN pixels: NaN
            m = np.nanmedian(D, axis=0)
            mad = np.nanmedian(np.abs(D - m), axis=0)
            ok[r:r + rows] = (seen * 2 >= n) & (mad <= max_spread * m)
        med[r:r + rows] = m
    return med, ok


def network_space(inv: np.ndarray, q: np.ndarray, ground: np.ndarray, what: str,
                   max_points: int = 20000):
    """The map from the plane's inverse depth ``q`` into the network's ``inv`` on the ground
    pixels below the horizon: (those pixels, (s, t) of ``inv ~ s q + t``, or None when the
    network's ground does not recede against the plane). Raises with fewer than 3 pixels."""
    G = ground & (q > 0) & np.isfinite(inv)
    if np.count_nonzero(G) < 3:
        raise InputError("the ground mask holds fewer than 3 pixels below the agents' horizon: "
                         f"no {what} pseudo labels")
    return G, _strided_fit(inv[G], q[G], max_points)


def _strided_fit(inv: np.ndarray, q: np.ndarray, max_points: int):
    """(s, t) of the robust ``inv ~ s q + t`` over paired pixel values (at most ``max_points``
    of them, evenly strided), or None when there is no positive slope."""
    from staticdepth.geometry.alignment import fit_inverse_affine

    step = max(1, len(inv) // max_points)
    try:
        return fit_inverse_affine(inv[::step], q[::step])
    except InputError:
        return None
