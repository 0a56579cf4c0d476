"""How fast the command line answers ``--help``: ``smplik --help``, ``smplik scene export --help`` and every
other command's ``--help``, each run as a fresh process (``python -m smplik.cli``, as the ``smplik`` console
script does), several times; the median wall time and CPU time per command, the bare interpreter's start
for reference, and whether torch was imported.

Run it on an idle machine: ``python benchmarks/cli_startup.py [--runs 7]``. Prints a table and writes
benchmarks/results/cli_startup.json.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parent.parent)]
from _common import save  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TARGET_S = 0.5
"""The goal for ``smplik --help`` and ``smplik scene export --help`` on an idle machine."""


def help_commands() -> list[list[str]]:
    """``--help`` of the top level, of every command and of every subcommand of the groups."""
    from smplik.cli.main import COMMANDS, load_command

    commands = [["--help"], ["scene", "export", "--help"]]
    for name in COMMANDS:
        command = load_command(name)
        subs = sorted(getattr(command, "commands", {}))
        commands += [[name, sub, "--help"] for sub in subs] if subs else [[name, "--help"]]
    return [c for i, c in enumerate(commands) if c not in commands[:i]]


def run_once(args: list[str]) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the child) of one ``python args`` process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, *args], cwd=ROOT, check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def imports_torch(args: list[str]) -> bool:
    """Whether the process imports torch (``python -X importtime``)."""
    res = subprocess.run([sys.executable, "-X", "importtime", *args], cwd=ROOT, capture_output=True, text=True)
    return any(line.split("|")[-1].strip() == "torch" for line in res.stderr.splitlines())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="processes per command (the median is reported)")
    parser.add_argument("--all", action=argparse.BooleanOptionalAction, default=True,
                        help="also every other command's --help (default: on)")
    opts = parser.parse_args()
    load_before = os.getloadavg()[0]
    commands = help_commands() if opts.all else [["--help"], ["scene", "export", "--help"]]
    rows = []
    baseline = [run_once(["-c", "pass"]) for _ in range(opts.runs)]
    rows.append({"command": "python -c pass", "wall_median_s": statistics.median(w for w, _ in baseline),
                 "cpu_median_s": statistics.median(c for _, c in baseline), "imports_torch": False})
    for args in commands:
        full = ["-m", "smplik.cli", *args]
        run_once(full)  # warm the file cache
        times = [run_once(full) for _ in range(opts.runs)]
        rows.append({"command": "smplik " + " ".join(args), "wall_median_s": statistics.median(w for w, _ in times),
                     "wall_min_s": min(w for w, _ in times), "cpu_median_s": statistics.median(c for _, c in times),
                     "imports_torch": imports_torch(full)})
    print(f"{'command':<42}{'wall median s':>15}{'CPU median s':>14}{'torch':>7}")
    for r in rows:
        print(f"{r['command']:<42}{r['wall_median_s']:>15.3f}{r['cpu_median_s']:>14.3f}{str(r['imports_torch']):>7}")
    print(f"load average: {load_before:.2f} before, {os.getloadavg()[0]:.2f} after (run on an idle machine)")
    print("wrote", save("cli_startup", {"runs": opts.runs, "target_s": TARGET_S, "load_average_before": load_before,
                                        "load_average_after": os.getloadavg()[0], "results": rows}))


if __name__ == "__main__":
    main()
