"""The resumable store of a benchmark sweep: one JSON file per finished run, settings pinned.

Every (agent, seed) run is saved to DIR/runs/<agent>-seed<S>.json the moment it finishes, so
an interrupted sweep (Ctrl-C, a killed job, a lost node) resumes when it is run again: finished
runs are read back, not redone. DIR/settings.json pins what the runs were made under; running
other settings (budget, cost, scenario, ...) into the same DIR is refused rather than mixing
results. Adding agents or seeds to a finished sweep runs only the new ones.
"""

from __future__ import annotations

import functools
import json
import sys
from pathlib import Path

from tqdm.auto import tqdm

from inertia_gym.benchmark import SweepSettings, Task, run_task
from inertia_gym.commands.common import write_json
from inertia_gym.errors import ConfigError
from inertia_gym.executors import map_unordered

SETTINGS_FILE = "settings.json"
RUNS_DIR = "runs"


def settings_diff(saved: dict, new: dict) -> list[str]:
    """Names of the settings that differ between two settings.json dicts (scenario.FIELD)."""
    keys = sorted(set(saved) | set(new))
    diff = [k for k in keys if k != "scenario" and saved.get(k) != new.get(k)]
    old_sc, new_sc = saved.get("scenario") or {}, new.get("scenario") or {}
    diff += [f"scenario.{k}" for k in sorted(set(old_sc) | set(new_sc))
             if old_sc.get(k) != new_sc.get(k)]
    return diff


def open_sweep(out: Path, settings: SweepSettings) -> dict[str, dict]:
    """Pin `settings` to the folder `out`; return the runs already saved there, by task name.

    Raises ConfigError if `out` holds a sweep made under other settings. A run file that cannot
    be read (e.g. truncated by a crash) is reported on stderr and redone.
    """
    out = Path(out)
    path = out / SETTINGS_FILE
    new = settings.to_json()
    if path.exists():
        try:
            saved = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path} is not valid JSON ({exc}); choose another --out") from exc
        if not isinstance(saved, dict):
            raise ConfigError(f"{path} does not hold benchmark settings; choose another --out")
        diff = settings_diff(saved, new)
        if diff:
            raise ConfigError(f"{out} holds a sweep made with other settings ({', '.join(diff)}); "
                              f"choose another --out, or remove {out} to start over")
    else:
        write_json(path, new)
    runs = out / RUNS_DIR
    runs.mkdir(exist_ok=True)
    done = {}
    for f in sorted(runs.glob("*.json")):
        try:
            record = json.loads(f.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            print(f"benchmark: {f} is unreadable ({exc}); that run is done again", file=sys.stderr)
            continue
        if record.get("settings_key") == settings.key():
            done[f.stem] = record
    return done


def saved_runs(out: Path) -> int:
    """How many run files the folder `out` holds."""
    return len(list((Path(out) / RUNS_DIR).glob("*.json")))


def run_sweep(out: Path, settings: SweepSettings, tasks: list[Task], *, backend: str = "local",
              workers: int | None = None, ray_address: str | None = None,
              progress: bool = True) -> list[dict]:
    """Run the tasks not yet saved in `out`, saving each as it finishes; return all records.

    Records come back in the order of `tasks`, whatever order they finished in. backend, workers
    and ray_address select where the runs execute (:func:`inertia_gym.executors.map_unordered`).
    """
    out = Path(out)
    done = open_sweep(out, settings)
    todo = [t for t in tasks if t.name not in done]
    if len(todo) < len(tasks):
        print(f"benchmark: resuming, {len(tasks) - len(todo)} of {len(tasks)} runs already saved "
              f"in {out / RUNS_DIR}", file=sys.stderr)
    bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), desc="benchmark",
               unit="run", disable=not progress)
    try:
        fn = functools.partial(run_task, settings)
        for task, record in map_unordered(fn, todo, backend=backend, workers=workers,
                                          ray_address=ray_address):
            write_json(out / RUNS_DIR / f"{task.name}.json", record)
            done[task.name] = record
            bar.set_postfix_str(task.name)
            bar.update(1)
    finally:
        bar.close()
    return [done[t.name] for t in tasks]


__all__ = ["RUNS_DIR", "SETTINGS_FILE", "open_sweep", "run_sweep", "saved_runs", "settings_diff"]
