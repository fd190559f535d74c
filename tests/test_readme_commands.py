"""The README's commands and adapt settings exist: a newcomer copies them.

The deploy section once told users ``--set detector_model=yolox_nano.onnx``, which adapt refuses
(``detector.model``); these tests read README.md itself, so a renamed flag or a mistyped setting
fails here instead of on a user's first run.
"""
from __future__ import annotations

import contextlib
import dataclasses
import io
import re
import shlex
from pathlib import Path

import pytest

from staticdepth.adaptation.config import AdaptConfig, build_config
from staticdepth.config import setting_keys
from staticdepth.errors import InputError

README = Path(__file__).resolve().parents[1] / "README.md"
SECTIONS = tuple(f.name for f in dataclasses.fields(AdaptConfig))


def _commands(text: str) -> list[str]:
    """Every ``staticdepth ...`` line of the README's bash blocks, continuations joined."""
    blocks = re.findall(r"```(?:bash|sh)\n(.*?)```", text, re.S)
    lines = "\n".join(blocks).replace("\\\n", " ").splitlines()
    return [ln.strip() for ln in lines if ln.strip().startswith("staticdepth ")]


def _as_argv(command: str) -> list[str]:
    """A README synopsis as one concrete argument list: comments dropped, ``[optional]`` parts
    kept (the first of ``a | b``), ``x|y`` alternatives their first, ``...`` dropped and the
    one-letter placeholders (``N``, ``K``, ``H``) a number."""
    c = re.sub(r"\s#.*$", "", command)
    for _ in range(2):                               # nested brackets
        c = re.sub(r"\[([^\[\]]*)\]", lambda m: m.group(1).split(" | ")[0], c)
    c = re.sub(r"(\S+?)\|\S+", r"\1", c).replace("...", "")
    return [("1" if re.fullmatch(r"[A-Z]", a) else a) for a in shlex.split(c)[1:]]


def test_every_readme_command_parses():
    from staticdepth.cli import build_parser

    commands = _commands(README.read_text())
    assert len(commands) >= 30, len(commands)
    failed = []
    for c in commands:
        argv, err = _as_argv(c), io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                build_parser(argv).parse_args(argv)
        except SystemExit:
            failed.append(f"{c}\n    {err.getvalue().strip().splitlines()[-1]}")
    assert not failed, "README commands the CLI refuses:\n" + "\n".join(failed)


def test_the_parse_check_catches_a_renamed_flag():
    from staticdepth.cli import build_parser

    argv = _as_argv("staticdepth import-video site.mp4 --out site.h5 [--every K] "
                    "[--frames-max N]")
    assert argv[-2:] == ["--frames-max", "1"]
    with pytest.raises(SystemExit), contextlib.redirect_stderr(io.StringIO()):
        build_parser(argv).parse_args(argv)


def _adapt_commands(text: str) -> list[str]:
    """Every ``staticdepth adapt ...`` command of the bash blocks and of the inline code."""
    inline = [c.strip() for c in re.findall(r"`(staticdepth adapt [^`]*)`", text)]
    return [c for c in _commands(text) if c.startswith("staticdepth adapt ")] + inline


def _set_keys(command: str) -> list[tuple[str, str]]:
    return re.findall(r"--set\s+([^\s=\[\]]+)=([^\s\]]+)", command)


def _is_setting(key: str) -> bool:
    return key in setting_keys(AdaptConfig)


def test_every_set_of_an_adapt_command_is_accepted():
    commands = _adapt_commands(README.read_text())
    pairs = [kv for c in commands for kv in _set_keys(c)]
    assert len(commands) >= 3 and pairs, (commands, pairs)
    for key, value in pairs:
        if key.lower() == "key":      # the placeholder (--set KEY=VALUE, --set key=value)
            continue
        try:
            build_config({key: value})
        except InputError as e:
            pytest.fail(f"README: adapt --set {key}={value}: {e}")


def test_every_dotted_adapt_setting_named_in_backticks_exists():
    text = README.read_text()
    spans = re.findall(r"`([^`\n]+)`", text)
    pat = re.compile(r"(?<![\w./-])((?:%s)\.[a-z_][a-z0-9_.]*[a-z0-9_])(?![\w/])"
                     % "|".join(SECTIONS))
    keys = {k for s in spans for k in pat.findall(s)
            if not re.search(r"\.(json|py|yaml|h5|png|csv|onnx|pt)$", k)}
    assert len(keys) >= 20, keys        # the README names dozens; a broken regex finds none
    missing = sorted(k for k in keys if not _is_setting(k))
    assert not missing, f"README names adapt settings that do not exist: {missing}"


def test_the_check_catches_the_former_deploy_line():
    wrong = "staticdepth adapt site.h5 --detector yolox --set detector_model=yolox_nano.onnx"
    (key, value), = _set_keys(wrong)
    with pytest.raises(InputError, match="detector.model"):
        build_config({key: value})
    assert not _is_setting("detector_model") and _is_setting("detector.model")
