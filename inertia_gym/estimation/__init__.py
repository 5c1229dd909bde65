"""Joint estimators of (q, w, theta): an EKF (default) and a UKF, both over a log-Cholesky inertia."""
