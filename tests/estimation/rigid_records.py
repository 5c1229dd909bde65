"""Records of a rigid body made by the project's integrator, shared by the estimation tests."""

import numpy as np

from inertia_gym.dynamics import euler_to_quat
from inertia_gym.estimation import output_error
from inertia_gym.estimation.equation_error import equation_error_theta
from inertia_gym.estimation.inertia_param import phi_from_inertia
from inertia_gym.estimation.integrator import trajectory
from inertia_gym.information import inertia_from_theta

J_TRUE = np.array([[100.0, 2.0, -3.0], [2.0, 130.0, 4.0], [-3.0, 4.0, 200.0]])
W0 = np.array([0.5, 10.0, 0.45])
Q0 = euler_to_quat([10.0, 20.0, 30.0])


def grid(n=2000, dt=0.01, torque=True, momentum=True):
    t = np.arange(n + 1) * dt
    tau = np.zeros((n + 1, 3))
    if torque:
        tau[300:400] = [1.0, -2.0, 0.5]
    h = np.zeros((n + 1, 3))
    if momentum:
        h[:, 2] = 5.0 * np.sin(t)
    return t, tau, h


def model(t, tau, h, meas, phi, w0, q0, n_sub=1, drag=None):
    out_w, out_q = np.zeros((meas.size, 3)), np.zeros((meas.size, 4))
    nd = 12 if drag is None else 15
    ok = trajectory(t, tau, h, np.full(t.size, n_sub, dtype=np.int64), meas, phi, w0, q0, False,
                       True, out_w, np.zeros((1, 3, nd)), out_q, np.zeros((1, 3, nd)),
                       None if drag is None else np.asarray(drag, dtype=float))
    assert ok
    return out_w, out_q


def noisy_problem(seed, torque=True, momentum=True, n=3000, every=5, sigma_w=0.03, sigma_q=0.01):
    rng = np.random.default_rng(seed)
    t, tau, h = grid(n=n, torque=torque, momentum=momentum)
    meas = np.arange(0, t.size, every)
    z_w, z_q = model(t, tau, h, meas, phi_from_inertia(J_TRUE), W0, Q0)
    z_w = z_w + sigma_w * rng.standard_normal(z_w.shape)
    z_q = z_q + sigma_q * rng.standard_normal(z_q.shape)
    z_q /= np.linalg.norm(z_q, axis=1, keepdims=True)
    return output_error.Problem(t, tau, h, np.ones(t.size, dtype=np.int64), meas, z_w, z_q,
                      np.full(3, sigma_w), 2 * sigma_q, fit_bias=True,
                      fix_scale=not (torque or momentum))


def start(prob, rel=0.0, seed=0):
    """An equation-error start (p0, its inertia's covariance), optionally pushed off by rel (log units)."""
    rng = np.random.default_rng(seed + 1000)
    n = prob.n_params
    p0 = np.zeros(n)
    theta = equation_error_theta(prob.t_grid[prob.meas_idx], prob.z_w, prob.tau_grid[prob.meas_idx],
                                 prob.h_grid[prob.meas_idx], trace=float(np.trace(J_TRUE)))
    p0[:6] = phi_from_inertia(inertia_from_theta(theta)) + rel * rng.standard_normal(6)
    p0[6:9] = prob.z_w[0]
    return p0, 0.1 ** 2 * np.eye(6)


