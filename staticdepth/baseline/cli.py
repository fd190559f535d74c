"""Commands ``baseline train`` and ``baseline predict``."""
from __future__ import annotations

import argparse

from staticdepth.baseline.config import PRESETS


def register(sub) -> None:
    p = sub.add_parser("baseline", help="stereo self-supervised baseline (MonoDepth2 S)",
                       description="A monocular network trained on the scene's own stereo pairs "
                                   "with the real baseline, so its depth is metric: the upper "
                                   "bound the paper compares with.")
    bsub = p.add_subparsers(dest="baseline_command", metavar="ACTION", required=True)

    from staticdepth.cli import add_device_argument, add_overwrite_argument

    t = bsub.add_parser("train", help="train on the adaptation split's stereo pairs",
                        description="Train on the adaptation split's rectified stereo pairs. "
                                    "Resumes an unfinished checkpoint with the same settings "
                                    "and sequence; one trained on another sequence (the file "
                                    "replaced since) is refused unless --overwrite.",
                        epilog="example:\n  staticdepth baseline train c1.h5 --preset tiny "
                               "--set epochs=8")
    t.add_argument("sequence", help="sequence file (.h5) with left and right images")
    t.add_argument("--preset", default="default", choices=sorted(PRESETS),
                   help="network size and training schedule (tiny: a quick smoke run; site: the "
                        "tiny network at the sequence's resolution, for a CPU)")
    t.add_argument("--scene-fit", choices=("range", "all", "none"), default="all",
                   help="fit the depth range (range) and the network size (all) to the rig's "
                        "baseline and the scene's depths (default all; none: the preset as is)")
    t.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a setting, e.g. --set epochs=5 (repeatable)")
    t.add_argument("--weights", help="ImageNet ResNet18 weights: a local torchvision .pth")
    t.add_argument("--checkpoint", help="checkpoint file (default: SEQ.baseline.pt)")
    t.add_argument("--checkpoint-every", type=int, default=200, metavar="STEPS",
                   help="write the resumable checkpoint every STEPS (>= 1) optimisation steps, "
                        "and at the end of every epoch")
    t.add_argument("--overwrite", action="store_true",
                   help="start again, replacing the checkpoint (never the sequence or --weights)")
    add_device_argument(t)
    t.set_defaults(func=_train)

    q = bsub.add_parser("predict", help="predict metric depth for every frame",
                        description="Predict every frame's depth and store it beside the "
                                    "sequence as SEQ.h5.pred/NAME.h5 (the sequence file is not "
                                    "rewritten). An existing prediction NAME is replaced only "
                                    "with --overwrite.",
                        epilog="example:\n  staticdepth baseline predict c1.h5 --checkpoint "
                               "c1.baseline.pt")
    q.add_argument("sequence", help="sequence file (.h5) whose frames are predicted")
    q.add_argument("--checkpoint", help="trained checkpoint (default: SEQ.baseline.pt)")
    q.add_argument("--name", default="stereo-baseline",
                   help="prediction name: the file SEQ.h5.pred/NAME.h5 (default stereo-baseline)")
    q.add_argument("--batch-size", type=int, default=4, help="frames per forward pass")
    q.add_argument("--any-sequence", action="store_true",
                   help="predict with a checkpoint trained on another sequence (refused "
                        "otherwise: a stale SEQ.baseline.pt of a sequence since replaced)")
    add_overwrite_argument(q, help="replace the prediction SEQ.h5.pred/NAME.h5 if it exists "
                                   "(refused otherwise)")
    add_device_argument(q)
    q.set_defaults(func=_predict)


def _train(args: argparse.Namespace) -> int:
    from staticdepth.baseline.config import preset
    from staticdepth.baseline.train import (check_checkpoint_every, check_checkpoint_path,
                                            default_checkpoint_path, train)
    from staticdepth.cli import parse_overrides, resolve_device

    check_checkpoint_every(args.checkpoint_every)
    ckpt = args.checkpoint or default_checkpoint_path(args.sequence)
    check_checkpoint_path(ckpt, {"sequence": args.sequence, "weights": args.weights})
    overrides = parse_overrides(args.set)
    if args.weights:
        overrides["imagenet_weights"] = args.weights
    conf = preset(args.preset, overrides)
    if args.scene_fit != "none":
        from staticdepth.baseline.scene_fit import fit_to_scene
        from staticdepth.dataset.h5 import SequenceReader

        with SequenceReader(args.sequence) as r:
            conf = fit_to_scene(r, conf, explicit=overrides, fit_size=args.scene_fit == "all")
        print(f"scene fit: {conf.width}x{conf.height}, depth {conf.min_depth:.2f}-"
              f"{conf.max_depth:.0f} m")
    device = resolve_device(args.device)
    info = train(args.sequence, ckpt, conf, device, overwrite=args.overwrite,
                 checkpoint_every=args.checkpoint_every, log=print)
    loss = info["epoch_loss"]
    what = (f"{ckpt} kept, from an earlier run: {info['epochs']} epochs" if info["already_trained"]
            else f"trained {info['epochs']} epochs")        # nothing was trained now
    print(f"{what} ({info['steps']} steps, {info['frames']} frames, baseline "
          f"{info['baseline_m']:.3f} m)" + ("" if info["already_trained"] else f" -> {ckpt}")
          + (f"; loss {loss[0]:.4f} -> {loss[-1]:.4f}" if loss else ""))
    return 0


def _predict(args: argparse.Namespace) -> int:
    from staticdepth.baseline.predict import predict_sequence
    from staticdepth.baseline.train import default_checkpoint_path
    from staticdepth.cli import resolve_device

    ckpt = args.checkpoint or default_checkpoint_path(args.sequence)
    info = predict_sequence(args.sequence, ckpt, resolve_device(args.device), name=args.name,
                            batch_size=args.batch_size, overwrite=args.overwrite,
                            any_sequence=args.any_sequence, log=print)
    from staticdepth.dataset.predictions import prediction_path

    print(f"stored prediction {info['name']!r} ({info['frames']} frames, metric) -> "
          f"{prediction_path(args.sequence, info['name'])}")
    return 0
