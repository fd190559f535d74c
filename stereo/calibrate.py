"""Stereo calibration from image pairs of a chessboard or a ChArUco board.

Steps: detect the board in every pair (sub-pixel corners; for ChArUco only the corners seen in
both views), calibrate each camera, then ``stereoCalibrate`` starting from those intrinsics and
refining everything jointly, drop views whose reprojection error is an outlier (and say which),
calibrate again, and rectify (``stereoRectify``). The square size sets the metric scale of ``T``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import cv2
import numpy as np

from staticdepth.errors import InputError
from staticdepth.geometry.camera import Camera, StereoRig
from staticdepth.stereo.io import read_rgb
from staticdepth.stereo.rectify import stereo_rectify

PATTERNS = ("chessboard", "charuco")
MIN_PAIRS = 2                 # Zhang: two views of a flat board fix zero-skew intrinsics, one not
MIN_BASELINE_SQUARES = 0.04   # a baseline under 1/25 of the square (1 mm for 25 mm) is no rig


@dataclass(frozen=True)
class Board:
    """A calibration board: ``cols x rows`` inner corners (chessboard) or squares (ChArUco)."""

    pattern: str = "chessboard"
    cols: int = 9
    rows: int = 6
    square_m: float = 0.025
    marker_m: float = 0.0            # ChArUco marker side (0: 0.75 of the square)
    dictionary: str = "DICT_4X4_50"  # ChArUco ArUco dictionary

    def __post_init__(self):
        if self.pattern not in PATTERNS:
            raise InputError(f"pattern must be one of {PATTERNS}, got {self.pattern!r}")
        if self.cols < 2 or self.rows < 2:
            raise InputError(f"board must be at least 2x2, got {self.cols}x{self.rows}")
        if not (np.isfinite(self.square_m) and self.square_m > 0):   # inf, nan, 0: refused
            raise InputError(f"square size must be a finite positive number, got "
                             f"{self.square_m}")
        if not (np.isfinite(self.marker_m) and 0 <= self.marker_m < self.square_m):
            raise InputError(f"marker size must be 0 (0.75 of the square) or a finite number "
                             f"below the square size {self.square_m:g}, got {self.marker_m}")
        if self.pattern == "charuco" and not hasattr(cv2.aruco, self.dictionary):
            raise InputError(f"unknown ArUco dictionary {self.dictionary!r}")

    @classmethod
    def parse(cls, pattern: str, size: str, square_m: float, **kw) -> "Board":
        """``size`` as ``COLSxROWS`` (e.g. ``9x6``)."""
        try:
            cols, rows = (int(s) for s in size.lower().split("x"))
        except ValueError:
            raise InputError(f"board size must look like 9x6, got {size!r}") from None
        return cls(pattern, cols, rows, square_m, **kw)

    def charuco(self):
        marker = self.marker_m or 0.75 * self.square_m
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, marker, d)

    def object_points(self) -> np.ndarray:
        """Board-frame corner positions (N, 3) in metres, z = 0, in detection order (ids)."""
        if self.pattern == "charuco":
            return np.asarray(self.charuco().getChessboardCorners(), np.float32).reshape(-1, 3)
        grid = np.mgrid[0:self.cols, 0:self.rows].T.reshape(-1, 2)
        return np.hstack([grid * self.square_m, np.zeros((len(grid), 1))]).astype(np.float32)


def detect_corners(board: Board, image_rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Board corners in one image: (ids (N,), pixels (N, 2) float32), or None if not found."""
    grey = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2GRAY)
    if board.pattern == "chessboard":
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        ok, corners = cv2.findChessboardCorners(grey, (board.cols, board.rows), flags=flags)
        if not ok:
            return None
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
        grid = corners.reshape(board.rows, board.cols, 2)
        spacing = min(np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
                      np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
        win = int(np.clip(0.4 * spacing, 2, 11))   # stay inside one square on small boards
        corners = cv2.cornerSubPix(grey, corners, (win, win), (-1, -1), crit)
        return np.arange(len(corners)), corners.reshape(-1, 2).astype(np.float32)
    det = cv2.aruco.CharucoDetector(board.charuco())
    corners, ids, _, _ = det.detectBoard(grey)
    if ids is None or len(ids) < 6:
        return None
    return np.asarray(ids).reshape(-1), np.asarray(corners, np.float32).reshape(-1, 2)


@dataclass(frozen=True)
class Calibration:
    rig: StereoRig
    used: list[str]                                  # left image of each pair used
    dropped: dict[str, float]                        # outlier pairs -> their RMS (px)
    not_found: list[str]                             # pairs where the board was not found
    per_view_rms: dict[str, float] = field(default_factory=dict)


def _pair_points(board: Board, dl, dr):
    ids = np.intersect1d(dl[0], dr[0])
    obj = board.object_points()[ids]
    pl = dl[1][np.searchsorted(dl[0], ids)] if board.pattern == "charuco" else dl[1][ids]
    pr = dr[1][np.searchsorted(dr[0], ids)] if board.pattern == "charuco" else dr[1][ids]
    return obj, pl, pr


def _stereo(obj, pl, pr, size, refine=True):
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-6)
    _, K1, d1, _, _ = cv2.calibrateCamera(obj, pl, size, None, None, criteria=crit)
    _, K2, d2, _, _ = cv2.calibrateCamera(obj, pr, size, None, None, criteria=crit)
    flags = cv2.CALIB_USE_INTRINSIC_GUESS if refine else cv2.CALIB_FIX_INTRINSIC
    out = cv2.stereoCalibrateExtended(obj, pl, pr, K1, d1, K2, d2, size, np.eye(3),
                                      np.zeros((3, 1)), flags=flags, criteria=crit)
    rms, K1, d1, K2, d2, R, T, per_view = *out[:7], out[-1]
    return rms, K1, d1, K2, d2, R, T, np.asarray(per_view).reshape(len(obj), 2)


def calibrate_stereo(left_files: list[str], right_files: list[str], board: Board, *,
                     min_pairs: int = 5, outlier_factor: float = 2.5) -> Calibration:
    """Calibrate a stereo rig from pairs of board images (sorted, left[i] with right[i]).

    Refused (:class:`InputError`): ``min_pairs`` below 2, a file given as both views, fewer than
    ``min_pairs`` pairs with the board, a baseline under ``MIN_BASELINE_SQUARES`` squares (the
    same view twice) and a right camera to the left of the left one (swapped views).
    """
    if min_pairs < MIN_PAIRS:
        raise InputError(f"min_pairs must be at least {MIN_PAIRS} (one view of a flat board cannot "
                         f"fix the focal length), got {min_pairs}")
    if len(left_files) != len(right_files):
        raise InputError(f"{len(left_files)} left images but {len(right_files)} right images")
    size = None
    obj, pl, pr, used, not_found = [], [], [], [], []
    for lf, rf in zip(left_files, right_files):
        L, R = read_rgb(lf), read_rgb(rf)
        if size is None:
            size = (L.shape[1], L.shape[0])
        for f, img in ((lf, L), (rf, R)):
            if (img.shape[1], img.shape[0]) != size:
                raise InputError(f"image is {img.shape[1]}x{img.shape[0]}, the first left image "
                                 f"is {size[0]}x{size[1]}", f)
        dl, dr = detect_corners(board, L), detect_corners(board, R)
        if dl is None or dr is None:
            not_found.append(lf if dl is None else rf)
            continue
        if os.path.realpath(lf) == os.path.realpath(rf):   # a view paired with itself
            raise InputError("given as both the left and the right image of a pair: give the "
                             "left camera's images as --left and the right camera's as --right",
                             lf)
        o, a, b = _pair_points(board, dl, dr)
        if len(o) < 6:
            not_found.append(lf)
            continue
        obj.append(o), pl.append(a), pr.append(b), used.append(lf)
    folder = (os.path.dirname(left_files[0]) or ".") if left_files else "."
    if len(used) < min_pairs:
        found = (f"found in only {len(used)} of {len(left_files)} pairs, need {min_pairs}; not "
                 f"found in: {', '.join(map(os.path.basename, not_found))}" if not_found else
                 f"found in all {len(used)} pairs, but {min_pairs} are needed: give more pairs")
        raise InputError(f"board ({board.pattern} {board.cols}x{board.rows}) {found}", folder)
    rms, K1, d1, K2, d2, R, T, per_view = _stereo(obj, pl, pr, size)
    view_rms = np.sqrt((per_view ** 2).mean(axis=1))
    limit = max(outlier_factor * float(np.median(view_rms)), 0.5)
    keep = view_rms <= limit
    dropped = {used[i]: float(view_rms[i]) for i in np.flatnonzero(~keep)}
    if dropped and keep.sum() >= min_pairs:
        sel = np.flatnonzero(keep)
        obj, pl, pr = [obj[i] for i in sel], [pl[i] for i in sel], [pr[i] for i in sel]
        used = [used[i] for i in sel]
        rms, K1, d1, K2, d2, R, T, per_view = _stereo(obj, pl, pr, size)
        view_rms = np.sqrt((per_view ** 2).mean(axis=1))
    else:
        dropped = {}
    check_baseline(R, T.ravel(), board, folder)
    left, right = Camera(K1, *size, d1.ravel()), Camera(K2, *size, d2.ravel())
    rig = StereoRig(left, right, R, T.ravel(), None, None, float(rms),
                    {"board": f"{board.pattern} {board.cols}x{board.rows} square "
                              f"{board.square_m} m", "pairs_used": len(used),
                     "pairs_dropped": sorted(map(os.path.basename, dropped))})
    rig = StereoRig(left, right, R, T.ravel(), stereo_rectify(rig), None, float(rms),
                    dict(rig.extra))
    return Calibration(rig, used, dropped, not_found,
                       {u: float(e) for u, e in zip(used, view_rms)})


def check_baseline(R: np.ndarray, T: np.ndarray, board: Board, source: str | None = None) -> None:
    """Raise :class:`InputError` for a calibrated pose ``right_from_left`` (R, T) that is no
    usable left/right rig: cameras less than ``MIN_BASELINE_SQUARES`` board squares apart (the
    same images given twice), or the right camera further left than it is up or down (swapped)."""
    baseline = float(np.linalg.norm(T))
    limit = MIN_BASELINE_SQUARES * board.square_m
    if baseline < limit:
        raise InputError(f"the calibrated cameras are {baseline:.2g} m apart (under {limit:.2g} m, "
                         f"{MIN_BASELINE_SQUARES:g} of the square): both views show the board "
                         f"from the same place; are --left and --right images of one camera?",
                         source)
    right_in_left = -np.asarray(R).T @ np.asarray(T).ravel()   # the right camera's centre
    if right_in_left[0] < 0 and abs(right_in_left[0]) > abs(right_in_left[1]):
        raise InputError(f"the views look swapped: the --right camera is {-right_in_left[0]:.4f} m "
                         f"to the left of the --left one; give the left camera's images as "
                         f"--left and the right camera's as --right", source)
