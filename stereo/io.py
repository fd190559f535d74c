"""Stereo file formats: images, PFM (Middlebury's disparity format), disparity files, PLY clouds.

Disparity files: ``.pfm`` (float32, invalid = inf, Middlebury's convention), ``.png`` (uint16,
disparity x 256, 0 = invalid, KITTI's convention), ``.npy`` (float32, NaN = invalid).
"""
from __future__ import annotations

import glob
import os
import re

import cv2
import numpy as np

from staticdepth.errors import InputError
# the toolkit's one image reader, and its names for images and videos
from staticdepth.fileio import (IMAGE_EXTS, VIDEO_EXTS, read_image, read_npy,  # noqa: F401
                                read_rgb, sorted_frames)


def check_image_headers(files: list[str], size: tuple[int, int] | None = None) -> None:
    """Raise :class:`InputError` naming the first file that is missing, is not an image, or whose
    header says a size other than ``size`` = (width, height).

    Reads only the headers (PIL opens lazily), so a whole recording is checked in well under a
    second per thousand files; data corrupted after the header is found when the frame is decoded.
    """
    from PIL import Image, UnidentifiedImageError

    for f in files:
        try:
            with Image.open(f) as im:
                got = im.size
        except FileNotFoundError:
            raise InputError("file not found", f) from None
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
            raise InputError(f"corrupt or unreadable image ({e.__class__.__name__})", f) from None
        if size is not None and tuple(got) != tuple(size):
            raise InputError(f"image is {got[0]}x{got[1]} but the rig was calibrated for "
                             f"{size[0]}x{size[1]}", f)


def expand_images(pattern: str) -> list[str]:
    """Image files of a folder, a glob pattern or a single file, sorted; none found is an error."""
    if os.path.isdir(pattern):
        files = [os.path.join(pattern, f) for f in os.listdir(pattern)
                 if f.lower().endswith(IMAGE_EXTS)]
    elif any(c in pattern for c in "*?["):
        files = glob.glob(pattern)
    else:
        files = [pattern] if os.path.exists(pattern) else []
    files = sorted_frames(files)      # 2.png before 10.png, as every frame listing
    if not files:
        raise InputError("no images found", pattern)
    return files


def is_video(path: str) -> bool:
    return os.path.isfile(path) and path.lower().endswith(VIDEO_EXTS)


# -- PFM ----------------------------------------------------------------------------------------
def write_pfm(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a float32 (H, W) or (H, W, 3) image as little-endian PFM (rows bottom to top)."""
    a = np.asarray(image, dtype=np.float32)
    if a.ndim == 2:
        header = "Pf"
    elif a.ndim == 3 and a.shape[2] == 3:
        header = "PF"
    else:
        raise InputError(f"PFM stores (H, W) or (H, W, 3) images, got {a.shape}", path)
    from staticdepth.fileio import atomic_write_bytes

    atomic_write_bytes(path, f"{header}\n{a.shape[1]} {a.shape[0]}\n-1.0\n".encode("ascii")
                       + np.ascontiguousarray(a[::-1]).astype("<f4").tobytes())


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """Read a PFM file (either endianness) into float32 (H, W) or (H, W, 3), top row first."""
    try:
        with open(path, "rb") as f:
            header = f.readline().decode("ascii").strip()
            dims = f.readline().decode("ascii").strip()
            scale = float(f.readline().decode("ascii").strip())
            data = f.read()
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except (UnicodeDecodeError, ValueError):
        raise InputError("not a PFM file (bad header)", path) from None
    m = re.fullmatch(r"(\d+)\s+(\d+)", dims)
    if header not in ("PF", "Pf") or not m:
        raise InputError("not a PFM file (bad header)", path)
    w, h = int(m.group(1)), int(m.group(2))
    c = 3 if header == "PF" else 1
    dtype = "<f4" if scale < 0 else ">f4"
    if len(data) < w * h * c * 4:
        raise InputError(f"PFM data truncated ({len(data)} bytes for {w}x{h}x{c})", path)
    a = np.frombuffer(data[:w * h * c * 4], dtype=dtype).astype(np.float32)
    a = a.reshape((h, w, 3) if c == 3 else (h, w))
    return np.ascontiguousarray(a[::-1])


def write_disparity(path: str | os.PathLike, disparity: np.ndarray) -> None:
    """Write a disparity map (float32, NaN = invalid) by extension: .pfm, .png (x256) or .npy,
    atomically (the previous file stays whole until the new one is complete)."""
    import io

    from staticdepth.fileio import atomic_write_bytes, write_image

    path = os.fspath(path)
    d = np.asarray(disparity, dtype=np.float32)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".pfm":
        write_pfm(path, np.where(np.isfinite(d), d, np.inf).astype(np.float32))
    elif ext == ".png":
        if np.nanmax(d, initial=0) * 256 > 65535:
            raise InputError("disparity above 255.99 px does not fit a uint16 x256 PNG "
                             "(write .pfm or .npy)", path)
        q = np.where(np.isfinite(d) & (d > 0), np.round(d * 256), 0).astype(np.uint16)
        write_image(path, q)
    elif ext == ".npy":
        buf = io.BytesIO()
        np.save(buf, d)
        atomic_write_bytes(path, buf.getvalue())
    else:
        raise InputError("disparity output must end in .pfm, .png or .npy", path)


def read_disparity(path: str | os.PathLike) -> np.ndarray:
    """Inverse of :func:`write_disparity`: float32 with NaN = invalid."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".pfm":
        d = read_pfm(path)
    elif ext == ".png":
        q = read_image(path)
        if q.dtype != np.uint16 or q.ndim != 2:
            raise InputError("expected a 16-bit disparity PNG", path)
        d = q.astype(np.float32) / 256.0
        d[q == 0] = np.nan
        return d
    elif ext == ".npy":
        d = read_npy(path)
        if d.ndim != 2 or d.dtype.kind not in "fiu":
            raise InputError(f"expected an H x W numeric disparity array, got {d.dtype} "
                             f"{d.shape}", path)
    else:
        raise InputError("disparity file must end in .pfm, .png or .npy", path)
    d = d.astype(np.float32)
    d[~np.isfinite(d)] = np.nan
    return d


def write_ply(path: str | os.PathLike, points: np.ndarray, colors: np.ndarray | None = None) -> int:
    """Write finite points (..., 3) (and uint8 RGB colours (..., 3)) as binary PLY.

    Returns the number of points written.
    """
    P = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    keep = np.all(np.isfinite(P), axis=1)
    P = P[keep]
    props = "property float x\nproperty float y\nproperty float z\n"
    dtype = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        C = np.asarray(colors, dtype=np.uint8).reshape(-1, 3)[keep]
        props += "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        dtype += [("r", "u1"), ("g", "u1"), ("b", "u1")]
    rows = np.empty(len(P), dtype=dtype)
    rows["x"], rows["y"], rows["z"] = P[:, 0], P[:, 1], P[:, 2]
    if colors is not None:
        rows["r"], rows["g"], rows["b"] = C[:, 0], C[:, 1], C[:, 2]
    from staticdepth.fileio import atomic_write_bytes

    atomic_write_bytes(path, f"ply\nformat binary_little_endian 1.0\nelement vertex {len(P)}\n"
                       f"{props}end_header\n".encode("ascii") + rows.tobytes())
    return len(P)
