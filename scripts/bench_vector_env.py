"""Speed of the native vector env against gymnasium's SyncVectorEnv of single envs, in one process.

Both are built by ``gym.make_vec("InertiaGym/Excitation-v0", num_envs=B, ...)``, one with
``vectorization_mode="vector_entry_point"`` (ExcitationVectorEnv: one call of the compiled batched
loop per step, parallel over runs on NUMBA_NUM_THREADS threads), one with ``"sync"`` (B single
envs stepped one after the other). Each repetition resets both with the same seed and times
--steps steps with the same random actions; the two alternate so that a load spike hits both.
Their outcomes are compared for exact equality (they run the same episodes).

Prints one JSON line: wall_s_native and wall_s_sync (medians over --repeats, seconds for
--steps steps of B envs), their per-repetition lists, speedup = wall_s_sync / wall_s_native;
cpu_s_native, cpu_s_sync (medians of the process's CPU time, all threads) and cpu_ratio =
cpu_s_sync / cpu_s_native: the work saved by batching, whatever the load on the cores;
cpu_ms_per_env_step: for each, the CPU ms per env step spent in the compiled closed loop, in
the information metric and in the rest (one extra rollout of each, its calls wrapped in timers);
num_envs, steps, threads, same_results.

    .venv/bin/python scripts/bench_vector_env.py [--num-envs 8] [--steps 3] [--repeats 5]
"""

import argparse
import contextlib
import json
import time

import gymnasium as gym
import numba
import numpy as np
from gymnasium.utils.env_checker import data_equivalence

from inertia_gym import episode, simulation
from inertia_gym.envs import ENV_ID

#: Where a step's CPU time is split: (module, function name, part).
PARTS = ((simulation, "_call_kernel", "compiled_loop"),
         (episode, "information_costs", "information_metric"))


def timed_rollout(venv, seed: int, actions: list[np.ndarray]) -> tuple[float, float, list]:
    """Reset with `seed`, step through `actions`; (wall s, CPU s of this process, outcomes)."""
    outcomes = [venv.reset(seed=seed)[0]]  # observations, then (observations, rewards)
    wall, cpu = time.perf_counter(), time.process_time()
    for action in actions:
        outcomes.append(venv.step(action)[:2])
    return time.perf_counter() - wall, time.process_time() - cpu, outcomes


@contextlib.contextmanager
def cpu_by_part():
    """Within the block, accumulate the process CPU time (s) spent in each part of PARTS."""
    spent = {part: 0.0 for _, _, part in PARTS}

    def timed(function, part):
        def call(*args, **kwargs):
            start = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                spent[part] += time.process_time() - start
        return call

    originals = [(module, name, getattr(module, name)) for module, name, _ in PARTS]
    for (module, name, function), (_, _, part) in zip(originals, PARTS):
        setattr(module, name, timed(function, part))
    try:
        yield spent
    finally:
        for module, name, function in originals:
            setattr(module, name, function)


def cpu_split(venv, actions: list[np.ndarray], num_envs: int) -> dict[str, float]:
    """CPU ms per env step in the compiled loop, the information metric and the rest."""
    with cpu_by_part() as spent:
        _, cpu, _ = timed_rollout(venv, 0, actions)
    per_env_step = 1e3 / (num_envs * len(actions))
    split = {part: seconds * per_env_step for part, seconds in spent.items()}
    split["rest"] = cpu * per_env_step - sum(split.values())
    return split


def main() -> None:
    """Run the benchmark and print its JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--steps", type=int, default=3, help="env steps per repetition")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    envs = {mode: gym.make_vec(ENV_ID, num_envs=args.num_envs, vectorization_mode=mode,
                               budget=args.steps + 1)
            for mode in ("vector_entry_point", "sync")}
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, (args.num_envs, 3)).astype(np.float32)
               for _ in range(args.steps)]
    for venv in envs.values():  # compile / load the kernels outside the timing
        timed_rollout(venv, 0, actions[:1])
    walls: dict[str, list[float]] = {mode: [] for mode in envs}
    cpus: dict[str, list[float]] = {mode: [] for mode in envs}
    same = True
    for rep in range(args.repeats):
        order = list(envs) if rep % 2 == 0 else list(envs)[::-1]
        outcomes = {}
        for mode in order:
            wall, cpu, outcomes[mode] = timed_rollout(envs[mode], rep, actions)
            walls[mode].append(wall)
            cpus[mode].append(cpu)
        same &= data_equivalence(outcomes["vector_entry_point"], outcomes["sync"], exact=True)
    split = {name: cpu_split(envs[mode], actions, args.num_envs)
             for name, mode in (("native", "vector_entry_point"), ("sync", "sync"))}
    native = float(np.median(walls["vector_entry_point"]))
    sync = float(np.median(walls["sync"]))
    cpu_native = float(np.median(cpus["vector_entry_point"]))
    cpu_sync = float(np.median(cpus["sync"]))
    print(json.dumps({
        "wall_s_native": native, "wall_s_sync": sync, "speedup": sync / native,
        "wall_s_native_runs": walls["vector_entry_point"], "wall_s_sync_runs": walls["sync"],
        "cpu_s_native": cpu_native, "cpu_s_sync": cpu_sync, "cpu_ratio": cpu_sync / cpu_native,
        "cpu_ms_per_env_step": split,
        "num_envs": args.num_envs, "steps": args.steps, "threads": numba.get_num_threads(),
        "same_results": bool(same),
    }))


if __name__ == "__main__":
    main()
