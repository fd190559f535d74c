"""Start-up: `--help` and the dataset commands import neither torch nor scipy; the command table
that makes this possible agrees with the modules' own registrations; every option has help."""
from __future__ import annotations

import argparse
import importlib
import subprocess
import sys

import pytest

from staticdepth import cli

HEAVY = ("torch", "scipy")
PROBE = ("import sys\nfrom staticdepth.cli import main\ntry:\n    main(sys.argv[1:])\n"
         "except SystemExit:\n    pass\n"
         "print('LOADED', *[m for m in {heavy!r} if m in sys.modules], file=sys.stderr)\n")


@pytest.mark.parametrize("argv", [["--help"], [], ["--version"], ["inspect", "--help"],
                                  ["verify", "--help"], ["export", "--help"],
                                  ["publish", "--help"], ["import-kitti", "--help"],
                                  ["synth", "--help"], ["stereo", "--help"], ["demo", "--help"]])
def test_light_commands_do_not_import_torch_or_scipy(argv):
    out = subprocess.run([sys.executable, "-c", PROBE.format(heavy=HEAVY), *argv],
                         capture_output=True, text=True, timeout=120)
    loaded = [line for line in out.stderr.splitlines() if line.startswith("LOADED")]
    assert loaded == ["LOADED"], (argv, out.stderr[-500:])
    if argv[-1:] == ["--help"]:
        assert "usage: staticdepth" in out.stdout


def _registered() -> dict[str, tuple[str, argparse.ArgumentParser]]:
    """command -> (module, parser), from each module's own register()."""
    out = {}
    for module in cli.COMMAND_MODULES:
        _, sub = cli._top_parser()
        importlib.import_module(module).register(sub)
        for name, parser in sub.choices.items():
            out[name] = (module, parser)
    return out


def test_command_table_matches_the_registrations():
    registered = _registered()
    assert list(registered) == [n for n in cli.COMMANDS if n in registered]
    for name, (module, _) in registered.items():
        assert name in cli.COMMANDS, f"add {name!r} to staticdepth.cli.COMMANDS"
        assert cli.COMMANDS[name][0] == module
    full = cli.build_parser()
    sub = next(a for a in full._actions if isinstance(a, argparse._SubParsersAction))
    helps = {a.dest: a.help for a in sub._choices_actions}
    for name in registered:
        assert helps[name] == cli.COMMANDS[name][1], name
        assert sub.choices[name].epilog.startswith("example:\n  staticdepth " + name.split()[0])


def test_help_shows_defaults_and_the_example(capsys):
    with pytest.raises(SystemExit):
        cli.main(["stereo", "--help"])
    text = capsys.readouterr().out
    assert "(default: 80.0)" in text and "example:\n  staticdepth stereo --rig" in text


# Options of commands other branches own, still without help text when this test was written.
HELP_PENDING: set[tuple[str, str]] = set()


def test_every_option_has_help():
    missing = []

    def walk(parser, name):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub_name, sp in a.choices.items():
                    walk(sp, f"{name} {sub_name}".strip())
            elif a.help is None and a.dest != "help":
                missing.append((name, (a.option_strings or [a.dest])[0]))

    walk(cli.build_parser(), "")
    assert set(missing) <= HELP_PENDING, sorted(set(missing) - HELP_PENDING)
