"""Pure timestamp logic: pairing two free-running cameras, and gaps in a recorded stream.

Pairing (software sync of two UVC cameras): frames arrive per camera in time order. A frame pairs
with the nearest not-yet-paired frame of the other camera when the two are at most ``tolerance_s``
apart (default half a frame period); every frame that cannot pair is counted as dropped, never
silently lost. :class:`NearestPairer` does this online with at most one frame of look-ahead;
:func:`pair_nearest` runs it over two whole timestamp lists.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

LEFT, RIGHT = 0, 1


@dataclass
class NearestPairer:
    """Online nearest-timestamp pairing of two streams.

    ``push(side, t_s, item)`` with ``side`` in (LEFT, RIGHT) and per-side non-decreasing ``t_s``
    returns the pairs ``(left_item, right_item, t_left_s, t_right_s)`` completed by that frame.
    A frame waits for the other camera's next frame only when a later frame could still be nearer
    (one frame of latency); :meth:`flush` resolves what is left at the end of a stream.
    ``max_pending`` frames wait per side at most (older ones are dropped and counted), so a
    stalled camera cannot make the other one's frames pile up.
    """

    tolerance_s: float
    max_pending: int = 64
    unpaired: list[int] = field(default_factory=lambda: [0, 0])
    _queues: tuple[deque, deque] = field(default_factory=lambda: (deque(), deque()))

    def push(self, side: int, t_s: float, item: Any = None) -> list[tuple[Any, Any, float, float]]:
        q = self._queues[side]
        if q and t_s < q[-1][0]:
            raise ValueError(f"timestamps of side {side} go backwards ({t_s} < {q[-1][0]})")
        q.append((float(t_s), item))
        while len(q) > self.max_pending:
            q.popleft()
            self.unpaired[side] += 1
        return self._resolve(final=False)

    def flush(self) -> list[tuple[Any, Any, float, float]]:
        """Pair what can still be paired, count the rest as unpaired, empty the buffers."""
        out = self._resolve(final=True)
        for side in (LEFT, RIGHT):
            self.unpaired[side] += len(self._queues[side])
            self._queues[side].clear()
        return out

    def _resolve(self, final: bool) -> list[tuple[Any, Any, float, float]]:
        out: list[tuple[Any, Any, float, float]] = []
        ql, qr = self._queues
        tol = self.tolerance_s
        while ql and qr:
            tl, tr = ql[0][0], qr[0][0]
            if tl < tr - tol:                       # no right frame can reach this left one
                ql.popleft()
                self.unpaired[LEFT] += 1
                continue
            if tr < tl - tol:
                qr.popleft()
                self.unpaired[RIGHT] += 1
                continue
            # Within tolerance. Walk the chain of preferences early[0] -> late[0] -> early[1] ->
            # late[1] ... while each next frame is strictly nearer; the first local minimum decides:
            # at an even step the heads pair, at an odd step early[0] has lost its only partner.
            early, late = (ql, qr) if tl <= tr else (qr, ql)
            step, settled = self._chain_minimum(early, late)
            if not settled and not final:
                break                               # wait: a later frame may change the answer
            if step % 2:
                early.popleft()
                self.unpaired[LEFT if early is ql else RIGHT] += 1
                continue
            (tl, left), (tr, right) = ql.popleft(), qr.popleft()
            out.append((left, right, tl, tr))
        return out

    @staticmethod
    def _chain_minimum(early: deque, late: deque) -> tuple[int, bool]:
        """(index of the first local minimum of d(e0,l0), d(l0,e1), d(e1,l1), ..., settled):
        not settled when the distances still decrease at the last frame received so far."""
        seq: list[float] = []                     # e0, l0, e1, l1, ... while frames exist
        for i in range(len(early)):
            seq.append(early[i][0])
            if i >= len(late):
                break
            seq.append(late[i][0])
        if len(early) > 1 and early[1][0] <= late[0][0]:
            return 1, True                          # early[1] is nearer to late[0] than early[0]
        prev = abs(seq[1] - seq[0])
        for m in range(1, len(seq) - 1):
            d = abs(seq[m + 1] - seq[m])
            if prev <= d:
                return m - 1, True
            prev = d
        return len(seq) - 2, seq[-1] == seq[-2]     # a zero distance cannot get any smaller


def pair_nearest(left_ts: Sequence[float], right_ts: Sequence[float], tolerance_s: float
                 ) -> tuple[list[tuple[int, int]], int, int]:
    """Pair two sorted timestamp lists offline, exactly as :class:`NearestPairer` does online.

    Returns ``(pairs, unpaired_left, unpaired_right)`` with ``pairs`` as (left index, right index),
    merged in arrival (time) order.
    """
    p = NearestPairer(tolerance_s, max_pending=len(left_ts) + len(right_ts) + 1)
    pairs: list[tuple[int, int]] = []
    events = sorted([(t, LEFT, i) for i, t in enumerate(left_ts)]
                    + [(t, RIGHT, i) for i, t in enumerate(right_ts)])
    for t, side, i in events:
        pairs += [(a, b) for a, b, _, _ in p.push(side, t, i)]
    pairs += [(a, b) for a, b, _, _ in p.flush()]
    return pairs, p.unpaired[LEFT], p.unpaired[RIGHT]


def timestamp_gaps(timestamps_s: Sequence[float], period_s: float | None = None,
                   factor: float = 1.5) -> list[tuple[int, float]]:
    """Intervals longer than ``factor`` x the frame period: ``[(index after the gap, gap_s), ...]``.

    ``period_s`` defaults to the median interval. Each gap is about ``round(gap_s / period_s) - 1``
    missing frames.
    """
    t = np.asarray(timestamps_s, dtype=np.float64)
    if t.size < 2:
        return []
    dt = np.diff(t)
    period = float(np.median(dt)) if period_s is None else float(period_s)
    if period <= 0:
        return []
    idx = np.flatnonzero(dt > factor * period)
    return [(int(i) + 1, float(dt[i])) for i in idx]


def stream_summary(timestamps_s: Sequence[float], nominal_fps: float | None = None
                   ) -> dict[str, Any]:
    """Frames, duration, achieved FPS, interval statistics and gaps of one recorded stream."""
    t = np.asarray(timestamps_s, dtype=np.float64)
    n = int(t.size)
    out: dict[str, Any] = {"frames": n, "duration_s": 0.0, "achieved_fps": None,
                           "interval_median_s": None, "interval_max_s": None, "gaps": 0,
                           "missing_frames_estimate": 0, "largest_gaps": []}
    if n < 2:
        return out
    dt = np.diff(t)
    duration = float(t[-1] - t[0])
    period = 1.0 / nominal_fps if nominal_fps else float(np.median(dt))
    gaps = timestamp_gaps(t, period)
    out.update(duration_s=duration, achieved_fps=(n - 1) / duration if duration > 0 else None,
               interval_median_s=float(np.median(dt)), interval_max_s=float(dt.max()),
               gaps=len(gaps),
               missing_frames_estimate=int(sum(max(round(g / period) - 1, 1) for _, g in gaps)),
               largest_gaps=[{"frame": i, "gap_s": g}
                             for i, g in sorted(gaps, key=lambda x: -x[1])[:10]])
    return out
