"""The joint plane's reported std against the spread of its errors (issue 13, agent_plane_boot).

Truth: the independent generators of tests/plane_generators.py, one noise-free camera with fresh
1 px noise drawn onto its observations; each draw is fitted with its bootstrap and the RMS of the
true errors over the draws is the spread the reported std has to match. The bootstrap and the
Laplace estimate the same spread, so their variances are averaged; their quadrature sum (before)
is sqrt(2) too large where the two agree. Over many cameras (benchmarks/bench_plane_coverage.py,
masks at 1 px) the average puts 67% of the cameras within 1 std on seeds 0-19 and 59% held out
on 20-39 (a 2-D Gaussian: 63%), the sum 86 / 90%. One camera is one sample of that: on thin 6
the average is 0.72 of its spread and the sum 1.02; on tapered 6 (here) 1.14 and 1.62.
"""
from __future__ import annotations

import numpy as np

from plane_generators import scene
from staticdepth.geometry.agent_plane import AgentPlaneConfig, fit_agent_plane
from staticdepth.geometry.agent_plane_gate import GATE_STD_DEG
from staticdepth.geometry.plane import angle_between_deg


def test_reported_std_matches_the_spread_the_quadrature_sum_overstated():
    s = scene("tapered", 6, noise_px=0.0, n_tracks=12, frames=(6, 8))
    rng = np.random.default_rng(5)
    errs, new, old = [], [], []
    for _ in range(8):
        t = s.obs.copy()
        for c in ("foot_u", "foot_v", "top_v", "top_u"):
            t[c] = t[c] + rng.normal(0.0, 1.0, len(t))
        t["height_px"] = t["foot_v"] - t["top_v"]
        p = fit_agent_plane(s.K, t, AgentPlaneConfig(bootstrap=8, column_weight=1.0,
                                                     seed=int(rng.integers(1000))))
        q = p.normal_std_parts
        errs.append(angle_between_deg(p.normal, s.normal))
        new.append(p.normal_std_deg)
        old.append(np.sqrt(q["bootstrap_std_deg"] ** 2 + q["laplace_std_deg"] ** 2
                           + q["class_misfit_deg"] ** 2))
    spread = float(np.sqrt(np.mean(np.square(errs))))
    print(f"spread {spread:.3f} deg, reported {np.median(new):.3f}, quadrature sum "
          f"{np.median(old):.3f}")
    assert 0.3 < spread < 1.0                           # a camera where the noise matters
    assert 0.8 < np.median(new) / spread < 1.4          # the reported std: the spread
    assert np.median(old) / spread > 1.5                # the sum overstated it
    # the gate's verdicts move with the scale: std <= 1 / sqrt(2) is the sum <= 1
    for n, o in zip(new, old):
        assert (n <= GATE_STD_DEG) == (o <= 1.0)
