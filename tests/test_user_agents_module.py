"""A user's own `agents.py` in the working directory must not break any command (issue 12).

The commands run through the CLI's entry point in one `python -c` process in a folder holding
the user's agents.py, with the working directory first on sys.path (as `python -m inertia_gym.cli`
puts it): the worst case for a module name the package might import. The user's agents.py raises
on import, so any import of it fails the command that makes it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from inertia_gym.cli import COMMANDS

REPO = Path(__file__).resolve().parents[1]

#: Each command with the smallest budgets that still run it end to end.
COMMAND_LINES = {
    "simulate": ["simulate", "--duration", "5", "--out", "rec.csv"],
    "validate": ["validate", "--xi", "none", "--duration", "5", "--seeds", "1", "--out", "val"],
    "optimize": ["optimize", "--agent", "random", "--budget", "2", "--no-progress", "--out", "opt"],
    "benchmark": ["benchmark", "--agents", "random", "--seeds", "1", "--budget", "2", "--grid-points", "2",
                  "--eval-seeds", "1", "--val-seeds", "1", "--val-duration", "5", "--workers", "1",
                  "--no-progress", "--out", "bench"],
    "diagnose": ["diagnose", "rec.csv", "--no-plots", "--out", "diag"],
    "identify": ["identify", "rec.csv", "--no-plots", "--out", "ident"],
    "example": ["example", "thrown-rotor", "--out", "ex"],
}


@pytest.fixture(scope="module")
def user_folder(tmp_path_factory) -> Path:
    """A working directory holding an agents.py that raises on import."""
    folder = tmp_path_factory.mktemp("user")
    (folder / "agents.py").write_text('raise RuntimeError("the user\'s own agents.py was imported")\n')
    return folder


def _run(folder: Path, code: str, *args: str) -> subprocess.CompletedProcess:
    """`python -c code args` in folder: like `python -m`, -c puts the working directory first on
    sys.path."""
    env = dict(os.environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg")
    env.pop("INERTIA_GYM_DEBUG", None)
    return subprocess.run([sys.executable, "-c", code, *args], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=1800)


#: Runs each command line of its JSON argument in turn through the CLI's entry point in this
#: one process (any import of the user's module fails the command that makes it), and prints
#: {command: exit code}.
RUN_ALL = """
import json, sys
from inertia_gym.cli import main
lines = json.loads(sys.argv[1])
print(json.dumps({name: main(argv) for name, argv in lines.items()}))
"""

OUTPUTS = {"simulate": "rec.json", "validate": "val", "optimize": "opt", "benchmark": "bench",
           "diagnose": "diag/report.json", "identify": "ident/identify.json",
           "example": "ex/thrown-rotor.json"}


def _ran(folder: Path, commands: list[str]) -> None:
    """The commands run in one process beside the user's agents.py, each to exit code 0 and its
    output, and no import of agents.py anywhere."""
    done = _run(folder, RUN_ALL, json.dumps({c: COMMAND_LINES[c] for c in commands}))
    assert done.returncode == 0, done.stderr
    assert "agents.py was imported" not in done.stderr and "Traceback" not in done.stderr
    codes = json.loads(done.stdout.strip().splitlines()[-1])
    assert codes == dict.fromkeys(commands, 0), done.stderr
    for command in commands:
        out = folder / OUTPUTS[command]
        assert out.exists(), command
        if out.suffix == ".json":
            json.loads(out.read_text())
        else:
            assert any(out.iterdir()), command


def test_every_command_is_covered():
    assert set(COMMAND_LINES) == set(COMMANDS) == set(OUTPUTS)


@pytest.mark.slow
def test_each_command_runs_beside_a_user_agents_module(user_folder):
    """Every command, simulate first: diagnose and identify read its file."""
    _ran(user_folder, list(COMMAND_LINES))
