"""`inertia-gym benchmark` as a user runs it: backends agree, a killed sweep resumes exactly."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from inertia_gym.cli import main

# A small sweep: 3 agents x 2 seeds + the grid (8 points), budgets of 10 evaluations.
SMALL = ["--agents", "bo,random,ppo,grid", "--seeds", "2", "--budget", "10", "--grid-points", "2",
         "--eval-seeds", "2", "--val-seeds", "2", "--val-duration", "150", "--no-progress"]
N_TASKS = 7
WALL_KEYS = {"wall_s", "score_wall_s"}


def without_wall_times(obj):
    """The report with every wall-clock entry removed (they differ from run to run)."""
    if isinstance(obj, dict):
        return {k: without_wall_times(v) for k, v in obj.items() if k not in WALL_KEYS}
    if isinstance(obj, list):
        return [without_wall_times(v) for v in obj]
    return obj


def run_cli(out: Path, *extra: str) -> dict:
    assert main(["benchmark", *SMALL, "--out", str(out), *extra]) == 0
    return json.loads((out / "benchmark.json").read_text())


@pytest.fixture(scope="session")  # one sweep per worker for every test here that reads it
def sequential(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bench") / "sequential"
    run_cli(out, "--workers", "1")
    return out


def test_report_files_and_contract_keys(sequential):
    report = json.loads((sequential / "benchmark.json").read_text())
    assert report["agents"] == ["bo", "random", "ppo", "grid"] and report["seeds"] == 2
    runs = report["runs"]
    assert sorted((r["agent"], r["seed"]) for r in runs) == sorted(
        (a, s) for a in ("bo", "random", "ppo") for s in (0, 1))
    for r in runs:
        assert {"best_cost", "costs", "xi_star", "wall_s", "val_rel_error", "regret"} <= set(r)
        assert len(r["costs"]) == 10 and len(r["xi_star"]) == 3
        assert r["best_cost"] == pytest.approx(min(r["costs"]))
        assert r["regret"] == pytest.approx(
            r["reeval_cost"] - report["summary"]["grid"]["reeval_cost"])
    table = report["summary"]["agents"]
    assert set(table) == {"bo", "random", "ppo"}
    assert table["bo"]["regret"]["median"] == pytest.approx(
        float(np.median([r["regret"] for r in runs if r["agent"] == "bo"])))
    csv_rows = (sequential / "benchmark.csv").read_text().strip().splitlines()
    assert csv_rows[0].startswith("agent,seed,best_cost") and len(csv_rows) == 1 + 6
    for png in ("cost_curves.png", "regret.png", "validated_error.png"):
        assert (sequential / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = (sequential / "summary.md").read_text()
    assert "| bo | 2 |" in summary and "regret.png" in summary and "Win rate" in summary
    assert len(list((sequential / "runs").glob("*.json"))) == N_TASKS


def test_process_pool_gives_the_sequential_results(sequential, tmp_path):
    pooled = run_cli(tmp_path / "pool", "--workers", "2")
    seq = json.loads((sequential / "benchmark.json").read_text())
    assert without_wall_times(pooled) == without_wall_times(seq)


@pytest.mark.science  # a local Ray cluster starts in minutes on 2 cores
def test_ray_backend_gives_the_local_results(sequential, tmp_path, monkeypatch):
    seq = without_wall_times(json.loads((sequential / "benchmark.json").read_text()))
    # A local Ray cluster started for the sweep.
    on_ray = run_cli(tmp_path / "ray", "--backend", "ray", "--workers", "2")
    assert without_wall_times(on_ray) == seq
    # An existing cluster reached by its address (kept on loopback like the one above).
    monkeypatch.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True,
                      head_node_args={"num_cpus": 2, "include_dashboard": False})
    try:
        assert cluster.address.startswith("127.0.0.1:")
        by_address = run_cli(tmp_path / "ray_address", "--backend", "ray",
                             "--ray-address", cluster.address)
    finally:
        cluster.shutdown()
    assert without_wall_times(by_address) == seq


@pytest.mark.slow
def test_killed_sweep_resumes_to_the_uninterrupted_report(sequential, tmp_path, capsys):
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "inertia_gym.cli", "benchmark", *SMALL, "--workers", "1",
           "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    runs = out / "runs"
    deadline = time.monotonic() + 300
    while len(list(runs.glob("*.json"))) < 3 and proc.poll() is None:
        assert time.monotonic() < deadline, "the sweep saved no run in 300 s"
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    saved = {p.name: p.stat().st_mtime_ns for p in runs.glob("*.json")}
    assert 3 <= len(saved) < N_TASKS, "the kill did not land midway"
    assert not (out / "benchmark.json").exists()
    resumed = run_cli(out, "--workers", "1")
    assert f"resuming, {len(saved)} of {N_TASKS} runs already saved" in capsys.readouterr().err
    # Finished runs were read back, not redone.
    assert all((runs / name).stat().st_mtime_ns == t for name, t in saved.items())
    seq = json.loads((sequential / "benchmark.json").read_text())
    assert without_wall_times(resumed) == without_wall_times(seq)


def test_ctrl_c_says_how_to_resume(tmp_path):
    """Ctrl-C once a run is saved: exit 130, the saved run kept, and how to resume said. Random
    agents only (four seeds): the interrupt lands while the second run is under way; the
    deadline leaves room for a fresh clone compiling its kernels on a loaded machine."""
    out = tmp_path / "interrupted"
    small = list(SMALL)
    small[small.index("--agents") + 1] = "random"
    small[small.index("--seeds") + 1] = "4"
    cmd = [sys.executable, "-m", "inertia_gym.cli", "benchmark", *small, "--workers", "1",
           "--out", str(out)]
    # the child gets Ctrl-C's default disposition, as from a terminal: a test runner's worker
    # may ignore SIGINT, and an ignored signal stays ignored across exec
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 900
    while not list((out / "runs").glob("*.json")) and proc.poll() is None:
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"the sweep saved no run in 900 s: {proc.communicate()[1][-2000:]}")
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert "run the same command again to resume" in err
    assert 1 <= len(list((out / "runs").glob("*.json"))) < 4


def test_rerun_with_other_settings_is_refused_and_loses_nothing(sequential, capsys):
    before = {p: p.read_bytes() for p in sequential.rglob("*.json")}
    code = main(["benchmark", *SMALL, "--budget", "11", "--out", str(sequential)])
    assert code == 2
    err = capsys.readouterr().err
    assert "other settings" in err and "budget" in err
    assert {p: p.read_bytes() for p in sequential.rglob("*.json")} == before


def test_added_seeds_run_only_the_new_tasks_and_unreadable_runs_are_redone(sequential, tmp_path):
    out = tmp_path / "extend"
    small = [a for a in SMALL]
    small[small.index("--agents") + 1] = "random"
    assert main(["benchmark", *small, "--seeds", "1", "--out", str(out)]) == 0
    first = (out / "runs" / "random-seed0.json").stat().st_mtime_ns
    (out / "runs" / "random-seed1.json").write_text('{"agent": "random", "se')  # a torn write
    assert main(["benchmark", *small, "--seeds", "3", "--out", str(out)]) == 0
    assert (out / "runs" / "random-seed0.json").stat().st_mtime_ns == first
    report = json.loads((out / "benchmark.json").read_text())
    assert [r["seed"] for r in report["runs"]] == [0, 1, 2]
    seq = json.loads((sequential / "benchmark.json").read_text())
    seq_random = {r["seed"]: r for r in seq["runs"] if r["agent"] == "random"}
    for r in report["runs"][:2]:
        assert r["costs"] == seq_random[r["seed"]]["costs"]
    assert report["summary"]["grid"] is None and report["runs"][0]["regret"] is None
    assert "add `grid` to --agents" in (out / "summary.md").read_text()


@pytest.mark.parametrize("content", ["[1, 2]", "{not json"])
def test_foreign_settings_file_is_refused(tmp_path, capsys, content):
    out = tmp_path / "foreign"
    out.mkdir()
    (out / "settings.json").write_text(content)
    assert main(["benchmark", *SMALL, "--out", str(out)]) == 2
    assert "settings.json" in capsys.readouterr().err
    assert (out / "settings.json").read_text() == content


@pytest.mark.parametrize("argv, match", [
    (["--agents", "bo,cmaes"], "--agents"),
    (["--agents", ""], "--agents"),
    (["--ray-address", "auto"], "Ray address needs backend 'ray'"),
])
def test_bad_options_end_in_a_clear_error(tmp_path, capsys, argv, match):
    assert main(["benchmark", *SMALL, "--out", str(tmp_path / "o"), *argv]) == 2
    assert match in capsys.readouterr().err


def test_the_ray_backend_without_ray_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    """Ray is an optional extra: asked for without it, the sweep ends in one line naming the
    extra, not a traceback."""
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as where it is not installed
    assert main(["benchmark", *SMALL, "--out", str(tmp_path / "o"), "--backend", "ray"]) == 2
    assert "pip install -e '.[ray]'" in capsys.readouterr().err
