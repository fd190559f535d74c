"""``staticdepth run RECIPE.yaml``: a scene's whole pipeline as a declarative list of stages.

A recipe is YAML::

    name: K1
    out_dir: runs/K1                    # relative to the current directory
    vars: {root: /data/kitti_raw}       # placeholders, overridable with --var root=...
    stages:                             # run in this order
      import:
        command: import-kitti           # any staticdepth subcommand
        args: {root: "{root}", drives: [2011_09_28_drive_0016], out: "{out_dir}/K1.h5"}
        outputs: ["{out_dir}/K1.h5"]    # what the stage produces (checked before skipping)
      adapt: {command: adapt, args: {_: ["{out_dir}/K1.h5"], epochs: 30}}

``args`` become the command's options (``key: value`` -> ``--key value``, lists -> several values,
``true`` -> a bare flag, ``false``/null -> omitted, ``_`` -> positionals). A stage is skipped when
its outputs exist and the state file records the same hash of its settings, of its input files
as they are (size and modification time of each file an argument names, folders walked), of the
value recorded for the stage before it (so of every earlier stage's) and of its outputs as it
left them: input data changed in place, a stage run again (``--only``, ``--force``) or an output
another command replaced make it, and every stage after it, run again. ``--force`` reruns
everything. A stage that was interrupted is continued, not started over: it runs again with
``--resume`` where the command has it, and without ``--overwrite`` where that would discard its
progress (``baseline train``'s checkpoint).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import time
from typing import Any, Mapping

from staticdepth.config import config_hash, load_yaml
from staticdepth.errors import InputError
from staticdepth.fileio import atomic_write_json

RECIPE_KEYS = {"name", "out_dir", "vars", "stages", "description", "paper"}
STAGE_KEYS = {"command", "args", "outputs", "description"}
STATE_FILE = "recipe_state.json"
PLACEHOLDER = r"\{([A-Za-z_][A-Za-z0-9_]*)\}"
STARTED = "@started"          # state key suffix: the hash a stage ran with until it completed
# commands whose --overwrite starts over where, without it, they continue an interrupted run
RESUME_WITHOUT_OVERWRITE = {"baseline train"}
MAX_FINGERPRINT_FILES = 200_000


def _subst(value: Any, env: Mapping[str, str], where: str) -> Any:
    if isinstance(value, str):
        def rep(m: re.Match) -> str:
            k = m.group(1)
            if k not in env:
                raise InputError(f"{where}: unknown placeholder {{{k}}} (known: {sorted(env)})")
            return str(env[k])
        return re.sub(PLACEHOLDER, rep, value)
    if isinstance(value, list):
        return [_subst(v, env, where) for v in value]
    if isinstance(value, dict):
        return {k: _subst(v, env, where) for k, v in value.items()}
    return value


def _dotted(d: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for k, v in d.items():
        if isinstance(v, dict):
            out += _dotted(v, f"{prefix}{k}.")
        else:
            out.append((f"{prefix}{k}", v))
    return out


def argv_from_args(command: str, args: Mapping[str, Any]) -> list[str]:
    """``{key: value}`` -> the command line of ``staticdepth COMMAND``."""
    argv = command.split()
    positional = args.get("_", [])
    argv += [str(p) for p in (positional if isinstance(positional, list) else [positional])]
    for k, v in args.items():
        if k == "_" or v is None or v is False:
            continue
        flag = "--" + k.replace("_", "-")
        if v is True:
            argv.append(flag)
        elif isinstance(v, list):
            argv += [flag] + [str(x) for x in v]
        elif isinstance(v, dict):  # set: {epochs: 3, tracking: {min_frames: 2}} -> --set
            for kk, vv in _dotted(v):  # epochs=3 --set tracking.min_frames=2
                argv += [flag, f"{kk}={vv}"]
        else:
            argv += [flag, str(v)]
    return argv


def load_recipe(path: str | os.PathLike, variables: Mapping[str, str] | None = None
                ) -> dict[str, Any]:
    r = load_yaml(path)
    src = os.fspath(path)
    unknown = set(r) - RECIPE_KEYS
    if unknown:
        raise InputError(f"unknown recipe key(s) {sorted(unknown)} (known: {sorted(RECIPE_KEYS)})",
                         src)
    for k in ("name", "stages"):
        if k not in r:
            raise InputError(f"recipe is missing {k!r}", src)
    if not isinstance(r["stages"], dict) or not r["stages"]:
        raise InputError("'stages' must be a non-empty mapping", src)
    # the shared data folder: $STATICDEPTH_DATA, else ../shared/data from the current folder,
    # made absolute so that --dry-run shows where it points
    env = {"name": str(r["name"]),
           "data": os.path.abspath(os.environ.get("STATICDEPTH_DATA", "../shared/data"))}
    # a variable is one the recipe declares or uses as a placeholder
    used = set(re.findall(PLACEHOLDER, json.dumps([r.get("vars"), r.get("out_dir"),
                                                   r["stages"]], default=str)))
    declared = set(r.get("vars") or {}) | used | {"data"}
    unknown = sorted(set(variables or {}) - declared)
    if unknown:          # a misspelt --var changed nothing, silently
        raise InputError(f"unknown variable(s) {unknown}; the recipe's: "
                         f"{', '.join(sorted(declared))}", src)
    for k, v in {**(r.get("vars") or {}), **dict(variables or {})}.items():
        env[k] = str(v)
    for k in list(env):  # vars may refer to each other and to {name}, {data}
        env[k] = str(_subst(env[k], env, f"{src} vars"))
    env["out_dir"] = str(_subst(r.get("out_dir", f"runs/{r['name']}"), env, src))
    given = "data" in (variables or {}) or "data" in (r.get("vars") or {})
    if not given and not os.path.isdir(env["data"]) and "data" in used | set(
            re.findall(PLACEHOLDER, json.dumps(r.get("vars"), default=str))):
        how = ("$STATICDEPTH_DATA" if "STATICDEPTH_DATA" in os.environ
               else "../shared/data from the current folder")
        raise InputError(f"{{data}} is {env['data']} ({how}), which does not exist: set "
                         "STATICDEPTH_DATA or pass --var data=FOLDER", src)
    stages = {}
    for name, st in r["stages"].items():
        if not isinstance(st, dict) or "command" not in st:
            raise InputError(f"stage {name!r} needs a 'command'", src)
        bad = set(st) - STAGE_KEYS
        if bad:
            raise InputError(f"stage {name!r}: unknown key(s) {sorted(bad)}", src)
        stages[name] = {"command": st["command"],
                        "args": _subst(st.get("args") or {}, env, f"{src} stage {name}"),
                        "outputs": _subst(st.get("outputs") or [], env, f"{src} stage {name}")}
    return {"name": r["name"], "out_dir": env["out_dir"], "stages": stages, "path": src}


def _accepts(argv: list[str], flag: str) -> bool:
    """Whether the command ``argv`` names takes ``flag`` (and does not have it yet)."""
    import argparse

    from staticdepth.cli import build_parser

    if flag in argv:
        return False
    parser = build_parser(argv)
    for word in (a for a in argv if not a.startswith("-")):
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        if sub is None or word not in sub.choices:
            break
        parser = sub.choices[word]
    return any(flag in a.option_strings for a in parser._actions)


def _fingerprint(paths) -> list:
    """[path, size, mtime_ns] of every file at or under ``paths`` (folders walked in order, up
    to MAX_FINGERPRINT_FILES files; lock files, which readers create, left out)."""
    out: list = []
    for p in sorted(set(paths)):
        if os.path.isfile(p):
            st = os.stat(p)
            out.append([p, st.st_size, st.st_mtime_ns])
            continue
        for root, dirs, files in os.walk(p):
            dirs.sort()
            for f in sorted(files):
                if f.endswith(".lock") or len(out) >= MAX_FINGERPRINT_FILES:
                    continue
                q = os.path.join(root, f)
                try:
                    st = os.stat(q)
                except OSError:
                    continue
                out.append([q, st.st_size, st.st_mtime_ns])
    return out


def _input_paths(st: Mapping[str, Any]) -> list[str]:
    """The files and folders a stage's arguments name that exist, less its outputs: plain paths,
    ``LABEL=path`` and ``scheme:path`` (model specs)."""
    from staticdepth.cli import NEITHER, OUTPUT_DESTS

    outs = {os.path.realpath(p) for p in st["outputs"]}
    found = []
    for k, v in st["args"].items():
        if k in OUTPUT_DESTS or k in NEITHER or isinstance(v, dict):
            continue
        for x in (v if isinstance(v, list) else [v]):
            if not isinstance(x, str) or not x:
                continue
            for cand in (x, x.partition("=")[2], x.partition(":")[2]):
                # a name (name: C1, detector: gt) is no path, even where cwd holds such a file
                named = cand and (os.sep in cand or "." in os.path.basename(cand))
                if named and os.path.exists(cand) and os.path.realpath(cand) not in outs:
                    found.append(cand)
                    break
    return found


def _read_state(state_path: str) -> dict[str, str]:
    """The stage hashes of earlier runs; a corrupt state file is an error naming it."""
    if not os.path.exists(state_path):
        return {}
    try:
        with open(state_path, "rb") as f:
            state = json.loads(f.read().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"corrupt recipe state ({type(e).__name__}: {e}); delete it to rerun "
                         "every stage", state_path) from None
    if not isinstance(state, dict) or not all(isinstance(v, str) for v in state.values()):
        raise InputError("corrupt recipe state (expected a mapping of stage -> hash); delete it "
                         "to rerun every stage", state_path)
    return state


def run_recipe(recipe: Mapping[str, Any], *, force: bool = False, only: list[str] | None = None,
               dry_run: bool = False, log=print) -> dict[str, str]:
    """Run the stages in order; returns {stage: "ran" | "skipped"}."""
    from staticdepth.cli import main as cli_main

    out_dir = recipe["out_dir"]
    if not dry_run:
        os.makedirs(out_dir, exist_ok=True)
    state_path = os.path.join(out_dir, STATE_FILE)
    state = _read_state(state_path)
    unknown = sorted(set(only or ()) - set(recipe["stages"]))
    if unknown:
        raise InputError(f"--only: no stage(s) {unknown}; the recipe's: "
                         f"{', '.join(recipe['stages'])}", recipe["path"])
    prev = ""
    fresh = ""   # the value as a full run would leave it (what the next --dry-run checks)
    status: dict[str, str] = {}
    for name, st in recipe["stages"].items():
        # a stage's hash chains the value recorded for the stage before it (what its outputs
        # were made with, and those outputs as it left them), so a stage whose inputs were remade
        # since - or were made with other settings when it ran under --only - runs again
        inputs = _fingerprint(_input_paths(st))
        chain = config_hash({"prev": prev, "command": st["command"], "args": st["args"],
                             "inputs": inputs})
        fresh_chain = config_hash({"prev": fresh, "command": st["command"],
                                   "args": st["args"], "inputs": inputs})
        argv = argv_from_args(st["command"], st["args"])
        outputs_there = bool(st["outputs"]) and all(os.path.exists(p) for p in st["outputs"])
        made = _fingerprint(st["outputs"]) if outputs_there else None
        done = outputs_there and state.get(name) == config_hash({"chain": chain, "out": made})
        full = outputs_there and state.get(name) == config_hash({"chain": fresh_chain,
                                                                  "out": made})
        fresh = state.get(name, "") if full else "runs again: " + fresh_chain
        if (only and name not in only) or (done and not force):
            status[name] = "skipped"
            # "up to date" only when a full run would skip it too: an unselected stage after
            # one that ran (or is out of date) is stale even when its own recorded hash matches
            if full:
                why = "up to date"
            elif only and name not in only:
                why = "out of date, not selected"
            else:
                why = "up to date with its inputs as they are (an earlier stage is out of date)"
            log(f"[{recipe['name']}] {name}: {why}, skipped")
            prev = state.get(name, "not run")
            continue
        # the same stage with the same inputs was interrupted: continue it
        resume = not force and state.get(name + STARTED) == chain
        if "--restart" not in argv and "--resume" not in argv:
            # otherwise an interrupted attempt with other settings or inputs is discarded
            flag = "--resume" if resume else "--restart"
            if _accepts(argv, flag):
                argv.append(flag)
        keep = resume and st["command"] in RESUME_WITHOUT_OVERWRITE
        if (any(os.path.exists(p) for p in st["outputs"]) and not keep
                and _accepts(argv, "--overwrite")):
            argv.append("--overwrite")   # a stage that runs again replaces its own outputs
        log(f"[{recipe['name']}] {name}: staticdepth {' '.join(argv)}")
        if dry_run:
            status[name] = "dry-run"
            prev = "runs again: " + chain   # as if it ran: the stages after it would run too
            continue
        state[name + STARTED] = chain
        atomic_write_json(state_path, state)
        t0, c0 = time.perf_counter(), time.process_time()
        rc = cli_main(argv, recipe=recipe["path"])
        if rc != 0:
            raise InputError(f"stage {name!r} failed (exit {rc}): staticdepth {' '.join(argv)}",
                             recipe["path"])
        missing = [p for p in st["outputs"] if not os.path.exists(p)]
        if missing:
            raise InputError(f"stage {name!r} did not produce {missing}", recipe["path"])
        state[name] = prev = config_hash({"chain": chain, "out": _fingerprint(st["outputs"])})
        if chain == fresh_chain:
            fresh = prev
        state.pop(name + STARTED, None)
        atomic_write_json(state_path, state)
        status[name] = "ran"
        log(f"[{recipe['name']}] {name}: done in {time.perf_counter() - t0:.1f} s "
            f"(CPU {time.process_time() - c0:.1f} s)")
    return status


def register(sub) -> None:
    p = sub.add_parser("run", help="run a scene recipe (import, adapt, baseline, evaluation)",
                       description="Run the stages of a recipe YAML in order, skipping stages "
                                   "whose outputs are present with the same settings.")
    p.add_argument("recipe", help="recipe YAML (recipes/*.yaml)")
    p.add_argument("--var", "--set", dest="var", action="append", default=[],
                   metavar="KEY=VALUE",
                   help="set a recipe placeholder, e.g. --var root=/data/kitti_raw")
    p.add_argument("--only", nargs="*", help="run only these stages")
    p.add_argument("--force", action="store_true", help="rerun stages even when up to date")
    p.add_argument("--dry-run", action="store_true", help="print the commands only")
    p.set_defaults(func=_run_cmd)


def parse_vars(items: list[str] | None) -> dict[str, str]:
    """``--var key=value`` pairs (the ``--set`` grammar, :func:`staticdepth.config.parse_set`);
    a malformed one is an error naming ``--var``."""
    from staticdepth.config import parse_set

    return parse_set(items, "--var")


def _run_cmd(args: argparse.Namespace) -> int:
    recipe = load_recipe(args.recipe, parse_vars(args.var))
    run_recipe(recipe, force=args.force, only=args.only, dry_run=args.dry_run)
    return 0
