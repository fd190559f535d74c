"""Temporal stereo fusion for a fixed rig: one background disparity from many frames, agents from
their own frame, and a per-pixel confidence (pure numpy/OpenCV, no files).

The camera never moves, so the static background is the same in every frame; only noise, light
and the agents passing in front of it change. Two passes over the (rectified) frames:

1. :func:`build_background` reads ``samples`` frames spread over the sequence (never more, so
   memory is bounded by ``samples`` frames whatever the length) and makes
   - the *background plates*: per pixel, the mean of the samples that look like the median of a
     few samples (static there), which removes the agents and averages the sensor noise away;
   - the *background disparity*: the plates matched once, upsampled ``plate_scale`` times (finer
     disparities; affordable because it is done once), left-right checked; its holes take the
     median disparity of ``disparity_samples`` frames where static; then local affine fits
     (:func:`smooth_planar`) remove the matching noise on planes (ground, walls);
   - the background confidence: left-right agreement x stability (share of the sampled frames
     whose own disparity agrees within ``stable_px``) x texture x plane-fit scatter relative to
     the disparity x depth precision (:func:`depth_precision`).
2. :func:`fuse_frame` per frame: the foreground test (colour change against the plate, or a
   disparity off the background's beside such a change) keeps the frame's own disparity on the
   agents; everywhere else the pixel takes the background disparity, which also fills the
   occlusion holes every agent leaves beside it.

>>> model = build_background(sampled_pairs, match, match_upsampled, TemporalConfig())
>>> fused = fuse_frame(model, left_rgb, match(left_rgb, right_rgb))
>>> fused.disparity, fused.confidence, fused.foreground

``match`` is any ``(left_rgb, right_rgb) -> disparity`` (float32, NaN = invalid), e.g. an SGBM or
ONNX matcher's ``.match(l, r).disparity``.
"""
from __future__ import annotations

import dataclasses
import hashlib
import io
import json
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

import cv2
import numpy as np

from staticdepth.config import from_dict
from staticdepth.errors import InputError
from staticdepth.stereo.fill import lr_consistent

# A matcher as the fusion sees it: rectified RGB pair -> left disparity (float32, NaN = invalid).
MatchFn = Callable[[np.ndarray, np.ndarray], np.ndarray]

FOREGROUND_CONFIDENCE = 0.25   # a single frame's match ranks below a stable background
FILLED_CONFIDENCE = 0.25       # background holes filled from the per-frame disparity samples
REL_SCATTER = 0.1              # plane-fit scatter / disparity at which confidence falls by 1/e
PRECISION_PX = 4.0             # disparity at which the depth-precision factor is 1/4
TEXTURE_DN = 4.0               # local grey-level std (DN) at which texture confidence is 1/2


@dataclass(frozen=True)
class TemporalConfig:
    """Settings of the temporal fusion (``--set temporal.<key>=value`` on the command line)."""

    samples: int = 25              # frames whose images make the background plates
    disparity_samples: int = 8     # of those, frames also matched (stability, plate hole filling)
    plate_scale: int = 2           # the plates are matched upsampled this many times
    change_dn: float = 6.0         # least colour change (5x5 mean, DN) that marks a foreground
    change_sigmas: float = 3.0     # ... or this many times the measured noise, if larger
    foreground_px: float = 0.5     # off the background by this much beside a change: foreground
    stable_px: float = 1.0         # a sample agrees with the background within this
    lr_px: float = 1.0             # left-right agreement of the plates
    plane_radius: int = 4          # background smoothing: local affine fit in (2r+1)^2 windows
    plane_rms_px: float = 0.4      # ... kept where the fit's residual RMS is below this

    def __post_init__(self):
        if self.samples < 1 or self.disparity_samples < 0:
            raise InputError(f"temporal samples must be >= 1 and disparity_samples >= 0, got "
                             f"{self.samples} and {self.disparity_samples}")
        if self.plate_scale < 1:
            raise InputError(f"temporal plate_scale must be >= 1, got {self.plate_scale}")
        if self.plane_radius < 0:
            raise InputError(f"temporal plane_radius must be >= 0, got {self.plane_radius}")
        for k in ("change_dn", "change_sigmas", "foreground_px", "stable_px", "lr_px",
                  "plane_rms_px"):
            if not getattr(self, k) > 0:
                raise InputError(f"temporal {k} must be positive, got {getattr(self, k)}")

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None, source: str | None = None
                  ) -> "TemporalConfig":
        return from_dict(cls, values, source=source)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class BackgroundModel:
    """The static scene as the rig sees it; all maps (H, W) in the rectified left view."""

    left: np.ndarray          # uint8 RGB plate (median of the samples)
    right: np.ndarray         # uint8 RGB plate
    disparity: np.ndarray     # float32 px, NaN = unknown
    confidence: np.ndarray    # float32 in [0, 1], 0 where unknown
    noise_dn: float           # robust std of a sample's channel values about the plates
    change_dn: float          # the foreground threshold used per frame
    foreground_px: float

    def to_bytes(self, key: str = "") -> bytes:
        """An ``.npz`` image of the model (with a free ``key``, e.g. the config's hash)."""
        buf = io.BytesIO()
        np.savez_compressed(buf, left=self.left, right=self.right, disparity=self.disparity,
                            confidence=self.confidence,
                            scalars=np.array([self.noise_dn, self.change_dn, self.foreground_px]),
                            key=np.array(key))
        return buf.getvalue()

    @classmethod
    def from_bytes(cls, data: bytes) -> tuple["BackgroundModel", str]:
        z = np.load(io.BytesIO(data), allow_pickle=False)
        s = z["scalars"]
        return cls(z["left"], z["right"], z["disparity"], z["confidence"], float(s[0]),
                   float(s[1]), float(s[2])), str(z["key"])


@dataclass(frozen=True)
class FusedFrame:
    disparity: np.ndarray     # float32 px, NaN = hole (an agent pixel its own frame missed)
    confidence: np.ndarray    # float32 in [0, 1], 0 on holes
    foreground: np.ndarray    # bool, pixels taken from the frame's own match


def sample_indices(n_frames: int, k: int) -> list[int]:
    """``k`` frame indices spread evenly over ``n_frames`` (all of them when ``k >= n_frames``)."""
    if n_frames <= 0:
        raise InputError("no frames to build a background from")
    k = min(k, n_frames)
    return sorted({int(round(x)) for x in np.linspace(0, n_frames - 1, k)})


def config_key(*parts: Mapping[str, Any]) -> str:
    """A short hash of the settings a background model depends on (for reuse on resume)."""
    blob = json.dumps(list(parts), sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def texture_confidence(grey: np.ndarray, radius: int = 2) -> np.ndarray:
    """s / (s + TEXTURE_DN) with s the local grey-level std in a (2r+1)^2 window."""
    g = grey.astype(np.float32)
    k = (2 * radius + 1, 2 * radius + 1)
    m = cv2.blur(g, k)
    var = np.maximum(cv2.blur(g * g, k) - m * m, 0)
    s = np.sqrt(var)
    return s / (s + np.float32(TEXTURE_DN))


def right_disparity(match: MatchFn, left_rgb: np.ndarray, right_rgb: np.ndarray) -> np.ndarray:
    """The right view's disparity with a left-view matcher: match the mirrored pair."""
    return match(np.ascontiguousarray(right_rgb[:, ::-1]),
                 np.ascontiguousarray(left_rgb[:, ::-1]))[:, ::-1]


def match_plates(match_scaled: MatchFn, left: np.ndarray, right: np.ndarray, scale: int,
                 lr_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Left disparity of the plates matched ``scale`` x upsampled (in original pixels, NaN where
    the left-right check fails), and the left-right disagreement in px (inf where unknown)."""
    h, w = left.shape[:2]
    if scale > 1:
        up = [cv2.resize(im, (w * scale, h * scale), interpolation=cv2.INTER_CUBIC)
              for im in (left, right)]
    else:
        up = [left, right]
    dl = match_scaled(*up)
    dr = right_disparity(match_scaled, *up)
    ok = lr_consistent(dl, dr, lr_px * scale)
    u = np.arange(dl.shape[1], dtype=np.float32)[None, :]
    ur = np.clip(np.round(u - np.nan_to_num(dl, nan=1e6)), 0, dl.shape[1] - 1).astype(np.int64)
    gap = np.abs(np.take_along_axis(dr, ur, axis=1) - dl)
    dl = np.where(ok, dl, np.nan)
    gap = np.where(np.isfinite(gap), gap, np.inf).astype(np.float32)
    if scale > 1:   # back to the original grid: the median of each scale x scale block
        def blocks(a):
            return a.reshape(h, scale, w, scale).transpose(1, 3, 0, 2).reshape(-1, h, w)

        dl = _nanmedian(blocks(dl)) / scale
        gap = np.min(blocks(gap), axis=0) / scale
    return dl.astype(np.float32), gap.astype(np.float32)


def _nanmedian(stack: np.ndarray) -> np.ndarray:
    """Median over axis 0 ignoring NaN (NaN where all are): sorting puts NaN last."""
    srt = np.sort(stack, axis=0)
    n = np.isfinite(stack).sum(axis=0)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[None], 0)[0]
    hi = np.take_along_axis(srt, np.maximum(n // 2, 0)[None], 0)[0]
    return np.where(n > 0, (lo + hi) / 2, np.nan).astype(np.float32)


def build_background(pairs: Iterable[tuple[np.ndarray, np.ndarray]], match: MatchFn,
                     match_scaled: MatchFn | None = None,
                     config: TemporalConfig | None = None) -> BackgroundModel:
    """The background model from sampled rectified RGB pairs (see the module docstring).

    ``pairs`` yields the sampled frames (at most ``config.samples`` are kept); ``match`` matches a
    pair at the original size, ``match_scaled`` one upsampled ``config.plate_scale`` times (the
    same as ``match`` when the scale is 1).
    """
    c = config or TemporalConfig()
    lefts, rights = [], []
    for L, R in pairs:
        if len(lefts) >= c.samples:
            break
        lefts.append(np.asarray(L, np.uint8))
        rights.append(np.asarray(R, np.uint8))
    if not lefts:
        raise InputError("no frames to build a background from")
    L_stack, R_stack = np.stack(lefts), np.stack(rights)
    # a robust reference from at most 9 samples, then the plates: the mean of the samples that
    # match it (static at the pixel: less noise than a median), the reference where none does
    step = max(1, len(lefts) // 9)
    ref_l = np.median(L_stack[::step], axis=0).astype(np.float32)
    ref_r = np.median(R_stack[::step], axis=0).astype(np.float32)
    # robust per-channel noise of a sample about the reference (MAD; 0 with too few samples)
    noise = float(1.4826 * np.median(np.abs(L_stack[::step] - ref_l))) if len(lefts) > 2 \
        else 0.0
    change_dn = max(c.change_dn, c.change_sigmas * noise)
    ref_l8, ref_r8 = (np.round(x).astype(np.uint8) for x in (ref_l, ref_r))
    static = np.stack([appearance_change(x, ref_l8) <= change_dn for x in lefts])
    static_r = np.stack([appearance_change(x, ref_r8) <= change_dn for x in rights])
    plate_l = _static_mean(L_stack, static, ref_l)
    plate_r = _static_mean(R_stack, static_r, ref_r)
    plate_g = cv2.cvtColor(plate_l, cv2.COLOR_RGB2GRAY).astype(np.float32)
    del L_stack, R_stack, static_r

    scale = c.plate_scale
    disp, gap = match_plates(match_scaled or match, plate_l, plate_r, scale, c.lr_px)
    # per-frame disparities of a few samples: stability of the background, and its holes' values
    picks = sample_indices(len(lefts), c.disparity_samples) if c.disparity_samples else []
    h, w = disp.shape
    agree = np.zeros((h, w), np.float32)
    seen = np.zeros((h, w), np.float32)
    own = np.full((len(picks), h, w), np.nan, np.float32)
    for j, k in enumerate(picks):
        d = match(lefts[k], rights[k])
        d = np.where(static[k], d, np.nan)
        own[j] = d
    med = _nanmedian(own) if picks else np.full((h, w), np.nan, np.float32)
    ref = np.where(np.isfinite(disp), disp, med)
    for j in range(len(picks)):
        m = np.isfinite(own[j])
        seen += m
        agree += m & (np.abs(own[j] - ref) <= c.stable_px)
    stability = np.where(seen > 0, (agree + 1) / (seen + 1), 0.5).astype(np.float32)
    lr_conf = np.exp(-np.minimum(gap, 50) / np.float32(c.lr_px)).astype(np.float32)
    texture = texture_confidence(plate_g)
    conf = np.where(np.isfinite(disp), lr_conf * stability * texture,
                    FILLED_CONFIDENCE * stability * texture)
    disparity = np.where(np.isfinite(disp), disp, med).astype(np.float32)
    if c.plane_radius:
        disparity, rms = smooth_planar(disparity, c.plane_radius, c.plane_rms_px)
        # the local scatter of the background's disparity about its plane, relative to the
        # disparity: the expected relative depth error where the plane fit holds
        # (no fit: at least the largest scatter a fit may have)
        scatter = np.where(np.isfinite(rms), rms, np.float32(c.plane_rms_px))
        with np.errstate(invalid="ignore"):
            rel = scatter / np.maximum(np.nan_to_num(disparity, nan=1e-3), 1e-3)
        conf = conf * np.exp(-rel / np.float32(REL_SCATTER))
    disparity = _measurable(disparity)
    conf = np.where(np.isfinite(disparity), conf * depth_precision(disparity), 0)
    return BackgroundModel(plate_l, plate_r, disparity, conf.astype(np.float32), noise,
                           change_dn, c.foreground_px)


def _measurable(disparity: np.ndarray, u0: int = 0) -> np.ndarray:
    """NaN where a disparity is no measurement: <= 0 (infinitely far) or a match outside the
    right image (column u < d; ``u0`` is the first column of ``disparity``)."""
    d = np.array(disparity, dtype=np.float32)
    cols = np.arange(u0, u0 + d.shape[1], dtype=np.float32)[None, :]
    d[(cols < d) | ~(d > 0)] = np.nan
    return d


def _static_mean(stack: np.ndarray, static: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Per-pixel mean of the samples flagged static; ``fallback`` where none is."""
    total = np.zeros(stack.shape[1:], np.float32)
    for img, m in zip(stack, static):
        cv2.accumulate(img, total, mask=m.view(np.uint8))
    n = static.sum(axis=0, dtype=np.float32)[..., None]
    mean = np.where(n > 0, total / np.maximum(n, 1), fallback)
    return np.clip(np.round(mean), 0, 255).astype(np.uint8)


def smooth_planar(disparity: np.ndarray, radius: int, max_rms_px: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel takes the value at its centre of an affine fit d = a + b u + c v over its
    (2r+1)^2 window, where the fit is good (residual RMS < ``max_rms_px``, 60% of the window
    valid). A plane's disparity is affine in (u, v), so planes (the ground, walls) lose their
    per-pixel matching noise; windows across a depth edge fit badly and keep their values."""
    d = np.asarray(disparity, np.float32)
    h, w = d.shape
    ok = np.isfinite(d)
    wgt = ok.astype(np.float64)
    dd = np.where(ok, d, 0).astype(np.float64)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    k = (2 * radius + 1, 2 * radius + 1)

    def S(a):
        return cv2.boxFilter(a, cv2.CV_64F, k, normalize=False, borderType=cv2.BORDER_CONSTANT)

    n, su, sv, sd = S(wgt), S(wgt * u), S(wgt * v), S(dd)
    suu, svv, suv = S(wgt * u * u), S(wgt * v * v), S(wgt * u * v)
    sud, svd, sdd = S(dd * u), S(dd * v), S(dd * dd)
    # moments about the window's centre pixel (u, v)
    cu, cv_ = su - n * u, sv - n * v
    cuu = suu - 2 * u * su + n * u * u
    cvv = svv - 2 * v * sv + n * v * v
    cuv = suv - u * sv - v * su + n * u * v
    A = np.empty((h, w, 3, 3))
    A[..., 0, 0], A[..., 1, 1], A[..., 2, 2] = n, cuu, cvv
    A[..., 0, 1] = A[..., 1, 0] = cu
    A[..., 0, 2] = A[..., 2, 0] = cv_
    A[..., 1, 2] = A[..., 2, 1] = cuv
    b = np.stack([sd, sud - u * sd, svd - v * sd], axis=-1)
    good = n >= 0.6 * k[0] * k[1]
    A[~good] = np.eye(3)
    b[~good] = 0
    with np.errstate(all="ignore"):
        try:
            beta = np.linalg.solve(A, b[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return d.copy(), np.full(d.shape, np.nan, np.float32)
        rss = sdd - 2 * (beta * b).sum(-1) + np.einsum("...i,...ij,...j->...", beta, A, beta)
        rms = np.sqrt(np.maximum(rss, 0) / np.maximum(n, 1))
    use = good & ok & np.isfinite(beta[..., 0]) & (rms < max_rms_px)
    return np.where(use, beta[..., 0], d).astype(np.float32), np.where(use, rms, np.nan).astype(
        np.float32)


def appearance_change(rgb: np.ndarray, plate_rgb: np.ndarray) -> np.ndarray:
    """uint8 (H, W): the largest channel's absolute difference, averaged over 5x5 pixels."""
    a = cv2.absdiff(rgb, plate_rgb)
    return cv2.blur(cv2.max(cv2.max(a[..., 0], a[..., 1]), a[..., 2]), (5, 5))


def foreground_mask(model: BackgroundModel, left_rgb: np.ndarray, disparity: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(foreground, changed): pixels to take from the frame itself, and those whose appearance
    changed. Foreground = the changed pixels (gaps closed) plus, within 5 px of them, pixels whose
    own disparity differs from the background's by more than ``foreground_px`` (an agent whose
    colour happens to match the background there)."""
    changed = appearance_change(left_rgb, model.left) > model.change_dn
    ch8 = changed.view(np.uint8)
    fg = cv2.morphologyEx(ch8, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    near_change = cv2.dilate(ch8, np.ones((11, 11), np.uint8)).view(bool)
    with np.errstate(invalid="ignore"):
        off = np.abs(disparity - model.disparity) > np.float32(model.foreground_px)
    return fg.view(bool) | (off & near_change), changed


def match_confidence(left_rgb: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """A single frame's match reliability: texture x local smoothness of the disparity (3x3 std);
    0 where the disparity is invalid."""
    d = np.where(np.isfinite(disparity), disparity, 0).astype(np.float32)
    m = cv2.blur(d, (3, 3))
    std = np.sqrt(np.maximum(cv2.blur(d * d, (3, 3)) - m * m, 0))
    conf = texture_confidence(cv2.cvtColor(left_rgb, cv2.COLOR_RGB2GRAY)) * np.exp(-2.0 * std)
    return np.where(np.isfinite(disparity), conf, 0).astype(np.float32)


def fuse_frame(model: BackgroundModel, left_rgb: np.ndarray, disparity: np.ndarray
               ) -> FusedFrame:
    """One frame: its own disparity on the foreground, the background's elsewhere.

    A foreground pixel without its own match stays a hole (the occlusion band beside an agent is
    background: its appearance did not change, so it takes the background). Foreground pixels
    get the frame's own confidence (:func:`match_confidence` x depth precision) times
    ``FOREGROUND_CONFIDENCE``; the work is done on the foreground's bounding box only.
    """
    take_own, _ = foreground_mask(model, left_rgb, disparity)
    out = model.disparity.copy()
    conf = model.confidence.copy()
    x, y, w, h = cv2.boundingRect(take_own.view(np.uint8))
    if w and h:
        box = np.s_[y:y + h, x:x + w]
        d = _measurable(disparity[box], x)
        c = np.float32(FOREGROUND_CONFIDENCE) * match_confidence(left_rgb[box], d) \
            * depth_precision(d)
        m = take_own[box]
        out[box][m] = d[m]
        conf[box][m] = np.where(np.isfinite(d[m]), c[m], 0)
    return FusedFrame(out, conf, take_own)


def depth_precision(disparity: np.ndarray) -> np.ndarray:
    """(d / (d + PRECISION_PX))^2: the same disparity error is a larger share of a far depth,
    so confidence in a depth falls with its disparity (1/4 at ``PRECISION_PX``)."""
    d = np.where(disparity > 0, disparity, 0).astype(np.float32)
    p = d / (d + np.float32(PRECISION_PX))
    return p * p
