"""Regenerate docs/results.md: run the benchmark and harness studies and splice in their tables.

Each study of STUDIES has a key, the shell commands a user pastes (``{out}`` stands for the
study's output folder, shown on the page as ``runs/results/KEY``), its prerequisites and a
renderer from docs/results_tables.py: a function from the study's output folder to the markdown
of its table(s). The page holds one block per study::

    <!-- generated: KEY -->
    ... the rendered table(s), then a bash block of the study's commands ...
    <!-- end generated: KEY -->

Only the blocks are rewritten; the prose between them is kept byte for byte. A study runs from
the repository root with this interpreter's folder first on the PATH (``python`` and
``inertia-gym`` are the project's), into a freshly emptied ``OUT_ROOT/KEY``; the standard output
of its commands goes to ``stdout.md``, their standard error to ``stderr.txt``, and ``run.json``
marks a run that finished. A study whose prerequisite is missing is skipped and keeps its block;
one whose command or renderer fails keeps its block and makes the exit status 1.

    .venv/bin/python docs/results.py                    # every study (over an hour on 2 cores)
    .venv/bin/python docs/results.py --only bench-speed,identify-rotor
    .venv/bin/python docs/results.py --list             # keys, commands, prerequisites
    .venv/bin/python docs/results.py --render-only      # re-render from runs/results, run nothing
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import results_tables as tables  # beside this file: python puts the script's folder on sys.path

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "results.md"
OUT_ROOT = "runs/results"
# A block's markers are whole lines; the same words inside a line (prose quoting them) are not one.
BLOCK = re.compile(r"^<!-- generated: (?P<key>[\w-]+) -->\n(?P<body>.*?)^<!-- end generated: (?P=key) -->$",
                   re.DOTALL | re.MULTILINE)
START, END = (re.compile(rf"^<!-- {w}generated: ", re.MULTILINE) for w in ("", "end "))
DONE = "run.json"


class StudyFailed(Exception):
    """A study's command exited with a non-zero status."""


@dataclasses.dataclass(frozen=True)
class Prerequisite:
    """Something a study needs that the repository does not ship: `what` in words, and
    `missing()` -> None when it is there, else the reason it is not.
    """

    what: str
    missing: Callable[[], str | None]


@dataclasses.dataclass(frozen=True)
class Study:
    """One block of the page: its key, commands (``{out}``: the output folder), renderer."""

    key: str
    commands: tuple[str, ...]
    render: Callable[[Path], str]
    needs: tuple[Prerequisite, ...] = ()
    note: str = ""

    def shown(self) -> list[str]:
        """The commands as the page shows them: the output folder under the default root."""
        return [c.replace("{out}", f"{OUT_ROOT}/{self.key}") for c in self.commands]


# ---- prerequisites --------------------------------------------------------------------------

def _basilisk_missing() -> str | None:
    return None if importlib.util.find_spec("Basilisk") else "Basilisk is not importable (pip install bsk)"


def rotor_data() -> Path:
    """The rotor-throw folder, found as scripts/identify_tables.py finds it: shared/data in the
    nearest parent folder holding one, else ../shared/data beside the repository.
    """
    script = REPO / "scripts" / "identify_tables.py"
    data = next((p / "shared" / "data" for p in script.parents if (p / "shared" / "data").is_dir()),
                REPO.parent / "shared" / "data")
    return data / "rotor-throws"


def _rotor_missing() -> str | None:
    truth = rotor_data() / "truth.json"
    return None if truth.exists() else f"no development data: {truth} does not exist"


BASILISK = Prerequisite("Basilisk, importable as `Basilisk` (make installs bsk)", _basilisk_missing)
ROTOR_DATA = Prerequisite("the development data ../shared/data/rotor-throws", _rotor_missing)


# ---- the registry ---------------------------------------------------------------------------

STUDIES = (
    Study("optimize", ("inertia-gym optimize --agent bo --budget 100 --seed 0 --out {out}",),
          tables.render_optimize),
    Study("benchmark", (
        "inertia-gym benchmark --agents bo,random,grid --seeds 4 --budget 40 --grid-points 5 --workers 1 "
        "--out {out}/default",
        "inertia-gym benchmark --agents bo,random,grid --seeds 4 --budget 40 --grid-points 5 --workers 1 "
        "--carry-over --cost info --out {out}/algorithm1"), tables.render_benchmark),
    Study("benchmark-budget", tuple(
        f"inertia-gym benchmark --scenario {name} --agents bo,random,ppo,sac,grid --seeds 16 "
        f"--budget 50 --out {{out}}/{name}" for name in ("paper-budget", "cubesat-6u-budget")),
          tables.render_benchmark_budget),
    Study("cost-vs-error", ("python scripts/benchmark_studies.py cost-vs-error --out {out}",),
          tables.render_cost_vs_error),
    Study("validate-paper", ("inertia-gym validate --xi 0.4,4,1 --seeds 16 --duration 1000 --out {out}",),
          tables.render_validate_paper),
    Study("validate-scenarios", (
        "inertia-gym validate --xi none --out {out}/none",
        "inertia-gym validate --scenario cubesat-6u --xi 0.0047036,0.0005,0.525 --out {out}/cubesat-6u",
        "inertia-gym validate --scenario upper-stage --xi 811.107,50,0.525 --out {out}/upper-stage"),
          tables.render_validate_scenarios),
    Study("identify-families",
          ("PYTHONPATH=.:tests python scripts/identify_tables.py families --seeds 10 --out {out}",),
          tables.render_stdout),
    Study("basilisk-identify", ("PYTHONPATH=.:tests python scripts/basilisk_harness.py identify --seeds 4 "
                                "--out {out}",), tables.render_basilisk_identify, (BASILISK,)),
    Study("identify-rotor", ("PYTHONPATH=. python scripts/identify_tables.py rotor --out {out}",),
          tables.render_stdout, (ROTOR_DATA,)),
    Study("diagnose-harness", ("PYTHONPATH=. python scripts/confusion_matrix.py --out {out}/cm.json",),
          tables.render_diagnose_harness),
    Study("basilisk-diagnose",
          ("PYTHONPATH=.:tests python scripts/basilisk_harness.py diagnose --out {out}",),
          tables.render_basilisk_diagnose_cases, (BASILISK,)),
    Study("basilisk-diagnose-step20",
          ("PYTHONPATH=.:tests python scripts/basilisk_harness.py diagnose --gyro-step 20 --out {out}",),
          tables.render_basilisk_diagnose, (BASILISK,)),
    Study("bench-speed", ("python scripts/bench_speed.py",), tables.render_bench_speed),
    Study("bench-identify", (
        "python scripts/bench_identify.py",
        "inertia-gym simulate --duration 1000 --sample-dt 0.01 --out {out}/R.csv",
        "inertia-gym identify {out}/R.csv --method ekf --out {out}/ekf"), tables.render_bench_identify),
    Study("bench-diagnose", ("PYTHONPATH=. python scripts/bench_diagnose.py --repeat 3 "
                             "--json {out}/bench_diagnose.json",), tables.render_bench_diagnose,
          note="the real-toss row needs ../shared/data/phyphox-racquet; without it the row is left out"),
    Study("bench-other", ("python scripts/bench_bo.py --out {out}", "python scripts/bench_vector_env.py",
                          "NUMBA_NUM_THREADS=1 python scripts/bench_vector_env.py"),
          tables.render_bench_other),
    Study("first-run", ("PYTHONPATH=. python scripts/bench_first_run.py",), tables.render_first_run),
)


# ---- the page's blocks ----------------------------------------------------------------------

def blocks(text: str) -> dict[str, tuple[int, int]]:
    """{key: (start, end) of the block's content} of every generated block of the page text.

    Raises ValueError on a marker without its partner or a key used twice.
    """
    found: dict[str, tuple[int, int]] = {}
    for m in BLOCK.finditer(text):
        if m.group("key") in found:
            raise ValueError(f"block {m.group('key')!r} appears twice")
        if START.search(m.group("body")):
            raise ValueError(f"block {m.group('key')!r} holds another block's start marker")
        found[m.group("key")] = m.span("body")
    if len(found) != len(START.findall(text)) or len(found) != len(END.findall(text)):
        raise ValueError("a generated block's start or end marker has no partner")
    return found


def replace_blocks(text: str, new: dict[str, str]) -> str:
    """The page text with the content of each block named in `new` replaced; all else kept."""
    spans = blocks(text)
    unknown = sorted(set(new) - set(spans))
    if unknown:
        raise KeyError(f"the page has no block for {unknown}")
    out, last = [], 0
    for key, (start, end) in sorted(spans.items(), key=lambda kv: kv[1]):
        if key in new:
            out += [text[last:start], new[key]]
            last = end
    return "".join(out) + text[last:]


def block_content(study: Study, folder: Path) -> str:
    """A block's new content: the rendered table(s), then the bash block of the commands."""
    commands = "\n".join(study.shown())
    return f"\n{study.render(folder).strip()}\n\n```bash\n{commands}\n```\n\n"


# ---- running --------------------------------------------------------------------------------

def run_study(study: Study, folder: Path) -> None:
    """Run the study's commands from the repository root into the emptied `folder`.

    Raises StudyFailed naming the command and the end of its standard error.
    """
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    env.setdefault("MPLBACKEND", "Agg")
    t0 = time.perf_counter()
    with open(folder / "stdout.md", "w") as out, open(folder / "stderr.txt", "w") as err:
        for command in study.commands:
            line = command.replace("{out}", shlex.quote(str(folder)))
            print(f"  $ {line}", flush=True)
            done = subprocess.run(["bash", "-c", line], cwd=REPO, env=env, stdout=out, stderr=err)
            if done.returncode != 0:
                err.flush()
                tail = (folder / "stderr.txt").read_text().strip().splitlines()[-3:]
                raise StudyFailed(f"`{line}` exited with status {done.returncode}"
                                  + (": " + " / ".join(tail) if tail else ""))
    (folder / DONE).write_text(json.dumps({"commands": study.shown(),
                                           "wall_s": time.perf_counter() - t0}, indent=1) + "\n")


def check_registry(text: str, studies) -> None:
    """Raise ValueError unless the page has one block per study and no other block."""
    keys, present = {s.key for s in studies}, set(blocks(text))
    if keys != present:
        raise ValueError(f"studies without a block: {sorted(keys - present)}; "
                         f"blocks without a study: {sorted(present - keys)}")


def list_studies(studies) -> None:
    """Print each study's key, commands and prerequisites (met or not)."""
    for s in studies:
        print(s.key)
        for command in s.shown():
            print(f"    {command}")
        for need in s.needs:
            reason = need.missing()
            print(f"    needs {need.what}: " + ("found" if reason is None else f"MISSING ({reason})"))
        if s.note:
            print(f"    note: {s.note}")


def main(argv: list[str] | None = None, studies=STUDIES, page: Path = PAGE) -> int:
    """Run the selected studies, rewrite their blocks of `page`; the exit status (0, or 1 when a
    study asked for failed, 2 on a usage error).
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=None, metavar="KEY[,KEY]", help="run only these studies")
    ap.add_argument("--list", action="store_true", help="list the studies, their commands and needs")
    ap.add_argument("--render-only", action="store_true",
                    help="re-render the blocks from the outputs on disk; run nothing")
    ap.add_argument("--out-root", default=OUT_ROOT, help=f"where each study writes DIR/KEY ({OUT_ROOT})")
    args = ap.parse_args(argv)
    by_key = {s.key: s for s in studies}
    if args.list:
        list_studies(studies)
        return 0
    keys = list(by_key) if args.only is None else [k.strip() for k in args.only.split(",") if k.strip()]
    unknown = [k for k in keys if k not in by_key]
    if unknown or not keys:
        ap.error(f"--only: unknown keys {unknown}; the keys: {', '.join(by_key)}")
    root = Path(args.out_root) if Path(args.out_root).is_absolute() else REPO / args.out_root
    try:
        check_registry(page.read_text(), studies)
    except ValueError as exc:
        print(f"results: {page}: {exc}", file=sys.stderr)
        return 2
    report: dict[str, list[str]] = {"updated": [], "kept": [], "failed": []}
    for key in keys:
        study, folder = by_key[key], root / key
        if not args.render_only:
            reason = next((r for r in (n.missing() for n in study.needs) if r is not None), None)
            if reason is not None:
                report["kept"].append(f"{key}: not run, a prerequisite is missing: {reason}")
                print(f"[{key}] not run: {reason}", flush=True)
                continue
            print(f"[{key}] running", flush=True)
            try:
                run_study(study, folder)
            except StudyFailed as exc:
                report["failed"].append(f"{key}: {exc}")
                print(f"[{key}] FAILED: {exc}", flush=True)
                continue
        if not (folder / DONE).exists():
            report["kept"].append(f"{key}: its outputs are missing (no finished run in {folder})")
            continue
        try:
            content = block_content(study, folder)
        except Exception as exc:  # a renderer's failure is this study's, not the whole run's
            report["failed"].append(f"{key}: the outputs in {folder} were not rendered: "
                                    f"{type(exc).__name__}: {exc}")
            continue
        # The page is read again and written after each study: edits made to its prose during a
        # long run are kept, and an interrupted run keeps the tables already done.
        page.write_text(replace_blocks(page.read_text(), {key: content}))
        report["updated"].append(key)
    heads = {"updated": "tables rewritten", "kept": "tables kept", "failed": "FAILED, tables kept"}
    for what, lines in report.items():
        if lines:
            print(f"{heads[what]}:" + "".join(f"\n  {line}" for line in lines))
    return 1 if report["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
