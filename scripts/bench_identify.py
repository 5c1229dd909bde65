"""Speed of identify() against a straightforward peer on the same output-error problem, in one run.

Two simulated cases with known truth:

a. the paper's scenario: --duration-a s (default 1000) at 100 Hz with torque bursts and attitude
   (``simulate_recording(Scenario(), duration, seed=0, sample_dt=0.01)``; 15 parameters: phi,
   w0, dq0, gyro bias);
b. a 0.5-s, 4-kHz throw of a 5e-4 kg·m² body, gyro only, torque-free, with a rotor whose known
   momentum (h_max 2e-3 kg·m²/s) fixes the scale (9 parameters: phi, w0);
c. eleven such throws (seeds 0-10) of one body fitted together (identify_joint): its wall time
   against the eleven identify() calls it makes inside, and its error against theirs' mean.

identify() (complex-step sensitivities, Levenberg-Marquardt over a progressive horizon) is timed as
the median of --repeats calls after one warm-up call on a short recording that compiles the
numba kernels. The peer solves the same problem (``output_error.evaluate(prob, p, q_ref, False).r``, the
same weights, all free parameters) with ``scipy.optimize.least_squares`` (method 'trf',
default 2-point finite-difference Jacobian) over the whole record at once (no progressive
horizon), from the same equation-error start; it runs once, capped by max_nfev so that it ends
within about --peer-budget s (the cap is derived from one timed residual evaluation: each trf
iteration costs one evaluation plus one per parameter for the Jacobian, which max_nfev does not
count). A non-finite model output is returned to the peer as a large finite residual.

Prints one JSON line per case: wall_s_identify (median) and its runs, wall_s_peer, speedup,
rel_error_identify / rel_error_peer / rel_error_start (relative Frobenius error against the
truth), identify's CRLB, peer_reached_identify (the peer's inertia within 3 CRLB of identify's),
the peer's nfev, njev, status and whether it hit the cap. When identify raises, the line carries
identify_error, the wall time until the exception (one run; the failure is deterministic) and
speedup null. A speedup means little where the peer stopped short of identify's optimum.
Single-threaded (numba and BLAS at one thread, one process): a ratio in one run, never a
timed test.

    .venv/bin/python scripts/bench_identify.py [--repeats 3] [--duration-a 1000]
        [--peer-budget 150] [--cases a,b]
"""

import os

# One thread for numba and for BLAS: on a shared 2-core machine a threaded SVD of the peer's
# 6000 x 9 Jacobian takes 60 ms instead of 1 ms (oversubscription), which is noise, not speed.
for _var in ("NUMBA_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from inertia_gym.discrepancy.synthetic import simulate_recording  # noqa: E402
from inertia_gym.errors import ConfigError, RecordingError  # noqa: E402
from inertia_gym.estimation import output_error  # noqa: E402
from inertia_gym.estimation.equation_error import equation_error_theta  # noqa: E402
from inertia_gym.estimation.inertia_param import inertia_from_phi, phi_from_inertia  # noqa: E402
from inertia_gym.identification import identify  # noqa: E402
from inertia_gym.information import inertia_from_theta  # noqa: E402
from inertia_gym.joint_identification import identify_joint  # noqa: E402
from inertia_gym.prepare import prepared  # noqa: E402
from inertia_gym.scenario import Scenario  # noqa: E402

SMALL_BODY = [[5.2e-4, 0.0, 0.0], [0.0, 2.2e-4, 0.0], [0.0, 0.0, 5.2e-4]]
#: Residual returned to the peer where the model's trajectory is not finite.
NON_FINITE_RESIDUAL = 1e8


def rel_error(j_hat, j) -> float:
    """|j_hat - j|_F / |j|_F."""
    return float(np.linalg.norm(j_hat - j) / np.linalg.norm(j))


def case_recording(name: str, duration_a: float):
    """(recording, true inertia (3, 3)) of case 'a' or 'b'."""
    if name == "a":
        sc = Scenario()
        rec, _ = simulate_recording(sc, duration_a, seed=0, sample_dt=0.01)
        return rec, sc.inertia_true_array
    # The scenario needs quat_sigma > 0; the throw is gyro only, so the attitude is dropped.
    sc = Scenario(inertia_true=SMALL_BODY, inertia_guess=SMALL_BODY, omega0=[15.0, -6.0, -10.0],
                  dt=0.00025, gyro_sigma=0.01)
    rec, _ = simulate_recording(sc, 0.5, seed=0, torque=False, rotor_h_max=2e-3)
    return dataclasses.replace(rec, q=None), sc.inertia_true_array


def start_and_problem(rec):
    """The problem and start identify() builds: (prob, p0 (n,), q_ref (4,))."""
    prep = prepared(rec)
    prob = output_error.problem_from(prep, prep.sigma)
    nominal = rec.inertia_nominal
    trace = float(np.trace(nominal)) if nominal is not None else 1.0
    theta0 = equation_error_theta(prob.t_grid, prob.z_w, prob.tau_grid, prob.h_grid, trace=trace)
    p0 = np.zeros(prob.n_params)
    p0[:6], p0[6:9] = phi_from_inertia(inertia_from_theta(theta0)), prob.z_w[0]
    q_ref = np.array([1.0, 0.0, 0.0, 0.0]) if rec.q is None else np.asarray(rec.q[0], float)
    return prob, p0, q_ref


def run_peer(prob, p0, q_ref, budget_s: float) -> dict:
    """scipy least_squares (trf, 2-point) on the whole record from p0; one timed run."""
    free = prob.free()
    n_free = int(free.sum())
    calls = [0]

    def residuals(x):
        calls[0] += 1
        p = p0.copy()
        p[free] = x
        r = output_error.evaluate(prob, p, q_ref, False).r
        return np.nan_to_num(r, nan=NON_FINITE_RESIDUAL, posinf=NON_FINITE_RESIDUAL,
                             neginf=-NON_FINITE_RESIDUAL)

    t0 = time.perf_counter()
    residuals(p0[free])
    per_eval = time.perf_counter() - t0
    max_nfev = max(2, int(budget_s / ((n_free + 1) * per_eval * 1.2)))
    calls[0] = 0
    t0 = time.perf_counter()
    res = least_squares(residuals, p0[free], method="trf", max_nfev=max_nfev)
    wall = time.perf_counter() - t0
    p = p0.copy()
    p[free] = res.x
    return {"wall_s": wall, "inertia": inertia_from_phi(np.ascontiguousarray(p[:6])),
            "nfev": int(res.nfev), "njev": int(res.njev or 0), "residual_calls": calls[0],
            "max_nfev": max_nfev, "status": int(res.status), "hit_cap": res.status == 0,
            "cost": float(res.cost), "message": res.message, "s_per_eval": per_eval}


def bench_case(name: str, args) -> dict:
    rec, truth = case_recording(name, args.duration_a)
    out = {"case": name, "n_samples": int(rec.t.size), "duration_s": float(rec.t[-1] - rec.t[0]),
           "attitude": rec.q is not None, "torque": rec.has_torque, "rotor_h": rec.has_momentum}
    walls, ident, error = [], None, None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        try:
            ident = identify(rec)
        except (ConfigError, RecordingError) as exc:
            error = f"{type(exc).__name__}: {exc}"
        walls.append(time.perf_counter() - t0)
        if error is not None:
            break  # deterministic: every repeat would fail the same way
    out["wall_s_identify"] = float(np.median(walls))
    out["wall_s_identify_runs"] = [round(w, 4) for w in walls]
    if error is None:
        out["rel_error_identify"] = rel_error(ident.estimate.inertia, truth)
        out["crlb_identify"] = float(ident.crlb)
        out["identify_converged"] = bool(ident.converged)
        out["identify_noise"] = ident.noise.kind
    else:
        out["identify_error"] = error
        out["rel_error_identify"] = None
    prob, p0, q_ref = start_and_problem(rec)
    out["n_params"] = int(prob.free().sum())
    out["rel_error_start"] = rel_error(inertia_from_phi(np.ascontiguousarray(p0[:6])), truth)
    peer = run_peer(prob, p0, q_ref, args.peer_budget)
    out["wall_s_peer"] = round(peer["wall_s"], 3)
    out["speedup"] = (None if error is not None
                      else round(peer["wall_s"] / out["wall_s_identify"], 1))
    out["rel_error_peer"] = rel_error(peer["inertia"], truth)
    # Did the peer find identify's optimum (within 3 Cramer-Rao bounds of it)?
    out["peer_reached_identify"] = (None if error is not None else bool(
        rel_error(peer["inertia"], ident.estimate.inertia) < 3.0 * ident.crlb))
    out["peer"] = {k: peer[k] for k in ("nfev", "njev", "residual_calls", "max_nfev", "hit_cap",
                                        "status", "cost", "s_per_eval", "message")}
    return out


def bench_joint(args) -> dict:
    """Case c: identify_joint on eleven simulated throws of one body against identify on each."""
    recs = []
    for seed in range(11):
        sc = Scenario(inertia_true=SMALL_BODY, inertia_guess=SMALL_BODY, omega0=[15.0, -6.0 + seed, -10.0],
                      dt=0.00025, gyro_sigma=0.01)
        rec, _ = simulate_recording(sc, 0.5, seed=seed, torque=False, rotor_h_max=2e-3)
        recs.append(dataclasses.replace(rec, q=None, name=f"throw-{seed}"))
    truth = np.asarray(SMALL_BODY, float)
    t0 = time.perf_counter()
    singles = [identify(rec) for rec in recs]
    wall_singles = time.perf_counter() - t0
    t0 = time.perf_counter()
    joint = identify_joint(recs)
    wall_joint = time.perf_counter() - t0
    mean = np.mean([s.estimate.inertia for s in singles], axis=0)
    return {"case": "c", "throws": len(recs), "wall_s_joint": round(wall_joint, 3),
            "wall_s_singles": round(wall_singles, 3), "estimator": joint.estimator,
            "rel_error_joint": rel_error(joint.estimate.inertia, truth),
            "rel_error_singles_mean": rel_error(mean, truth), "agreement_p": float(joint.agreement_p)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3,
                        help="identify() calls per case; the median wall time is reported")
    parser.add_argument("--duration-a", type=float, default=1000.0,
                        help="length of case a's recording, s")
    parser.add_argument("--peer-budget", type=float, default=150.0,
                        help="about how long the peer may run per case, s (sets max_nfev)")
    parser.add_argument("--cases", default="a,b,c", help="comma-separated subset of a,b,c")
    args = parser.parse_args()
    # Compile the kernels outside the timings (both branches: with and without attitude).
    warm, _ = simulate_recording(Scenario(), 5.0, seed=0, sample_dt=0.01)
    identify(warm)
    identify(dataclasses.replace(warm, q=None))
    least_squares(lambda x: x - 1.0, np.zeros(2), method="trf")  # scipy's first-call overhead
    for name in args.cases.split(","):
        report = bench_joint(args) if name.strip() == "c" else bench_case(name.strip(), args)
        print(json.dumps(report), flush=True)


if __name__ == "__main__":
    main()
