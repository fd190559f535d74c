"""Deploy an adapted network on its camera: ``export-model`` (one ONNX file, image -> metric depth)
and ``predict`` (stream a video, folder or sequence through a model to metric depth; in
:mod:`staticdepth.deploy_predict`).

For a fixed camera the agents' plane, the ground region and the metric scale are constants, so the
whole chain of ``adapt`` after fine-tuning fits in one graph:

    uint8 RGB (H, W, 3) -> /255, resize, normalise -> network -> relative inverse depth D
    -> Z = 1 / max(D, eps) -> scene alignment (METHOD.md 4; geometry/alignment_torch.py, in the
    adapt summary's ``align.mode``: ``eq2``, ``ground`` or ``upright``) -> x scale (METHOD.md 5:
    the camera
    height) -> metric depth (H, W) float32

The reference it is checked against, :func:`metric_depth_reference`, is the same chain with the
model's own ``predict`` and the numpy :func:`~staticdepth.geometry.alignment.align_depth` in the
same mode. ``align.colour_foot`` (upright) is in both: the adaptation frames' median image, read
from the sequence as adapt reads it (adaptation.align.align_image), is a constant of the camera,
and so are its colour runs' feet (geometry/colour_foot_torch.py); metadata ``colour_foot`` says
whether it applies (as in adapt: an older summary without the setting, no). Not in the graph:
``align.agents_at_contact`` (each detected agent takes the plane depth at its contact pixel) needs
the frame's agent instances, which an image-only model has not; the reference leaves it out too,
and the ONNX file's metadata says so (``agents_at_contact``). Nor is the per-frame removal of the
agents' pixels from the ground mask (no detector in the loop).
Keys read from the adapt summary: ``plane.normal`` (or ``planes.agents.normal``),
``camera_height_m``, ``scale.ft-align`` (else the camera height), ``config.eps``,
``config.erode_px``, ``config.detector``, ``config.detector_model``, ``config.align.mode`` (an
older summary without it: ``eq2``), ``config.align.snap_rel``, the upright mode's
``config.align.shape/jump_rel/recede_min/recede_max/fill/max_pull/contact_range/recede_push/
walked_ratio/plane_bound/step_occlude/colour_foot``, and
``sequence``, ``size``, ``frames`` (checked against ``--sequence``: another scene's summary is
refused, :func:`staticdepth.locate.check_summary_of`), ``ground_polygon`` when present
(the ground region's vertices in pixels; otherwise the feet hull is rebuilt from the sequence's
agents or by running the summary's detector again).
"""
from __future__ import annotations

import os
import warnings
from typing import Any

import numpy as np

from staticdepth.errors import InputError
from staticdepth.config import setting_from


# -- the constants of a deployment -------------------------------------------------------------
def deployment_constants(summary_path: str, seq_path: str, ground_mask_png: str | None = None,
                         log=print) -> dict[str, Any]:
    """K, size, plane normal, scale, eps, the ground mask and (``align.colour_foot``) the static
    image for the exported graph."""
    from staticdepth.adaptation.align import align_image, upright_options
    from staticdepth.dataset.h5 import SequenceReader
    from staticdepth.geometry.camera import read_json
    from staticdepth.locate import check_summary_of, plane_from_summary

    s = read_json(summary_path)
    check_sees_ground(s, summary_path)            # the summary alone refuses it
    with SequenceReader(seq_path) as r:
        check_summary_of(s, summary_path, r)      # another scene's plane and scale: refused
    n_g, h_c = plane_from_summary(s, summary_path)
    scale = (s.get("scale") or {}).get("ft-align") if isinstance(s.get("scale"), dict) else None
    scale = float(scale) if scale else h_c
    cfg = s.get("config") if isinstance(s.get("config"), dict) else {}
    with SequenceReader(seq_path) as r:
        K, W, H = r.camera.K, r.width, r.height
        if ground_mask_png:
            from staticdepth.fileio import read_image

            G = read_image(ground_mask_png, flags=0) > 0
            if G.shape != (H, W):
                raise InputError(f"the ground mask is {G.shape[1]}x{G.shape[0]}, the camera "
                                 f"{W}x{H}", ground_mask_png)
            how = f"mask {ground_mask_png}"
        elif isinstance(s.get("ground_polygon"), list) and len(s["ground_polygon"]) >= 3:
            from staticdepth.geometry.alignment import ground_mask_from_polygon

            G = ground_mask_from_polygon(s["ground_polygon"], W, H)
            how = "the summary's ground_polygon"
        else:
            G, how = _ground_from_feet(r, cfg, log)
        mode = setting_from(cfg, "align.mode", "eq2")
        if mode not in ("eq2", "ground", "upright"):
            raise InputError(f"align.mode {mode!r} has no exported form (eq2, ground, upright)",
                             summary_path)
        ac = _align_config(cfg, mode)
        image = align_image(ac, r)           # adapt's: None where the setting is off
    return {"K": K, "width": W, "height": H, "normal": n_g, "camera_height_m": h_c,
            "scale": scale, "eps": float(setting_from(cfg, "predict.eps", 1e-6)), "ground": G,
            "ground_from": how, "mode": mode,
            "snap_rel": float(setting_from(cfg, "align.snap_rel", 0.1)),
            "upright": upright_options(ac) if mode == "upright" else {},
            "agents_at_contact": bool(setting_from(cfg, "align.agents_at_contact", False)),
            "image": image}


def check_sees_ground(s: dict, summary_path: str) -> None:
    """Refuse an adapt summary ``s`` whose ``ft-align`` was the plane alone
    (``align.min_ground_r2``: the fine-tuned network's ground R^2 was under the bar): the
    deployed chain would align a prediction adapt judged to be noise over the ground."""
    if "ft-align" in (s.get("align_plane_only") or []):
        r2 = (s.get("align_ground_r2") or {}).get("ft-align")
        bar = setting_from(s.get("config") if isinstance(s.get("config"), dict) else {},
                           "align.min_ground_r2", None)
        raise InputError(f"adapt found that the fine-tuned network does not see the agents' "
                         f"ground (R^2 {r2} under align.min_ground_r2 {bar}): its ft-align is "
                         f"the plane alone, which an image-only model cannot reproduce (adapt "
                         f"with --set align.min_ground_r2=0 aligns it anyway)", summary_path)


def _align_config(cfg: dict, mode: str):
    """The AlignConfig of a summary's config in ``mode`` (AlignConfig's defaults where absent;
    older summaries: no upright limits, no plane bound, no colour foot)."""
    from staticdepth.adaptation.config import AlignConfig

    d = AlignConfig()
    return AlignConfig(
        mode=mode, shape=str(setting_from(cfg, "align.shape", d.shape)),
        jump_rel=float(setting_from(cfg, "align.jump_rel", d.jump_rel)),
        recede_min=float(setting_from(cfg, "align.recede_min", d.recede_min)),
        recede_max=float(setting_from(cfg, "align.recede_max", d.recede_max)),
        fill=bool(setting_from(cfg, "align.fill", True)),       # older summaries: no limits
        max_pull=setting_from(cfg, "align.max_pull", None),
        recede_push=setting_from(cfg, "align.recede_push", None),
        contact_range=setting_from(cfg, "align.contact_range", None),
        walked_ratio=setting_from(cfg, "align.walked_ratio", None),
        plane_bound=bool(setting_from(cfg, "align.plane_bound", False)),
        step_occlude=bool(setting_from(cfg, "align.step_occlude", False)),
        colour_foot=bool(setting_from(cfg, "align.colour_foot", False)))


def _ground_from_feet(reader, cfg: dict, log) -> tuple[np.ndarray, str]:
    """adapt's ground region: the eroded hull of the adaptation split's foot points (the
    sequence's agents, else the summary's detector run again on the adaptation frames)."""
    from staticdepth.geometry.alignment import ground_mask_from_feet

    W, H = reader.width, reader.height
    split = reader.split("adapt")
    if len(split) == 0:
        split = range(len(reader))
    det = setting_from(cfg, "detector.name", "motion")
    if reader.has("instances") and det in ("gt", None):
        rows = [reader.agents(i) for i in split]
    else:
        from staticdepth.detectors import make_detector
        from staticdepth.detectors.frames import SequenceFrames

        opts = ({"model": setting_from(cfg, "detector.model", "")}
                if det in ("yolox", "mask2former") else {})
        log(f"ground region: running the {det} detector on {len(split)} adaptation frames")
        rows = [r for _, r in make_detector(det, **opts).detect_sequence(
            SequenceFrames(reader, split))]
    feet = [np.stack([r["foot_u"], r["foot_v"]], 1) for r in rows if len(r)]
    feet = np.concatenate(feet) if feet else np.zeros((0, 2))
    feet = feet[feet[:, 1] >= 0]
    erode = setting_from(cfg, "align.erode_px")
    erode = W / 80.0 if erode is None else float(erode)
    return ground_mask_from_feet(feet, W, H, erode), f"feet hull of {len(feet)} detections"


def metric_depth_reference(model, image: np.ndarray, c: dict[str, Any]) -> np.ndarray:
    """The pipeline the export must reproduce: predict, 1/max(D, eps), align (numpy, the summary's
    mode, the colour foot on the static image when it applies; no agents_at_contact), x scale."""
    from staticdepth.geometry.alignment import align_depth, depth_from_inverse

    Z = depth_from_inverse(model.predict(image), c["eps"])
    return align_depth(Z, c["K"], c["normal"], 1.0, c["ground"], mode=c["mode"],
                       snap_rel=c["snap_rel"], image=c.get("image"), **c.get("upright", {})
                       ).depth * np.float32(c["scale"])


# -- the exported graph --------------------------------------------------------------------------
def metric_graph(model, c: dict[str, Any]):
    """A torch module mapping (H, W, 3) uint8 RGB to (H, W) float32 metric depth."""
    import torch
    from torch import nn

    import torch.nn.functional as F

    from staticdepth.geometry.alignment_torch import alignment_module

    H, W = c["height"], c["width"]
    h, w = model.input_size(H, W)

    class MetricDepth(nn.Module):
        def __init__(self):
            super().__init__()
            self.net = model.net
            self.align = alignment_module(c["mode"], c["K"], c["width"], c["height"],
                                          c["normal"], 1.0, c["ground"], snap_rel=c["snap_rel"],
                                          image=c.get("image"), **c.get("upright", {}))
            self.eps, self.scale = float(c["eps"]), float(c["scale"])

        def forward(self, image: torch.Tensor) -> torch.Tensor:
            # TorchDepthModel.forward with the sizes fixed (the camera's): resize, normalise,
            # run, resize back
            x = image.to(torch.float32).permute(2, 0, 1)[None] / 255.0
            if (h, w) != (H, W):
                x = F.interpolate(x, size=(h, w), mode="bicubic", align_corners=False)
            x = (x - model._mean) / model._std
            y = self.net(**{model.input_kw: x}) if model.input_kw else self.net(x)
            if model.output is not None:
                y = getattr(y, model.output) if hasattr(y, model.output) else y[model.output]
            if y.dim() == 3:
                y = y[:, None]
            if tuple(y.shape[-2:]) != (H, W):
                y = F.interpolate(y, size=(H, W), mode="bilinear", align_corners=False)
            D = y[0, 0]
            Z = 1.0 / torch.clamp(D, min=self.eps)
            return self.align(Z) * self.scale

    return MetricDepth().eval()


def export_model(model_spec: str, summary_path: str, seq_path: str, out: str, *,
                 ground_mask_png: str | None = None, check_frames: int = 5, opset: int = 17,
                 log=print) -> dict[str, Any]:
    """Write the ONNX file ``out`` and check it against :func:`metric_depth_reference` on
    ``check_frames`` frames of the sequence; returns the constants and the check's figures.
    Every option and ``out``'s folder are checked before any work; the file is written to a
    temporary, checked there and renamed onto ``out`` only when the check has run (a failure
    leaves nothing at ``out``)."""
    import torch

    from staticdepth.fileio import atomic_path, check_writable
    from staticdepth.models import TorchDepthModel, load_model

    check_export_options(out, check_frames, opset)
    check_writable(out)
    model = load_model(model_spec)
    if not isinstance(model, TorchDepthModel):
        raise InputError(f"export needs a torch model (builtin:, torch:, hf:), got {model_spec!r}")
    model.to("cpu").net.eval()
    c = deployment_constants(summary_path, seq_path, ground_mask_png, log)
    if c["agents_at_contact"]:
        log("note: adapt gave each detected agent its contact depth (align.agents_at_contact); "
            "an image-only model cannot: agents keep the aligned network depth")
    graph = metric_graph(model, c)
    dummy = torch.zeros((c["height"], c["width"], 3), dtype=torch.uint8)
    info = {k: c[k] for k in ("width", "height", "camera_height_m", "scale", "ground_from",
                              "mode")}
    info["normal"] = np.asarray(c["normal"]).tolist()
    info["path"] = out
    with atomic_path(out, "onnx") as tmp:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")              # tracer notes on the fixed sizes
            kw = {"dynamo": False} if "dynamo" in torch.onnx.export.__code__.co_varnames else {}
            try:
                torch.onnx.export(graph, (dummy,), tmp, input_names=["image"],
                                  output_names=["depth_m"], opset_version=opset, **kw)
            except torch.onnx.errors.OnnxExporterError as e:
                raise InputError(f"--opset {opset}: the graph cannot be exported at this opset "
                                 f"({str(e).splitlines()[0]})", out) from None
        meta = export_metadata(c, model_spec, summary_path)
        with open(tmp, "ab") as f:
            f.write(_onnx_metadata_bytes(meta))
        info.update(check_export(tmp, model, c, seq_path, check_frames))
    return info


#: Opsets the exported graph is written in: bicubic resizing needs 11, and onnxruntime's CPU
#: Clip of opset 11 does not take the graph's types; the top is the installed torch's.
MIN_OPSET = 12


def max_opset() -> int:
    """The newest opset the installed torch's exporter writes."""
    try:
        from torch.onnx import _constants
    except ImportError:                 # pragma: no cover (a torch without the module)
        return 17
    return int(getattr(_constants, "ONNX_MAX_OPSET", 17))


def check_export_options(out: str, check_frames: int, opset: int) -> None:
    """Refuse, before any work, an output not named ``.onnx``, ``check_frames`` under 1 (the
    export is always checked) and an opset outside :data:`MIN_OPSET`..:func:`max_opset`."""
    if not str(out).lower().endswith(".onnx"):
        raise InputError("export-model writes an ONNX graph: name the file .onnx", out)
    if isinstance(check_frames, bool) or not isinstance(check_frames, int) or check_frames < 1:
        raise InputError(f"--check-frames must be at least 1 (the export is checked against the "
                         f"torch/numpy pipeline), got {check_frames}")
    top = max_opset()
    if isinstance(opset, bool) or not isinstance(opset, int) or not MIN_OPSET <= opset <= top:
        raise InputError(f"--opset must be from {MIN_OPSET} to {top}, got {opset}")


def export_metadata(c: dict[str, Any], model_spec: str, summary_path: str) -> dict[str, str]:
    """What the exported file computes, as the ONNX model's metadata (string key -> value)."""
    return {"staticdepth.output": "metric depth (m), float32 (H, W); input uint8 RGB (H, W, 3)",
            "staticdepth.align_mode": c["mode"], "staticdepth.snap_rel": f"{c['snap_rel']:g}",
            **({"staticdepth.upright": ", ".join(f"{k}={v}" for k, v in c["upright"].items())}
               if c.get("upright") else {}),
            "staticdepth.scale": f"{c['scale']:.6g}",
            "staticdepth.camera_height_m": f"{c['camera_height_m']:.6g}",
            "staticdepth.ground_from": str(c["ground_from"]),
            "staticdepth.agents_at_contact": ("not applied: it needs the frame's agent instances "
                                              "(adapt " + ("applied it" if c["agents_at_contact"]
                                                           else "did not apply it either") + ")"),
            "staticdepth.colour_foot": ("applied: the adaptation frames' median image"
                                        if c.get("image") is not None else "not applied (adapt "
                                        "did not apply it either: align.colour_foot off or "
                                        "absent, or align.mode not upright)"),
            "staticdepth.model": model_spec, "staticdepth.summary": os.path.basename(summary_path)}


def _onnx_metadata_bytes(meta: dict[str, str]) -> bytes:
    """``ModelProto.metadata_props`` entries (field 14, StringStringEntryProto key=1, value=2)
    serialised; appended to a serialised ModelProto they add to its repeated field (protobuf
    merges concatenated messages), so no ``onnx`` package is needed."""
    def varint(n: int) -> bytes:
        out = bytearray()
        while True:
            b, n = n & 0x7F, n >> 7
            out.append(b | (0x80 if n else 0))
            if not n:
                return bytes(out)

    def field(num: int, payload: bytes) -> bytes:
        return varint(num << 3 | 2) + varint(len(payload)) + payload

    return b"".join(field(14, field(1, k.encode()) + field(2, v.encode()))
                    for k, v in meta.items())


def check_export(onnx_path: str, model, c: dict[str, Any], seq_path: str, frames: int = 5
                 ) -> dict[str, float]:
    """Median and 99th-percentile relative difference of the ONNX output vs the reference."""
    from staticdepth.dataset.h5 import SequenceReader

    sess = MetricOnnx(onnx_path)
    rels = []
    with SequenceReader(seq_path) as r:
        for i in np.linspace(0, len(r) - 1, min(frames, len(r))).astype(int):
            img = r.left(int(i))
            ref = metric_depth_reference(model, img, c)
            got = sess.predict(img)
            ok = np.isfinite(ref) & (ref > 0)
            rels.append(np.abs(got[ok] - ref[ok]) / ref[ok])
    rel = np.concatenate(rels)
    return {"check_frames": len(rels), "median_rel_diff": float(np.median(rel)),
            "p99_rel_diff": float(np.percentile(rel, 99))}


class MetricOnnx:
    """An exported metric model: (H, W, 3) uint8 RGB -> (H, W) metric depth."""

    def __init__(self, path: str, providers=None, threads: int | None = None):
        from staticdepth.onnx_session import onnx_session

        self.session = onnx_session(path, providers or ("CPUExecutionProvider",),
                                    threads=threads, what="exported model")
        inp = self.session.get_inputs()[0]
        if len(inp.shape) != 3 or inp.type != "tensor(uint8)":
            raise InputError("not an exported metric model (expects one (H, W, 3) uint8 input)",
                             path)
        self.name, self.shape, self.path = inp.name, tuple(inp.shape), path
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)

    def predict(self, image: np.ndarray) -> np.ndarray:
        """A frame of another size with the same aspect (the video before ``import-video
        --width``) is resized to the model's; the depth is at the model's size."""
        img = camera_frame(image, self.shape[1], self.shape[0], self.path)
        return self.session.run(None, {self.name: img})[0]


def camera_frame(image: np.ndarray, width: int, height: int, where: str) -> np.ndarray:
    """The frame at the deployed camera's size: a frame of another size with the same aspect (the
    video before ``import-video --width``) is resized (area); another aspect is refused."""
    img = np.ascontiguousarray(image, dtype=np.uint8)
    if img.shape != (height, width, 3):
        if (img.ndim != 3 or img.shape[2] != 3
                or abs(img.shape[1] / img.shape[0] - width / height) > 0.01 * width / height):
            raise InputError(f"frame is {img.shape}, the exported model takes "
                             f"{(height, width, 3)}", where)
        import cv2

        img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    return img


# -- command line --------------------------------------------------------------------------------
def register(sub) -> None:
    p = sub.add_parser("export-model", help="the adapted network + alignment + metric scale as one "
                                            "ONNX file (image -> metric depth)",
                       description="Export, for one fixed camera, the adapted network with the "
                                   "agents' plane, the ground region and the metric scale baked "
                                   "in: (H, W, 3) uint8 RGB -> (H, W) float32 metres. Checked "
                                   "against the torch/numpy pipeline on a few frames.")
    p.add_argument("--model", required=True, help="the adapted torch model: builtin:PATH.pt "
                                                  "(adapt --save-model), torch:FILE, hf:DIR")
    p.add_argument("--summary", required=True, help="adapt summary (SEQ.adapt.json)")
    p.add_argument("--sequence", required=True, help="the adapted sequence (camera, agents)")
    p.add_argument("--ground-mask", help="ground region PNG (default: adapt's feet hull)")
    p.add_argument("--out", required=True, help="output .onnx")
    p.add_argument("--check-frames", type=int, default=5,
                   help="frames on which the export is checked against the torch/numpy pipeline")
    p.add_argument("--opset", type=int, default=17, help="ONNX opset of the exported file")
    from staticdepth.cli import add_device_argument, add_overwrite_argument

    add_overwrite_argument(p)
    p.set_defaults(func=_run_export)

    p = sub.add_parser("predict", help="stream a video, folder or sequence through a model to "
                                       "(metric) depth",
                       description="Depth for every frame with any model spec; metric with an "
                                   "exported model, or with --summary and --sequence. Prints "
                                   "frames per second.")
    p.add_argument("--model", required=True, help="exported .onnx, or a model SPEC")
    p.add_argument("--input", required=True, help="video, image folder, URL or SEQ.h5")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--format", default="png16", choices=("png16", "npy", "mp4"),
                   help="png16: uint16 depth x scale (0 = unknown; the scale in the PNG's "
                        "text chunk staticdepth.depth_scale: 256 for metres, 65535 / the "
                        "frame's largest depth for relative depth); npy: float32; mp4: colour "
                        "map with a colour bar at the source's frame rate / --every")
    p.add_argument("--summary", help="adapt summary (metric output for a model SPEC)")
    p.add_argument("--sequence", help="the adapted sequence (with --summary)")
    p.add_argument("--every", type=int, default=1,
                   help="keep every K-th frame (files are named by the source frame index)")
    p.add_argument("--max-frames", type=int, default=None,
                   help="stop after N kept frames (source frames 0, K, ..., (N-1)K)")
    add_device_argument(p)
    add_overwrite_argument(p, help="write into an output folder that holds files already "
                                   "(same-named frames are replaced, an earlier run's other "
                                   "frames removed at the end; refused otherwise)")
    p.set_defaults(func=_run_predict)


def _run_export(args) -> int:
    from staticdepth.cli import refuse_existing

    check_export_options(args.out, args.check_frames, args.opset)
    refuse_existing(args.out, overwrite=args.overwrite)
    info = export_model(args.model, args.summary, args.sequence, args.out,
                        ground_mask_png=args.ground_mask, check_frames=args.check_frames,
                        opset=args.opset)
    print(f"exported {info['width']}x{info['height']} -> metric depth: {info['path']} (scale "
          f"{info['scale']:.3f}, align.mode {info['mode']}, ground region: {info['ground_from']})")
    print(f"check on {info['check_frames']} frames vs the torch/numpy pipeline: median relative "
          f"difference {100 * info['median_rel_diff']:.4f}%, p99 {100 * info['p99_rel_diff']:.3f}%")
    return 0


def _run_predict(args) -> int:
    from staticdepth.deploy_predict import predict

    if os.path.isdir(args.out) and os.listdir(args.out) and not args.overwrite:
        raise InputError("exists already and holds files; pass --overwrite to write into "
                         "it", args.out)
    rep = predict(args.model, args.input, args.out, args.format, summary=args.summary,
                  sequence=args.sequence, every=args.every, max_frames=args.max_frames,
                  device=args.device)
    step = f", every {rep['every']}" if rep["every"] > 1 else ""
    video = f" at {rep['video_fps']:.3g} frames/s" if rep.get("video_fps") else ""
    print(f"{rep['frames']} frames (source frames {rep['first_index']}-{rep['last_index']}"
          f"{step}) of {rep['kind']} depth -> {rep['out']}{video}: "
          f"{rep['fps_model']:.1f} frames/s (model), {rep['fps_total']:.1f} frames/s overall")
    return 0
