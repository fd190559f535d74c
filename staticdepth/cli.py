"""The ``staticdepth`` console script.

Each package contributes subcommands through a module with ``register(subparsers)``; each
subcommand's handler takes the parsed ``argparse.Namespace`` and returns an exit code. Bad input
(:class:`~staticdepth.errors.InputError`, missing files) is printed as one line and exits 2.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import Sequence

from staticdepth import __version__
from staticdepth.errors import InputError

# Modules that contribute subcommands, in the order their commands are listed in --help.
COMMAND_MODULES = [
    "staticdepth.capture.cli",       # capture
    "staticdepth.stereo.cli",        # calibrate, mount, stereo
    "staticdepth.stereo.rig_cli",    # import-rig
    "staticdepth.dataset.cli",       # synth, inspect, verify
    "staticdepth.dataset.commands",  # pack, import-kitti, import-carla, export, publish
    "staticdepth.observations",      # observations
    "staticdepth.ground_plane",      # ground-plane
    "staticdepth.align",             # align
    "staticdepth.adapt",             # adapt, train-builtin
    "staticdepth.baseline.cli",      # baseline train, baseline predict
    "staticdepth.evaluate",          # metrics, evaluate
    "staticdepth.report",            # report
    "staticdepth.run",               # run (recipes)
    "staticdepth.demo",              # demo
]

# Start-up: `staticdepth CMD ...` imports only the module that registers CMD (torch, scipy and
# h5py load only for the commands that use them); `staticdepth --help` imports none. The table
# gives each command's module, one-line help and example; tests/test_cli_startup.py checks it
# against the modules' own registrations. A command missing here still works (every module is
# imported then).
COMMANDS: dict[str, tuple[str, str, str]] = {
    "capture": ("staticdepth.capture.cli",
                "record a stereo rig losslessly (DepthAI, UVC cameras, replay)",
                "staticdepth capture --source uvc --device 0,1 --size 1280x800 --out rec/site1"),
    "calibrate": ("staticdepth.stereo.cli", "stereo calibration from board image pairs",
                  "staticdepth calibrate --board 9x6 --square 0.025 --left 'calib/left*.png' "
                  "--right 'calib/right*.png' --out rig.json"),
    "stereo": ("staticdepth.stereo.cli", "depth from stereo pairs (SGBM or an ONNX network)",
               "staticdepth stereo --rig rig.json --left left/ --right right/ --out seq.h5\n"
               "  staticdepth stereo --rectified --left im0.png --right im1.png "
               "--max-disparity 256 --disparity-out disp.pfm"),
    "mount": ("staticdepth.stereo.cli", "camera height and ground plane from a board on the ground",
              "staticdepth mount --rig rig.json --images 'ground/*.png' --board 9x6 --square 0.1 "
              "--out rig.json"),
    "import-rig": ("staticdepth.stereo.rig_cli",
                   "rig JSON from a DepthAI, Middlebury or KITTI calibration",
                   "staticdepth import-rig calib.txt --from middlebury --out rig.json"),
    "synth": ("staticdepth.dataset.cli", "render a synthetic fixed-camera stereo sequence",
              "staticdepth synth --preset c1 --frames 200 --adapt-frames 80 --out c1.h5"),
    "inspect": ("staticdepth.dataset.cli", "summarise and check a sequence file",
                "staticdepth inspect c1.h5 --sheet c1.png"),
    "verify": ("staticdepth.dataset.cli", "check integrity and checksums of sequences or a release",
               "staticdepth verify c1.h5"),
    "pack": ("staticdepth.dataset.commands",
             "pack a stereo recording into a sequence file with stereo depth",
             "staticdepth pack --recording rec/site1 --rig rig.json --camera-height 5.0 "
             "--adapt-frames 684 --out R1.h5"),
    "import-kitti": ("staticdepth.dataset.commands",
                     "import KITTI raw drives with LiDAR ground truth",
                     "staticdepth import-kitti --root KITTI_RAW --drives 2011_09_28_drive_0016 "
                     "--name K1 --adapt-frames 273 --out K1.h5"),
    "import-carla": ("staticdepth.dataset.commands", "import frames saved from CARLA's sensors",
                     "staticdepth import-carla carla_out/ --adapt-frames 342 --out C1.h5"),
    "export": ("staticdepth.dataset.commands", "export a sequence file to KITTI-style folders",
               "staticdepth export K1.h5 --format kitti --out K1_kitti/"),
    "publish": ("staticdepth.dataset.commands",
                "make a release folder: sequences, export, card, manifest",
                "staticdepth publish K1.h5 --out release/ --licence CC-BY-4.0 --citation '...'"),
    "observations": ("staticdepth.observations",
                     "agents' foot points and heights (obs.csv) for ground-plane",
                     "staticdepth observations c1.h5 --camera-out cam.json --out obs.csv\n"
                     "  staticdepth observations vtest.avi --detector yolox "
                     "--detector-model yolox_nano.onnx --out obs.csv"),
    "ground-plane": ("staticdepth.ground_plane",
                     "ground plane from agents' foot points and heights",
                     "staticdepth ground-plane --observations obs.csv --intrinsics cam.json "
                     "--agent-height 1.7 --out plane.json"),
    "align": ("staticdepth.align", "align predicted depth to the agents' ground plane",
              "staticdepth align --pred pred.npy --inverse --intrinsics cam.json --plane plane.json"
              " --ground-mask ground.png --camera-height 5.2 --out aligned.npy"),
    "adapt": ("staticdepth.adapt", "adapt a depth network to a static camera's sequence",
              "staticdepth adapt c1.h5 --model builtin --detector motion"),
    "train-builtin": ("staticdepth.adapt", "train the built-in small depth network",
                      "staticdepth train-builtin --frames 400 --epochs 15"),
    "baseline": ("staticdepth.baseline.cli", "stereo self-supervised baseline (MonoDepth2 S)",
                 "staticdepth baseline train c1.h5 --preset tiny && "
                 "staticdepth baseline predict c1.h5"),
    "metrics": ("staticdepth.evaluate", "depth metrics of .npy predictions against ground truth",
                "staticdepth metrics --pred pred.npy --gt gt.npy --protocol median --json m.json"),
    "evaluate": ("staticdepth.evaluate", "evaluate the predictions stored in a sequence file",
                 "staticdepth evaluate c1.h5 --json results.json"),
    "report": ("staticdepth.report", "tables and an HTML report for evaluated sequences",
               "staticdepth report C1=runs/C1/C1.h5 --summary C1=runs/C1/C1.adapt.json "
               "--out report/"),
    "run": ("staticdepth.run", "run a scene recipe (import, adapt, baseline, evaluation)",
            "staticdepth run recipes/K1.yaml --var kitti_raw=/data/kitti_raw"),
    "demo": ("staticdepth.demo", "run the whole pipeline on a built-in synthetic scene",
             "staticdepth demo --out demo_out"),
}


class _Formatter(argparse.HelpFormatter):
    """Examples keep their lines; every option with a default shows it."""

    def _fill_text(self, text, width, indent):
        if text.startswith("example"):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)

    def _get_help_string(self, action):
        text = action.help or ""
        if ("default" not in text.lower()
                and action.default not in (None, False, [], "", argparse.SUPPRESS)
                and action.option_strings):
            text += " (default: %(default)s)"
        return text


class _Parser(argparse.ArgumentParser):
    """argparse exits 2 on usage errors already; keep its one-line message."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)


def _top_parser():
    parser = _Parser(prog="staticdepth",
                     description="Depth sensing with a fixed, high-mounted camera.",
                     epilog="`staticdepth COMMAND --help` describes a command, with an example.")
    parser.add_argument("--version", action="version", version=f"staticdepth {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    return parser, sub


def _add_examples(sub) -> None:
    for name, p in sub.choices.items():
        if name in COMMANDS and p.epilog is None:
            p.epilog = "example:\n  " + COMMANDS[name][2]


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The command-line parser; with ``argv``, only the module of the command it names is
    imported (the other commands are listed by name and help only)."""
    parser, sub = _top_parser()
    command = None if argv is None else next((a for a in argv if not a.startswith("-")), "")
    if command is None or (command and command not in COMMANDS):
        for name in COMMAND_MODULES:
            importlib.import_module(name).register(sub)
        _add_examples(sub)
        return parser
    module = COMMANDS[command][0] if command else None
    if module:
        importlib.import_module(module).register(sub)
    for name, (mod, help_text, _) in COMMANDS.items():
        if mod != module and name not in sub.choices:
            sub.add_parser(name, help=help_text)
    _add_examples(sub)
    return parser


def add_overwrite_argument(p: argparse.ArgumentParser) -> None:
    """``--overwrite``: the one rule for every output (sequence files, JSON, images, folders)."""
    p.add_argument("--overwrite", action="store_true",
                   help="replace outputs that exist already (refused otherwise)")


def refuse_existing(*paths, overwrite: bool) -> None:
    """Raise :class:`InputError` for the first output that exists, unless ``overwrite``."""
    for path in paths:
        if path and os.path.lexists(path) and not overwrite:
            raise InputError("exists already; pass --overwrite to replace it", os.fspath(path))


def add_device_argument(p: argparse.ArgumentParser) -> None:
    """``--device auto|cpu|cuda[:N]``, resolved at the edge by :func:`resolve_device`."""
    p.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda, cuda:N")


def resolve_device(name: str):
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise InputError(f"unknown device {name!r} (use auto, cpu, cuda or cuda:N)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"device {name!r} requested but CUDA is not available")
    return dev


def parse_overrides(items: Sequence[str] | None) -> dict[str, str]:
    """``--set key=value`` pairs into a dict (values still strings)."""
    out: dict[str, str] = {}
    for item in items or ():
        if "=" not in item:
            raise InputError(f"--set expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except InputError as e:
        print(f"staticdepth {args.command}: error: {e}", file=sys.stderr)
        return 2
    except FileNotFoundError as e:
        print(f"staticdepth {args.command}: error: {e.filename}: file not found", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"staticdepth {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
