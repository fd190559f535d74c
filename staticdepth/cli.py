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
import contextlib
import importlib
import os
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
    "staticdepth.observations",      # observations
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
    "import-video": ("staticdepth.dataset.video",
                     "import a video, an image folder or a camera URL (no ground truth)",
                     "staticdepth import-video vtest.avi --fov-deg 60 --adapt-frames 200 --out site.h5"),
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
                      "staticdepth train-builtin --out builtin.pt --frames 400 --epochs 15"),
    "locate": ("staticdepth.locate", "agents' positions in metres, speeds, distances between people",
               "staticdepth locate site.h5 --summary site.adapt.json --out positions.csv"),
    "export-model": ("staticdepth.deploy",
                     "the adapted network + alignment + metric scale as one ONNX file (image -> "
                     "metric depth)",
                     "staticdepth export-model --model builtin:site.ft.pt --summary site.adapt.json "
                     "--sequence site.h5 --out site_metric.onnx"),
    "predict": ("staticdepth.deploy", "stream a video, folder or sequence through a model to "
                "(metric) depth", "staticdepth predict --model site_metric.onnx --input vtest.avi "
                "--out depth/ --format png16"),
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


# Commands that load a model or checkpoint file: they take --trust-model (added by build_parser;
# a command registered elsewhere under one of these names gets it too). Space-separated names are
# nested subcommands.
TRUST_MODEL_COMMANDS = ("adapt", "run", "baseline train", "baseline predict", "predict",
                        "export-model", "locate")


class _Parser(argparse.ArgumentParser):
    """A usage error is one line and exit code 2 (argparse printed the whole usage block above
    it: 7 lines for adapt, more inside a recipe's run); ``--help`` shows the usage."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


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
        _add_trust_model_arguments(parser)
        return parser
    module = COMMANDS[command][0] if command else None
    if module:
        importlib.import_module(module).register(sub)
    for name, (mod, help_text, _) in COMMANDS.items():
        if mod != module and name not in sub.choices:
            sub.add_parser(name, help=help_text)
    _add_examples(sub)
    _add_trust_model_arguments(parser)
    return parser


def add_overwrite_argument(p: argparse.ArgumentParser, help: str | None = None) -> None:
    """``--overwrite``: the one rule for every output (sequence files, JSON, images, folders);
    ``help`` names the outputs when a command has some that are never replaced."""
    p.add_argument("--overwrite", action="store_true",
                   help=help or "replace outputs that exist already (refused otherwise)")


def refuse_existing(*paths, overwrite: bool) -> None:
    """Raise :class:`InputError` for the first output that exists, unless ``overwrite``."""
    for path in paths:
        if path and os.path.lexists(path) and not overwrite:
            raise InputError("exists already; pass --overwrite to replace it", os.fspath(path))


# options that name a file or folder a command writes (every other path argument is read)
OUTPUT_DESTS = ("out", "json", "camera_out", "disparity_out", "summary_json", "bev", "annotate",
                "ply", "save_model", "sheet", "pairs")
# read and written on purpose: ``mount --rig rig.json --out rig.json`` adds the mount to the rig
IN_PLACE = {("mount", "out", "rig")}
NEITHER = ("checkpoint", "func", "command", "set", "var")   # resumed from and written; not paths
# the outputs that are HDF5 files (sequences) or images: no other output replaces an existing
# file of those kinds, even with --overwrite (``metrics --json seq.h5 --overwrite`` replaced a
# sequence with JSON, ``train-builtin --out photo.png --overwrite`` a photo with weights)
HDF5_OUTPUTS = {("synth", "out"), ("pack", "out"), ("import-kitti", "out"),
                ("import-carla", "out"), ("import-video", "out"), ("stereo", "out")}
IMAGE_OUTPUTS = {("locate", "bev"), ("inspect", "sheet"), ("stereo", "disparity_out")}
KIND_WRITERS = {"hdf5": HDF5_OUTPUTS, "png": IMAGE_OUTPUTS, "jpeg": IMAGE_OUTPUTS}
# a sequence's companions, read with it: its prediction store and adapt's stage files
COMPANIONS = (".pred", ".adapt")


def _flag(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def _path_values(value) -> list[str]:
    vals = value if isinstance(value, (list, tuple)) else [value]
    return [os.fspath(v) for v in vals if isinstance(v, (str, os.PathLike)) and v]


def _same(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _companion(out: str, seq: str) -> str | None:
    """The companion folder (``SEQ.pred``, ``SEQ.adapt``) of the file ``seq`` that holds the
    path ``out``, else None."""
    if not os.path.isfile(seq):
        return None
    real = os.path.realpath(out)
    for suffix in COMPANIONS:
        folder = os.path.realpath(seq) + suffix
        if real == folder or real.startswith(folder + os.sep):
            return os.fspath(seq) + suffix + os.sep
    return None


def refuse_foreign_kind(path: str, option: str, command: str, dest: str) -> None:
    """An existing ``path`` that holds a file of a kind the output does not write (a sequence,
    a prediction, an image) is refused in one line, even with --overwrite: --overwrite replaces
    an earlier output, not the user's data."""
    from staticdepth.fileio import KIND_NAMES, file_kind

    kind = file_kind(path)          # None: a folder or unreadable: the command says what's wrong
    if kind in KIND_WRITERS and (command, dest) not in KIND_WRITERS[kind]:
        raise InputError(f"{option} names {KIND_NAMES[kind]}, which this command does not "
                         "write: even with --overwrite it is not replaced; choose another output",
                         path)


def refuse_output_over_input(args: argparse.Namespace) -> None:
    """Refuse, before any work, an output that is also one of the command's inputs or another
    output (``evaluate seq.h5 --json seq.h5 --overwrite`` replaced the sequence with JSON): one
    line naming the file and both options. Existing files are compared with ``samefile`` (links,
    relative paths), names not yet written by their real path. Also refused: an output inside an
    input sequence's prediction store or stage folder (``evaluate SEQ --json
    SEQ.pred/base.h5``), and an existing HDF5 file or image under any output but one that writes
    such files (:func:`refuse_foreign_kind`; ``metrics --json other.h5`` replaced a sequence
    the command does not read)."""
    outs = [(d, p) for d in OUTPUT_DESTS for p in _path_values(getattr(args, d, None))]
    ins = [(d, p) for d, v in vars(args).items()
           if d not in OUTPUT_DESTS and d not in NEITHER for p in _path_values(v)
           if os.path.exists(p)]
    for k, (dest, out) in enumerate(outs):
        for other, p in outs[k + 1:]:
            if _same(out, p):
                raise InputError(f"{_flag(dest)} and {_flag(other)} name the same file", out)
        for src, p in ins:
            folder = _companion(out, p)
            if folder:
                raise InputError(f"{_flag(dest)} lies in {folder}, a folder of this "
                                 f"command's input ({src.replace('_', '-')}) that it reads: "
                                 "choose another output", out)
        if not os.path.exists(out):
            continue
        for src, p in ins:
            if _same(out, p) and (args.command, dest, src) not in IN_PLACE:
                raise InputError(f"{_flag(dest)} names this command's input "
                                 f"({src.replace('_', '-')}): writing it would destroy the input; "
                                 "choose another output", out)
        refuse_foreign_kind(out, _flag(dest), args.command, dest)


def _add_trust_model_arguments(parser: argparse.ArgumentParser) -> None:
    commands = dict(_subcommands(parser))
    for name in TRUST_MODEL_COMMANDS:
        if name in commands:
            add_trust_model_argument(commands[name])


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


def parse_overrides(items: Sequence[str] | None, option: str = "--set") -> dict[str, str]:
    """``--set key=value`` pairs into a dict (values still strings):
    :func:`staticdepth.config.parse_set`; ``option`` names the option in errors."""
    from staticdepth.config import parse_set

    return parse_set(items, option)


LIBRARY_LOG_LEVELS = {"OPENCV_LOG_LEVEL": "ERROR", "DEPTHAI_LEVEL": "error"}


def main(argv: Sequence[str] | None = None, *, recipe: str | None = None) -> int:
    """Run one command; ``recipe`` names the recipe whose stage this is (it cannot trust models)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    # OpenCV's and DepthAI's warnings ('[ WARN:0@0.07] global cap_v4l.cpp ... can't open camera
    # by index') came before our one error line; their errors still print (the environment's
    # own setting wins)
    for key, level in LIBRARY_LOG_LEVELS.items():
        os.environ.setdefault(key, level)
    parser = build_parser(argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:              # --help, --version, or a usage error (said already)
        return e.code if isinstance(e.code, int) else 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    trust = bool(getattr(args, "trust_model", False))
    try:
        if trust and recipe is not None:
            raise InputError("a recipe cannot pass --trust-model (pickled model files run code): "
                             "give --trust-model to 'staticdepth run' yourself", recipe)
        refuse_output_over_input(args)
        with trusted_models(trust):
            return int(args.func(args) or 0)
    except InputError as e:
        return _error(args.command, str(e))
    except BrokenPipeError:
        # `inspect ... | head`: the reader left. No error line; the status of a process that
        # SIGPIPE stopped (128 + 13), since whatever followed the print did not run
        with contextlib.suppress(OSError):
            sys.stdout = open(os.devnull, "w")    # noqa: SIM115 (the interpreter flushes it)
        return 141
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
