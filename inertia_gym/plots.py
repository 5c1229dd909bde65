"""Figures written to files (matplotlib, Agg backend): the paper's Figures 2 and 3."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from inertia_gym.information import theta_from_inertia  # noqa: E402

THETA_LABELS = ("Jxx", "Jxy", "Jxz", "Jyy", "Jyz", "Jzz")


def plot_validation(result, path: str | Path, run: int = 0) -> Path:
    """Figure 2: w_hat vs truth, theta_hat with its 95% band vs truth, and the applied torque."""
    path = Path(path)
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    t = result.t_meas[run]
    ok = np.isfinite(t)
    for i, name in enumerate("xyz"):
        axes[0].plot(t[ok], result.w_true[run, ok, i], color=f"C{i}", lw=0.6, alpha=0.6)
        axes[0].plot(t[ok], result.w_est[run, ok, i], color=f"C{i}", lw=0.8, ls="--",
                     label=f"w_{name} (dashed: estimate)")
    axes[0].set_ylabel("rate (rad/s)")
    axes[0].legend(loc="upper right", fontsize=7)
    truth = theta_from_inertia(result.inertia_true)
    for i, name in enumerate(THETA_LABELS):
        est, sig = result.theta_hat[run, ok, i], result.theta_sigma[run, ok, i]
        axes[1].plot(t[ok], est, color=f"C{i}", lw=0.9, label=name)
        axes[1].fill_between(t[ok], est - 1.96 * sig, est + 1.96 * sig, color=f"C{i}", alpha=0.12)
        axes[1].axhline(truth[i], color=f"C{i}", lw=0.6, ls=":")
    lo, hi = truth.min(), truth.max()
    pad = 0.6 * (hi - lo)
    axes[1].set_ylim(lo - pad, hi + pad)
    axes[1].set_ylabel("inertia (kg m²)")
    axes[1].legend(loc="upper right", fontsize=7, ncol=3)
    if result.tau.shape[1]:
        for i, name in enumerate("xyz"):
            axes[2].plot(result.t_step, result.tau[run, :, i], lw=0.8, label=f"tau_{name}")
        axes[2].legend(loc="upper right", fontsize=7)
    axes[2].set_ylabel("torque (N m)")
    axes[2].set_xlabel("time (s)")
    xi = "none" if result.xi is None else "(" + ", ".join(f"{x:.3g}" for x in result.xi) + ")"
    fig.suptitle(f"Validation of xi = {xi}, seed {result.seeds[run]}: "
                 f"final error {100 * result.rel_errors[run]:.2f}%")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_error_histories(result, path: str | Path) -> Path:
    """Figure 3 style for one validation: relative inertia error over time, every seed."""
    return plot_informative_vs_not(result, None, path)


def plot_informative_vs_not(informative, non_informative, path: str | Path) -> Path:
    """Figure 3: relative inertia error over time, informative vs. non-informative input."""
    path = Path(path)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    truth = theta_from_inertia(informative.inertia_true)
    for res, color, label in ((informative, "C0", "informative"),
                              (non_informative, "C3", "no torque")):
        if res is None:
            continue
        for r in range(res.theta_hat.shape[0]):
            err = np.linalg.norm(res.theta_hat[r] - truth, axis=-1) / np.linalg.norm(truth)
            ax.semilogy(res.t_meas[r], err, color=color, lw=0.7, alpha=0.6,
                        label=label if r == 0 else None)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("||theta_hat - theta|| / ||theta||")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_identification(result, folder: str | Path) -> list[Path]:
    """Figures of identify: fit over the measured rates, residuals, and the inertia with its 95 %
    intervals. result is an identify.Identification; returns the files written.
    """
    folder = Path(folder)
    t = result.t - result.t[0]
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i, name in enumerate("xyz"):
        axes[0].plot(t, result.w_meas[:, i], color=f"C{i}", lw=0.5, alpha=0.5)
        axes[0].plot(t, result.w_fit[:, i], color=f"C{i}", lw=1.0, label=f"w_{name} fit")
        axes[1].plot(t, result.w_meas[:, i] - result.w_fit[:, i], color=f"C{i}", lw=0.5)
    axes[0].set_ylabel("rate (rad/s)")
    axes[0].legend(loc="upper right", fontsize=7)
    axes[0].set_title(f"{result.name}: measured (thin) and fitted rates")
    axes[1].set_ylabel("residual (rad/s)")
    axes[1].set_xlabel("time (s)")
    axes[1].set_title(f"residuals: rms/noise {result.rms_over_noise:.2f} ({result.noise.kind})")
    fig.tight_layout()
    fit_path = folder / "fit.png"
    fig.savefig(fit_path, dpi=110)
    plt.close(fig)
    est = result.estimate
    fig, ax = plt.subplots(figsize=(7, 4))
    ci = est.ci95()
    ax.errorbar(np.arange(6), est.theta, yerr=[est.theta - ci[:, 0], ci[:, 1] - est.theta], fmt="o",
                capsize=4)
    ax.set_xticks(np.arange(6), THETA_LABELS)
    ax.axhline(0.0, color="k", lw=0.5)
    unit = "kg·m²" if est.scale_identified else "normalised (scale not identified)"
    ax.set_ylabel(f"inertia ({unit})")
    ax.set_title("identified inertia with 95 % intervals")
    fig.tight_layout()
    inertia_path = folder / "inertia.png"
    fig.savefig(inertia_path, dpi=110)
    plt.close(fig)
    return [fit_path, inertia_path]
