"""The install without extras: simulate, identify, diagnose and the env run where torch,
BoTorch, GPyTorch and Stable-Baselines3 cannot be imported, and the package's core
dependencies do not name them."""

import subprocess
import sys
import tomllib
from pathlib import Path

HEAVY = ("torch", "botorch", "gpytorch", "stable_baselines3")

# A finder placed first on sys.meta_path that refuses the heavy packages, as an environment
# without them would (nothing is put in sys.modules, so libraries probing it see no torch).
BLOCK = f"""
import sys
class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {HEAVY!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None
sys.meta_path.insert(0, Refuse())
"""


def _run_light(code: str, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCK + code], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


def test_the_core_dependencies_leave_torch_and_the_agents_to_extras():
    project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]
    core = " ".join(project["dependencies"]).lower()
    assert not any(name.replace("_", "-") in core for name in HEAVY + ("stable-baselines3",))
    extras = project["optional-dependencies"]
    assert any("botorch" in d for d in extras["optimize"])
    assert any("stable-baselines3" in d for d in extras["rl"])


def test_identify_diagnose_the_env_and_random_search_run_without_the_extras(tmp_path):
    done = _run_light("""
import gymnasium as gym, numpy as np, sys
from inertia_gym.cli import main
assert main(["example", "thrown-rotor", "--out", "ex"]) == 0
assert main(["identify", "ex/thrown-rotor.csv", "--out", "id"]) == 0
from inertia_gym.discrepancy.report import diagnose
from inertia_gym.recordings import read_recordings
report = diagnose(read_recordings("ex/thrown-rotor.csv")[0]).report
env = gym.make("InertiaGym/Excitation-v0")
env.reset(seed=0)
env.step(np.zeros(3))
from inertia_gym.agents import make_agent
assert make_agent("random", seed=0, budget=4).ask().shape == (3,)
print("heavy imported:", [m for m in sys.modules if m.split(".")[0] in ("torch", "botorch", "gpytorch",
                                                                   "stable_baselines3")])
""", tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "heavy imported: []" in done.stdout
    assert (tmp_path / "id" / "identify.json").exists()


def test_optimize_without_the_extra_fails_in_one_line(tmp_path):
    done = _run_light("""
from inertia_gym.cli import main
raise SystemExit(main(["optimize", "--agent", "random", "--budget", "2", "--out", "op"]))
""", tmp_path)
    assert done.returncode != 0
    said = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(said) == 1 and "pip install -e '.[optimize]'" in said[0], done.stderr
