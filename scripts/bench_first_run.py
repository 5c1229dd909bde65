"""A new user's first commands, cold against warm, in one run.

Each command runs in a fresh process whose numba cache is an empty folder (NUMBA_CACHE_DIR), as
just after install, and then again with the cache that first run wrote (the peer: the same
command warm). The commands are a new user's first three: `inertia-gym example`, `identify` of
the shipped thrown-rotor example (a 0.5-s throw) and `diagnose` of the shipped phone toss (a
1-s toss), a 2-s `simulate`, and `optimize` for two episodes (the excitation design's
simulation loop, which `make run` compiles first). With --make-run, `make run` is also timed
in a clone of the repository's HEAD, install included. Prints one JSON line: cold and warm
seconds per command.

    PYTHONPATH=. .venv/bin/python scripts/bench_first_run.py [--make-run]   (about 5 minutes)
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: Each command's arguments; {run} names the run's own output (the warm run must not meet the
#: cold run's files, which the commands refuse to overwrite).
COMMANDS = {
    "example": ["example", "thrown-rotor", "--out", "ex{run}"],
    "identify": ["identify", "ex/thrown-rotor.csv", "--out", "id{run}"],
    "diagnose": ["diagnose", "ex/phone-toss.csv", "--out", "dg{run}", "--no-plots"],
    "simulate": ["simulate", "--duration", "2", "--out", "sim{run}.csv"],
    "optimize": ["optimize", "--agent", "bo", "--budget", "2", "--seed", "0", "--out", "opt{run}"],
}


def timed(args: list[str], cache_dir: str, cwd: str) -> float:
    """Wall seconds of `inertia-gym args` in a fresh process with numba's cache in cache_dir."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir, MPLBACKEND="Agg")
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "inertia_gym.cli", *args], env=env, cwd=cwd, check=True,
                   capture_output=True, text=True)
    return time.perf_counter() - start


def first_commands() -> dict:
    """{command: {"cold_s", "warm_s"}}: each command first with an empty cache, then again."""
    out = {}
    with tempfile.TemporaryDirectory(prefix="inertia-gym-first-run-") as work:
        cache = str(Path(work) / "numba")
        for example in ("thrown-rotor", "phone-toss"):
            subprocess.run([sys.executable, "-m", "inertia_gym.cli", "example", example, "--out", "ex"],
                           cwd=work, check=True, capture_output=True)
        for name, args in COMMANDS.items():
            cold, warm = (timed([a.format(run=run) for a in args], cache, work) for run in ("-cold", "-warm"))
            out[name] = {"cold_s": round(cold, 2), "warm_s": round(warm, 2)}
    return out


def make_run() -> float:
    """Wall seconds of `make run` in a clone of HEAD (its own .venv, install included)."""
    with tempfile.TemporaryDirectory(prefix="inertia-gym-make-run-") as work:
        clone = Path(work) / "clone"
        subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True)
        start = time.perf_counter()
        subprocess.run(["make", "run"], cwd=clone, check=True, capture_output=True, text=True)
        return time.perf_counter() - start


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--make-run", action="store_true", help="also time `make run` in a clone of HEAD")
    args = ap.parse_args()
    report = {"commands": first_commands()}
    if args.make_run:
        report["make_run_s"] = round(make_run(), 1)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
