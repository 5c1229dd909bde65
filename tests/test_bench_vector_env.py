"""scripts/bench_vector_env.py runs end to end and reports what it promises (a short run)."""

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "bench_vector_env.py"


def test_bench_vector_env_reports_both_walls_their_ratio_and_equal_results():
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--num-envs", "2", "--steps", "1", "--repeats", "3"],
        capture_output=True, text=True, check=True, timeout=300,
    )
    report = json.loads(out.stdout.strip().splitlines()[-1])
    for mode in ("native", "sync"):
        runs = report[f"wall_s_{mode}_runs"]
        assert len(runs) == 3 and all(wall > 0 for wall in runs)
        assert sorted(runs)[1] == report[f"wall_s_{mode}"]
        assert report[f"cpu_s_{mode}"] > 0
    ratio = report["wall_s_sync"] / report["wall_s_native"]
    assert abs(report["speedup"] - ratio) <= 1e-9 * ratio
    assert abs(report["cpu_ratio"] - report["cpu_s_sync"] / report["cpu_s_native"]) < 1e-9
    for split in report["cpu_ms_per_env_step"].values():
        assert set(split) == {"compiled_loop", "information_metric", "rest"}
        assert split["compiled_loop"] > 0 and split["information_metric"] > 0
    assert report["num_envs"] == 2 and report["steps"] == 1 and report["threads"] >= 1
    assert report["same_results"] is True
