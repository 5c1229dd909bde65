"""scripts/bench_speed.py runs end to end and reports what it promises (a short run)."""

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "bench_speed.py"


def test_bench_speed_reports_both_walls_and_their_ratio():
    out = subprocess.run(
        [sys.executable, str(SCRIPT), "--duration", "5", "--repeats", "3"],
        capture_output=True, text=True, check=True, timeout=300,
    )
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(report["wall_s_project_runs"]) == 3
    assert sorted(report["wall_s_project_runs"])[1] == report["wall_s_project"]
    assert report["wall_s_project"] > 0 and report["wall_s_peer"] > 0
    ratio = report["wall_s_peer"] / report["wall_s_project"]
    assert abs(report["speedup"] - ratio) <= 0.01 * ratio
    assert 0 <= report["ratio_error_project"] < 1 and 0 <= report["ratio_error_peer"] < 1
