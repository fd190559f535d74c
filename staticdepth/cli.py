"""The ``staticdepth`` console script.

Each package contributes subcommands through a module with ``register(subparsers)``; each
subcommand's handler takes the parsed ``argparse.Namespace`` and returns an exit code.

Errors (:func:`main`): bad input is printed as ONE line, ``staticdepth CMD: error: PATH: problem``,
and exits 2, without a traceback. The rule that tells bad input from a bug:

- :class:`~staticdepth.errors.InputError` (raised where the input is checked, naming the file) and
  every ``OSError`` (the environment: missing, read-only, full, a folder where a file was meant,
  unreadable HDF5 chunks, which h5py raises as ``OSError``) are the user's to fix: one line.
- Exceptions a library raises while decoding a user's file (``cv2.error``, ``yaml.YAMLError``,
  ``UnicodeDecodeError``, ``json.JSONDecodeError``) are checked at their source where we know the
  path; the ones that slip through still print one line (the last net), naming the library.
- Anything else (``TypeError``, ``IndexError``, ``AssertionError`` of our code, ...) is a bug in
  staticdepth: it keeps its traceback so it can be reported and fixed.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from staticdepth import __version__
from staticdepth.errors import InputError
from staticdepth.models.trust import trusted_models

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


# Commands that load a model or checkpoint file: they take --trust-model (added by build_parser;
# a command registered elsewhere under one of these names gets it too). Space-separated names are
# nested subcommands.
TRUST_MODEL_COMMANDS = ("adapt", "run", "baseline train", "baseline predict", "predict",
                        "export-model", "locate")


class _Parser(argparse.ArgumentParser):
    """argparse exits 2 on usage errors already; keep its one-line message."""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="staticdepth",
                     description="Depth sensing with a fixed, high-mounted camera.")
    parser.add_argument("--version", action="version", version=f"staticdepth {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    commands = dict(_subcommands(parser))
    for name in TRUST_MODEL_COMMANDS:
        if name in commands:
            add_trust_model_argument(commands[name])
    return parser


def _subcommands(parser: argparse.ArgumentParser, prefix: str = ""):
    """(``"baseline predict"``, its parser) for every subcommand, nested ones included."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, p in action.choices.items():
                yield prefix + name, p
                yield from _subcommands(p, prefix + name + " ")


def add_trust_model_argument(p: argparse.ArgumentParser) -> None:
    """``--trust-model``: allow pickled torch files (they run code when loaded). Only the command
    line sets it; a recipe cannot (:func:`main` refuses it in a recipe's stages)."""
    if "--trust-model" not in p._option_string_actions:
        p.add_argument("--trust-model", action="store_true",
                       help="load pickled torch model/checkpoint files, which can run code when "
                            "loaded: only for files whose source you trust")


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
    """``--set key=value`` pairs into a dict (values still strings): :func:`staticdepth.config.parse_set`."""
    from staticdepth.config import parse_set

    return parse_set(items)


def main(argv: Sequence[str] | None = None, *, recipe: str | None = None) -> int:
    """Run one command; ``recipe`` names the recipe whose stage this is (it cannot trust models)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    trust = bool(getattr(args, "trust_model", False))
    try:
        if trust and recipe is not None:
            raise InputError("a recipe cannot pass --trust-model (pickled model files run code): "
                             "give --trust-model to 'staticdepth run' yourself", recipe)
        with trusted_models(trust):
            return int(args.func(args) or 0)
    except InputError as e:
        return _error(args.command, str(e))
    except OSError as e:
        return _error(args.command, _os_problem(e))
    except KeyboardInterrupt:
        print(f"staticdepth {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:
        problem = _library_input_error(e)
        if problem is None:
            raise  # a bug in staticdepth: keep the traceback
        return _error(args.command, problem)


def _error(command: str, message: str) -> int:
    line = " ".join(message.split()) or "failed"  # one line, whatever the message held
    print(f"staticdepth {command}: error: {line}", file=sys.stderr)
    return 2


def _os_problem(e: OSError) -> str:
    """``PATH: problem`` for an OSError; h5py's carry the path only in their text."""
    import errno
    import re

    from staticdepth.fileio import os_error

    path = e.filename
    if e.errno == errno.EISDIR and getattr(e, "filename2", None):
        path = e.filename2  # os.replace(tmp, out): the output is the folder
    if path is None:
        m = re.search(r"name = '([^']+)'", str(e))
        path = m.group(1) if m else None
    return str(os_error(e, path))


def _library_input_error(e: Exception) -> str | None:
    """The one-line problem for a library's error on user input (the last net), else None."""
    import json

    if isinstance(e, (UnicodeDecodeError, json.JSONDecodeError)):
        return f"a file is not valid text/JSON ({type(e).__name__}: {e})"
    mod = type(e).__module__ or ""
    if mod.startswith("cv2"):
        first = next((ln for ln in str(e).splitlines() if "error:" in ln), str(e))
        return f"OpenCV could not process an input ({first.strip()})"
    if mod.startswith("yaml"):
        return f"not valid YAML ({e})"
    return None


if __name__ == "__main__":
    sys.exit(main())
