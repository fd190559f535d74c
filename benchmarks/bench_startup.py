"""Start-up time of the command line, against a bare Python interpreter and against importing every
command module (what `staticdepth --help` did before commands were loaded lazily).

Usage: python benchmarks/bench_startup.py [--repeats N] [--commands]
Prints the median wall and CPU seconds of each, and the ratios to the bare interpreter, all
measured in this run (machines are shared: compare ratios, not seconds). ``--commands`` adds
`staticdepth X --help` for every command X of ``staticdepth.cli.COMMANDS``.
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time

_SCRIPT = os.path.join(os.path.dirname(sys.executable), "staticdepth")   # the console script
CLI = [_SCRIPT] if os.path.exists(_SCRIPT) else [sys.executable, "-m", "staticdepth.cli"]
CASES = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "staticdepth --help": [*CLI, "--help"],
    "staticdepth inspect --help": [*CLI, "inspect", "--help"],
    "every command module": [sys.executable, "-c",
                             "from staticdepth.cli import build_parser; build_parser()"],
}


def measure(cmd: list[str], repeats: int) -> tuple[float, float]:
    walls, cpus = [], []
    for _ in range(repeats):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run(cmd, stdout=subprocess.DEVNULL, check=True)
        walls.append(time.perf_counter() - t)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return statistics.median(walls), statistics.median(cpus)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--commands", action="store_true",
                    help="also time `staticdepth X --help` for every command X")
    args = ap.parse_args()
    cases = dict(CASES)
    if args.commands:
        from staticdepth.cli import COMMANDS

        cases.update({f"staticdepth {name} --help": [*CLI, name, "--help"] for name in COMMANDS})
    ref = None
    for name, cmd in cases.items():
        wall, cpu = measure(cmd, args.repeats)
        ref = ref or (wall, cpu)
        print(f"{name:36s} wall {wall:6.3f} s ({wall / ref[0]:5.1f}x)   "
              f"cpu {cpu:6.3f} s ({cpu / max(ref[1], 1e-3):5.1f}x)")


if __name__ == "__main__":
    main()
