"""The ``staticdepth`` console script.

Each package contributes subcommands through a module with ``register(subparsers)``; each
subcommand's handler takes the parsed ``argparse.Namespace`` and returns an exit code. Bad input
(:class:`~staticdepth.errors.InputError`, missing files) is printed as one line and exits 2.
"""
from __future__ import annotations

import argparse
import importlib
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
    "staticdepth.dataset.video",     # import-video
    "staticdepth.ground_plane",      # ground-plane
    "staticdepth.align",             # align
    "staticdepth.adapt",             # adapt, train-builtin
    "staticdepth.locate",            # locate
    "staticdepth.deploy",            # export-model, predict
    "staticdepth.baseline.cli",      # baseline train, baseline predict
    "staticdepth.evaluate",          # metrics, evaluate
    "staticdepth.report",            # report
    "staticdepth.run",               # run (recipes)
    "staticdepth.demo",              # demo
]


class _Parser(argparse.ArgumentParser):
    """argparse exits 2 on usage errors already; keep its one-line message."""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="staticdepth",
                     description="Depth sensing with a fixed, high-mounted camera.")
    parser.add_argument("--version", action="version", version=f"staticdepth {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


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
    parser = build_parser()
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
