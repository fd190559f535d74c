"""Procedural surface textures: value noise on world (or object) coordinates, no tables, no state.

A texture is a function of the 3-D surface point only, so both cameras of the stereo pair see the
same colour at the same point (what stereo matching needs). Octaves finer than about two pixels at
the point's depth fade out (``footprint_m``), so far surfaces do not alias into noise.
"""
from __future__ import annotations

import numpy as np

_PRIMES = (np.uint64(0x8DA6B343), np.uint64(0xD8163841), np.uint64(0xCB1AB31F))
_SEED_MUL = np.uint64(0x165667B1)


def hash01(cells: np.ndarray, seed: int) -> np.ndarray:
    """A deterministic hash of integer lattice cells (..., D) into [0, 1) floats (...,)."""
    c = np.asarray(cells, dtype=np.int64).view(np.uint64)
    h = np.uint64(seed & 0xFFFFFFFF) * _SEED_MUL + np.uint64(0x9E3779B97F4A7C15)
    h = np.broadcast_to(h, c.shape[:-1]).copy()
    for k in range(c.shape[-1]):
        h ^= c[..., k] * _PRIMES[k % 3]
        h ^= h >> np.uint64(29)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(32)
    return (h >> np.uint64(40)).astype(np.float64) * (1.0 / (1 << 24))


def _periodic_table(n: int, d: int, seed: int) -> np.ndarray:
    """Random values on an n^d periodic lattice, padded by one so corner i + 1 needs no wrap."""
    t = np.random.default_rng(seed).random((n,) * d, dtype=np.float32)
    return np.pad(t, [(0, 1)] * d, mode="wrap").ravel()


_N = {2: 1024, 3: 64}
_TABLES = {2: _periodic_table(1024, 2, 20231120), 3: _periodic_table(64, 3, 20231121)}


def value_noise(points: np.ndarray, cell_m: float, seed: int) -> np.ndarray:
    """Smooth value noise in [0, 1] at points (N, D), D = 2 or 3, lattice spacing ``cell_m``.

    Lattice values come from a fixed random table (period 1024 cells in 2-D, 64 in 3-D), shifted
    by the seed; a table lookup is far cheaper than hashing every corner.
    """
    p = np.asarray(points, dtype=np.float64) / cell_m
    d = p.shape[-1]
    n, table = _N[d], _TABLES[d]
    i0 = np.floor(p)
    f = (p - i0).astype(np.float32)
    f = f * f * (3.0 - 2.0 * f)  # smoothstep
    i0 = i0.astype(np.int64)
    shift = (seed * 0x9E3779B1) & 0xFFFFFFFF
    flat = np.zeros(p.shape[:-1], np.int64)
    strides = []
    for k in range(d):
        flat = flat * (n + 1) + ((i0[..., k] + (shift >> (8 * k))) & (n - 1))
        strides.append((n + 1) ** (d - 1 - k))
    out = np.zeros(p.shape[:-1], np.float32)
    g = 1.0 - f
    for corner in range(1 << d):
        off = 0
        w = None
        for k in range(d):
            bit = (corner >> k) & 1
            off += strides[k] * bit
            wk = f[..., k] if bit else g[..., k]
            w = wk if w is None else w * wk
        out += w * table[flat + off]
    return out


def fractal_noise(points: np.ndarray, finest_m: float, octaves: int, seed: int,
                  footprint_m: np.ndarray | None = None) -> np.ndarray:
    """Sum of ``octaves`` value-noise octaves (cells finest_m * 2^k), normalised to about [0, 1].

    ``footprint_m`` (N,): the size of one pixel on the surface; an octave whose cells are smaller
    than 1.5 pixels is dropped, one between 1.5 and 3 pixels faded in.
    """
    total = np.zeros(points.shape[:-1])
    weight_sum = np.zeros(points.shape[:-1])
    for k in range(octaves):
        cell = finest_m * 2.0 ** (octaves - 1 - k)   # coarse first
        amp = 0.6 ** k
        if footprint_m is None:
            w = amp
        else:
            w = amp * np.clip((cell / np.maximum(footprint_m, 1e-9) - 1.5) / 1.5, 0.0, 1.0)
            if not np.any(w > 0):
                continue
        total += w * (value_noise(points, cell, seed + 7919 * k) - 0.5)
        weight_sum += w
    return 0.5 + total / np.maximum(weight_sum, 1e-9) * 0.9
