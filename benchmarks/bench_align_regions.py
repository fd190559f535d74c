"""Where does the upright alignment lose? (issue 19) Per pixel category x true class x band.

Reads sequences that ``bench_gains.py --keep`` left in its work folder (their ``base``
prediction, adapt's summary: plane, settings, the adaptation split's feet), aligns the
evaluation split's frames again with adapt's settings (``--set align.KEY=VALUE`` over them) and
splits the pixel-weighted AbsRel (median scaling per frame, as ``evaluate``) by what the alignment
did to each pixel: ``snapped-walked`` / ``snapped`` (on the plane by the ground fit, inside /
outside the walked region), ``planar`` (took the plane: it recedes, or the walked-region rule),
``moved`` (traced to a contact and re-anchored), ``traced-refused`` (a contact the trust rules
refused), ``untraced`` (no contact: the ground mode), ``agent``; and by the truth: G ground, S
structure, A agent, distance bands. Beside the aligned error: the base prediction's and the
ground mode's on the same pixels, and each row's share of the frame's error (``contrib``). For
the traced structures, the true depth at their contact over the true depth of the pixel (1: the
right contact; below 1: a contact in front, e.g. through an occluder).

``--oracle-ground`` feeds the true ground (``all``, or ``beyond``: outside the walked region
only) to the alignment as ``extra_ground``: what a perfect ground cue would give.

Usage:
  python benchmarks/bench_align_regions.py --work out/bench --runs i4-m0,i4-m1 \\
      [--oracle-ground all|beyond] [--set align.shape=vertical] [--min-share 0.002]
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

BANDS = ((0, 10), (10, 20), (20, 40), (40, 80))


def categories(info: dict, walked: np.ndarray, agents: np.ndarray) -> np.ndarray:
    """(H, W) category names of one aligned frame from align_upright's ``info``."""
    cat = np.full(agents.shape, "untraced", object)
    cat[info["traced"] & ~info["moved"]] = "traced-refused"
    cat[info["moved"]] = "moved"
    cat[info["planar"] & ~info["moved"]] = "planar"
    snapped = info["snapped"] & ~info["moved"]
    cat[snapped] = "snapped"
    cat[snapped & walked] = "snapped-walked"
    cat[agents] = "agent"
    return cat


def run_settings(seq: str, sets: dict):
    """adapt's settings of a kept run (``sets``: ``align.KEY=VALUE`` over them) and its plane's
    normal."""
    from staticdepth.adaptation.config import build_config

    with open(seq + ".adapt.json") as f:
        summary = json.load(f)
    return build_config({**summary["config"], **sets}), np.asarray(summary["plane"]["normal"])


def run_image(r, conf):
    """The static image adapt's align stage gives ``align.colour_foot`` (None when it is off)."""
    from staticdepth.adaptation.align import align_image

    return align_image(conf.align, r)


def run_heights(seq: str, conf):
    """The people's fitted heights adapt's align stage gives ``agents_at_contact`` (None with
    ``align.hidden_contact=lowest``), from the run's ground_plane.json."""
    from dataclasses import replace

    from staticdepth.adaptation.align import person_heights
    from staticdepth.geometry.agent_plane import AgentPlane

    with open(seq + ".adapt/ground_plane.json") as f:
        d = json.load(f)
    plane = AgentPlane.from_dict(d["plane"])
    classes = {int(k): int(v) for k, v in d["track_classes"].items()}
    plane = replace(plane, extra={**plane.extra, "classes": np.array(
        [classes[int(t)] for t in plane.track_ids])})
    return person_heights(conf, plane)


def walked_region(r, conf):
    """Of an open SequenceReader: the agents' rows per frame and the walked region (the feet's
    hull over the adaptation split, eroded as adapt's align stage does)."""
    from staticdepth.geometry.alignment import ground_mask_from_feet

    rows = [r.agents(i) for i in range(len(r))]
    feet = np.concatenate([np.stack([x["foot_u"], x["foot_v"]], 1) for x in
                           (rows[i][rows[i]["foot_v"] >= 0] for i in r.split("adapt"))
                           if len(x)])
    erode = conf.align.erode_px
    return rows, ground_mask_from_feet(feet, r.width, r.height,
                                       r.width / 80.0 if erode is None else erode)


class KeptRun:
    """A run ``bench_gains.py --keep`` left, open (a context manager): adapt's settings
    (``conf``, ``--set`` over them), the plane's normal ``n_g``, the camera ``K``, the true
    ``mount`` (normal, height), the agents' ``rows`` per frame, the ``walked`` region, the
    static ``image`` and the people's ``heights``. :meth:`frames` aligns the evaluation split's
    base maps again exactly as adapt's align stage does (the benches over kept runs share it)."""

    def __init__(self, seq: str, sets: dict):
        self.seq = seq
        self.conf, self.n_g = run_settings(seq, sets)

    def __enter__(self) -> "KeptRun":
        from staticdepth.dataset.h5 import SequenceReader

        self.reader = r = SequenceReader(self.seq).__enter__()
        try:
            self.K = r.camera.K
            self.height, self.width = r.height, r.width
            self.mount = (r.meta.mounting.normal, r.meta.mounting.height_m)
            self.rows, self.walked = walked_region(r, self.conf)
            self.image, self.heights = run_image(r, self.conf), run_heights(self.seq, self.conf)
        except BaseException:
            r.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.reader.__exit__(*exc)

    def frames(self, extra_ground=None):
        """Per evaluation frame, a dict: ``i``, ``base``, ``gt``, ``inst``, ``agents`` (inst > 0),
        ``regions`` (evaluate.region_masks), ``valid``, ``info`` (align_upright's) and
        ``aligned`` (adapt's map, in the plane's units: the plane at distance 1).
        ``extra_ground``: a function of ``regions`` giving align_upright's ``extra_ground``."""
        from staticdepth.adaptation.align import upright_options
        from staticdepth.evaluate import region_masks
        from staticdepth.geometry.alignment import agents_at_contact, align_upright
        from staticdepth.metrics import valid_mask

        r, conf, walked = self.reader, self.conf, self.walked
        for i in r.split("eval"):
            Z, gt, inst = r.prediction("base", i), r.depth(i), r.instances(i)
            m = inst > 0
            am = m if np.count_nonzero(walked & ~m) >= 50 else None     # as aligned_frame
            reg = region_masks(gt, inst, self.rows[i], self.K, self.mount, 80.0)
            info: dict = {}
            A = align_upright(Z, self.K, self.n_g, 1.0, walked if am is None else walked & ~am,
                              agent_mask=am, snap_rel=conf.align.snap_rel, info=info,
                              extra_ground=None if extra_ground is None else extra_ground(reg),
                              image=self.image, **upright_options(conf.align)).depth
            if conf.align.agents_at_contact:
                A = agents_at_contact(A, self.K, self.n_g, 1.0, inst, self.rows[i],
                                      conf.pseudo_labels, heights=self.heights)[0]
            yield {"i": i, "base": Z, "gt": gt, "inst": inst, "agents": m, "regions": reg,
                   "valid": valid_mask(gt, 1e-3, 80.0), "info": info, "aligned": A}


def analyse(seq: str, sets: dict, oracle: str | None) -> dict:
    from staticdepth.metrics import apply_protocol

    acc: dict = {}
    contact_ratio = []
    total = np.zeros(3)
    with KeptRun(seq, sets) as run:
        walked = run.walked
        extra = None
        if oracle:
            def extra(reg):
                return reg["ground"] & (~walked if oracle == "beyond" else True)
        for f in run.frames(extra):
            gt, m, reg, info, A, vm = (f[k] for k in ("gt", "agents", "regions", "info",
                                                       "aligned", "valid"))
            errs = []
            for pred in (A, f["base"], info["ground_mode"]):
                scaled, _ = apply_protocol(pred, gt, "median", vm)
                errs.append(np.abs(scaled - gt) / gt)
            cat = categories(info, walked, m)
            truth = np.where(reg["ground"], "G", np.where(reg.get("agents", m), "A", "S"))
            for lo, hi in BANDS:
                b = vm & (gt >= lo) & (gt < hi)
                for c in np.unique(cat[b]):
                    for t in "GSA":
                        k = b & (cat == c) & (truth == t)
                        if k.any():
                            a = acc.setdefault((c, t, f"{lo}-{hi}m"), np.zeros(4))
                            a += [k.sum()] + [e[k].sum() for e in errs]
            total += [vm.sum(), errs[0][vm].sum(), errs[1][vm].sum()]
            # moved with a contact of their own (a filled pixel, e.g. a run an agent cut, has -1)
            k = vm & info["moved"] & reg["structures"] & (info["contact"] >= 0)
            if k.any():
                contact_ratio.append(gt.ravel()[info["contact"][k]] / gt[k])
    cr = np.concatenate(contact_ratio) if contact_ratio else np.zeros(0)
    cr = cr[np.isfinite(cr)]
    return {"acc": acc, "total": total, "contact_ratio": cr}


def report(name: str, res: dict, min_share: float) -> None:
    acc, (n, e, eb) = res["acc"], res["total"]
    print(f"\n{name}: pixel-weighted AbsRel aligned {e / n:.3f}, base {eb / n:.3f}")
    groups: dict = {}
    for (c, t, b), a in acc.items():
        for key in (b, t):
            groups.setdefault(key, np.zeros(4))
            groups[key] += a
    print("  " + "  ".join(f"{k}: {a[1] / a[0]:.3f} (base {a[2] / a[0]:.3f})"
                           for k, a in sorted(groups.items())))
    print(f"  {'category':15s} truth band    share  aligned  base  ground-mode  contrib")
    for (c, t, b), a in sorted(acc.items(), key=lambda kv: -kv[1][1]):
        if a[1] / n < min_share:
            continue
        print(f"  {c:15s} {t:5s} {b:7s} {a[0] / n:5.3f}  {a[1] / a[0]:7.3f} {a[2] / a[0]:5.3f}"
              f"  {a[3] / a[0]:11.3f}  {a[1] / n:7.4f}")
    cr = res["contact_ratio"]
    if len(cr):
        print(f"  traced structures: true depth at the contact / at the pixel, q10/50/90 "
              f"{' / '.join(f'{x:.2f}' for x in np.percentile(cr, [10, 50, 90]))}; "
              f"below 0.7 on {np.mean(cr < 0.7):.0%}")


def kept_run_parser(doc: str, runs: str) -> argparse.ArgumentParser:
    """The options of a bench over the runs ``bench_gains.py --keep`` left (also
    bench_align_twice.py): ``--work``, ``--runs``, ``--set``."""
    ap = argparse.ArgumentParser(description=doc,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", default="out/bench", help="bench_gains.py --keep's work folder")
    ap.add_argument("--runs", default=runs, help="sequences <scene>-m<model index>")
    ap.add_argument("--set", action="append", default=[], metavar="align.KEY=VALUE")
    return ap


def kept_runs(args):
    """(run, sequence path, ``--set`` settings) of each of ``--runs``; exits at a run without an
    adapt summary."""
    sets = dict(kv.split("=", 1) for kv in args.set)
    for run in args.runs.split(","):
        seq = os.path.join(args.work, f"{run}.h5")
        if not os.path.exists(seq + ".adapt.json"):
            sys.exit(f"{seq}: no adapt summary (run bench_gains.py --keep --work {args.work})")
        yield run, seq, sets


def main() -> None:
    ap = kept_run_parser(__doc__, "i4-m0,i4-m1")
    ap.add_argument("--oracle-ground", choices=("all", "beyond"))
    ap.add_argument("--min-share", type=float, default=0.002,
                    help="rows whose share of the frame's error is below this are left out")
    args = ap.parse_args()
    for run, seq, sets in kept_runs(args):
        report(run, analyse(seq, sets, args.oracle_ground), args.min_share)


if __name__ == "__main__":
    main()
