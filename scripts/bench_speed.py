"""Speed of the project's closed loop against a straightforward peer, in one process.

Both run the paper's scenario (torque-free tumble from the paper's start) for the same simulated
time: truth at dt = 0.01 s plus the 13-state joint EKF with the same maths (RK4 model, analytic
Jacobian, log-Cholesky inertia, Joseph-form update, same Q_k and R). The peer is filterpy's
ExtendedKalmanFilter driving plain-numpy model functions, predicting the covariance every dt as
a textbook EKF does. The project runs on one core (NUMBA_NUM_THREADS=1 is set below).

Prints one JSON line: wall_s_project (median of --repeats identical runs; each takes tens of
milliseconds, so one run is at the mercy of a scheduler hiccup), wall_s_project_runs,
wall_s_peer (one run: ~26 s averages its own noise), speedup (and the final trace-normalised
inertia errors of both, to show they solve the same problem).

    .venv/bin/python scripts/bench_speed.py [--duration 1000] [--repeats 5]
"""

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from filterpy.kalman import ExtendedKalmanFilter  # noqa: E402

from inertia_gym.estimation.ekf import alpha_schedule  # noqa: E402
from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_from_phi  # noqa: E402
from inertia_gym.information import psi  # noqa: E402
from inertia_gym.scenario import Scenario  # noqa: E402
from inertia_gym.simulation import initial_state, run_segment  # noqa: E402
from inertia_gym.validation import ratio_error  # noqa: E402


def rates(y, inertia, inertia_inv):
    q, w = y[:4], y[4:]
    dq = 0.5 * np.array([-q[1] * w[0] - q[2] * w[1] - q[3] * w[2],
                         q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
                         q[0] * w[1] - q[1] * w[2] + q[3] * w[0],
                         q[0] * w[2] + q[1] * w[1] - q[2] * w[0]])
    dw = inertia_inv @ (-np.cross(w, inertia @ w))
    return np.concatenate([dq, dw])


def rk4(y, dt, inertia, inertia_inv):
    k1 = rates(y, inertia, inertia_inv)
    k2 = rates(y + 0.5 * dt * k1, inertia, inertia_inv)
    k3 = rates(y + 0.5 * dt * k2, inertia, inertia_inv)
    k4 = rates(y + dt * k3, inertia, inertia_inv)
    out = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    out[:4] /= np.linalg.norm(out[:4])
    return out


def jacobian(x, inertia, inertia_inv):
    q, w = x[:4], x[4:7]
    a = np.zeros((13, 13))
    wx, wy, wz = w
    a[0:4, 0:4] = 0.5 * np.array([[0, -wx, -wy, -wz], [wx, 0, wz, -wy], [wy, -wz, 0, wx],
                                  [wz, wy, -wx, 0]])
    a[0:4, 4:7] = 0.5 * np.array([[-q[1], -q[2], -q[3]], [q[0], -q[3], q[2]],
                                  [q[3], q[0], -q[1]], [-q[2], q[1], q[0]]])
    skew = lambda v: np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])  # noqa: E731
    a[4:7, 4:7] = inertia_inv @ (skew(inertia @ w) - skew(w) @ inertia)
    w_dot = inertia_inv @ (-np.cross(w, inertia @ w))
    a[4:7, 7:13] = -inertia_inv @ psi(w, w_dot) @ dtheta_dphi(x[7:13])
    return a


def run_peer(sc, state0, duration, rng):
    dt = sc.dt
    ekf = ExtendedKalmanFilter(dim_x=13, dim_z=7)
    ekf.x = state0.x[0].copy()
    ekf.P = state0.P[0].copy()
    ekf.R = np.diag([sc.gyro_sigma**2] * 3 + [sc.quat_sigma**2] * 4)
    h_mat = np.zeros((7, 13))
    h_mat[0:3, 4:7] = np.eye(3)
    h_mat[3:7, 0:4] = np.eye(4)
    y_true = state0.y_true[0].copy()
    j_true = sc.inertia_true_array
    j_true_inv = np.linalg.inv(j_true)
    n_steps = int(round(duration / dt))
    next_meas = int(round(rng.uniform(*sc.meas_interval) / dt))
    updates = 0
    for k in range(1, n_steps + 1):
        y_true = rk4(y_true, dt, j_true, j_true_inv)
        inertia = inertia_from_phi(ekf.x[7:13])
        inertia_inv = np.linalg.inv(inertia)
        f = np.eye(13) + dt * jacobian(ekf.x, inertia, inertia_inv)
        ekf.x[:7] = rk4(ekf.x[:7], dt, inertia, inertia_inv)
        ekf.P = f @ ekf.P @ f.T
        if k == next_meas:
            alpha = alpha_schedule(updates, sc.alpha_gamma, sc.alpha_qmin)
            d_inv = np.linalg.inv(dtheta_dphi(ekf.x[7:13]))
            q_phi = sc.Q_theta * d_inv @ d_inv.T
            q_phi[0, 1:] = q_phi[1:, 0] = 0.0
            ekf.P += alpha * np.diag([sc.Q_quat] * 4 + [sc.Q_omega] * 3 + [0.0] * 6)
            ekf.P[7:, 7:] += alpha * q_phi
            q_meas = y_true[:4] + sc.quat_sigma * rng.standard_normal(4)
            z = np.concatenate([y_true[4:] + sc.gyro_sigma * rng.standard_normal(3),
                                q_meas / np.linalg.norm(q_meas)])
            if z[3:] @ ekf.x[:4] < 0:
                z[3:] *= -1
            ekf.update(z, lambda _x: h_mat, lambda x: h_mat @ x)
            ekf.x[:4] /= np.linalg.norm(ekf.x[:4])
            updates += 1
            next_meas += int(round(rng.uniform(*sc.meas_interval) / dt))
    return inertia_from_phi(ekf.x[7:13])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=1000.0)
    parser.add_argument("--repeats", type=int, default=5,
                        help="project runs; their median wall time is reported (the peer runs once)")
    args = parser.parse_args()
    # The peer has no covariance guards (NIS gate, step limit): start both where a textbook EKF
    # survives (P0_theta = 100) so both solve the same problem to the end.
    sc = Scenario(P0_theta=100.0)
    n_steps = int(round(args.duration / sc.dt))
    rngs = [np.random.default_rng(0)]
    warm = initial_state(sc, rngs)
    run_segment(sc, warm, 10, np.zeros((1, 0, 2)), np.zeros(3), np.eye(3)[0], rngs,
                record_steps=False)  # compile outside the timing
    state0 = initial_state(sc, [np.random.default_rng(1)])
    walls = []
    for _ in range(args.repeats):  # the same run each time; its wall time is tens of ms
        t0 = time.perf_counter()
        end, _ = run_segment(sc, state0, n_steps, np.zeros((1, 0, 2)), np.zeros(3),
                             np.eye(3)[0], [np.random.default_rng(2)], record_steps=False)
        walls.append(time.perf_counter() - t0)
    wall_project = float(np.median(walls))
    t0 = time.perf_counter()
    j_peer = run_peer(sc, state0, args.duration, np.random.default_rng(2))
    wall_peer = time.perf_counter() - t0
    print(json.dumps({
        "duration_s": args.duration,
        "wall_s_project": round(wall_project, 6),
        "wall_s_project_runs": [round(w, 6) for w in walls],
        "wall_s_peer": round(wall_peer, 3),
        "speedup": round(wall_peer / wall_project, 1),
        "ratio_error_project": float(ratio_error(end.inertia_hat()[0], sc.inertia_true_array)),
        "ratio_error_peer": float(ratio_error(j_peer, sc.inertia_true_array)),
    }))


if __name__ == "__main__":
    main()
