"""Every figure the package writes (matplotlib, Agg backend): the paper's Figures 1-3,
identify's figures, and the optimisation and benchmark figures.
"""

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
    return _saved(fig, path)


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
    return _saved(fig, path)


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
    fit_path = _saved(fig, folder / "fit.png")
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
    return [fit_path, _saved(fig, folder / "inertia.png")]


# --- optimisation and benchmark figures ----------------------------------------------------

#: Evaluations in the moving mean of the cost curves (where an agent is sampling).
MOVING_WINDOW = 10


def cost_label(cost_kind: str) -> str:
    """Axis label of a cost: "info" (the paper's J) or "posterior" (change of log det P_theta)."""
    return "cost J (info)" if cost_kind == "info" else "change of log det P_theta (posterior)"


def moving_mean(costs, window: int = MOVING_WINDOW) -> np.ndarray:
    """Mean of the last `window` costs at each evaluation (fewer at the start); (..., M) -> same.

    It shows where an agent samples: flat for random search, falling for an agent that learns.
    """
    c = np.asarray(costs, dtype=float)
    csum = np.cumsum(c, axis=-1)
    shifted = np.concatenate([np.zeros(c.shape[:-1] + (window,)), csum], axis=-1)[..., :c.shape[-1]]
    counts = np.minimum(np.arange(1, c.shape[-1] + 1), window)
    return (csum - shifted) / counts


def plot_costs(result, path: str | Path) -> Path:
    """Figure 1 for one optimisation run: cost of each evaluation, its running best and moving
    mean, xi* (the recommended xi) marked with its predicted cost. result: OptimizationResult.
    """
    path = Path(path)
    i = np.arange(1, len(result.costs) + 1)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax.plot(i, result.costs, color="k", lw=0.8, marker=".", ms=3, label="cost of evaluation i")
    ax.plot(i, np.minimum.accumulate(result.costs), color="g", lw=2.0,
            label="running best (observed)")
    ax.plot(i, moving_mean(result.costs), color="C0", lw=2.0,
            label=f"mean of the last {MOVING_WINDOW}")
    ax.plot(result.star_index + 1, result.cost_star, "r*", ms=14,
            label="xi* (recommended) at its predicted cost")
    ax.set_xlabel("function evaluation i")
    ax.set_ylabel(cost_label(result.cost_kind))
    xi = ", ".join(f"{x:.3g}" for x in result.xi_star)
    mode = "carry-over (Algorithm 1)" if result.carry_over else "from-start episodes"
    ax.set_title(f"{result.agent}, seed {result.seed}, {mode}: xi* = ({xi})", fontsize=10)
    return _finish(fig, ax, path)


def plot_cost_curves(runs: list[dict], summary: dict, settings, path: str | Path) -> Path:
    """Learning curves of a benchmark, per agent (median over seeds, band 25-75 %).

    Left: the re-evaluated cost (mean over the fresh re-evaluation seeds, from the scenario's
    start) of the xi the agent would recommend after i evaluations (records'
    ``recommended_curve``), with the grid optimum for scale: what the agent has learned, free
    of single-episode noise. Right: running best of the observed cost, the curve of the
    paper's Figure 1 (under carry-over it is set by the first episodes). runs: benchmark
    records; summary: benchmark.summarize(); settings: benchmark.SweepSettings.
    """
    path = Path(path)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for k, name in enumerate(summary["agents"]):
        rows = [r for r in runs if r["agent"] == name]
        learned = np.array([r["recommended_curve"]["reeval_cost"] for r in rows], dtype=float)
        steps = rows[0]["recommended_curve"]["evaluations"]
        observed = np.minimum.accumulate(np.array([r["costs"] for r in rows], dtype=float), 1)
        for ax, i, curves in ((axes[0], steps, learned),
                              (axes[1], np.arange(1, observed.shape[1] + 1), observed)):
            ax.plot(i, np.median(curves, 0), color=f"C{k}", lw=2, marker="o" if ax is axes[0]
                    else None, ms=4, label=name)
            ax.fill_between(i, np.quantile(curves, 0.25, 0), np.quantile(curves, 0.75, 0),
                            color=f"C{k}", alpha=0.2)
    if summary["reference_cost"] is not None:
        axes[0].axhline(summary["reference_cost"], color="k", ls=":", label="grid optimum")
    n_eval = len(settings.eval_seeds)
    axes[0].set_title(f"recommended xi after i evaluations: its cost re-evaluated\n"
                      f"from the start (mean of {n_eval} fresh episodes)", fontsize=10)
    axes[1].set_title("running best of the observed cost (single noisy episodes)", fontsize=10)
    axes[0].set_ylabel(cost_label(settings.cost))
    mode = "carry-over (Algorithm 1)" if settings.carry_over else "from-start episodes"
    fig.suptitle(f"learning curves, {mode}, cost {settings.cost} (median over seeds, band "
                 f"25-75 %)")
    for ax in axes:
        ax.set_xlabel("evaluation i")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    return _saved(fig, path)


def _per_agent_strip(ax, runs, agents, key):
    """Dots per seed and a bar at the median of runs' `key`, one column per agent."""
    data = [[r[key] for r in runs if r["agent"] == a and r[key] is not None] for a in agents]
    for k, values in enumerate(data):
        if values:
            x = k + np.linspace(-0.15, 0.15, len(values))
            ax.scatter(x, values, color=f"C{k}", s=14, alpha=0.7)
            ax.hlines(np.median(values), k - 0.3, k + 0.3, color=f"C{k}", lw=2)
    ax.set_xticks(range(len(agents)), agents)


def plot_regret(runs: list[dict], summary: dict, path: str | Path) -> Path | None:
    """Regret of xi* (recommended) and of the observed best per agent (dots: seeds; bar:
    median); None without a grid reference.
    """
    if summary["reference_cost"] is None:
        return None
    path = Path(path)
    agents = list(summary["agents"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True)
    for ax, key, title in ((axes[0], "regret", "xi* (recommended: lowest GP posterior mean)"),
                           (axes[1], "regret_observed_best", "observed best (lowest observed cost)")):
        _per_agent_strip(ax, runs, agents, key)
        ax.axhline(0.0, color="k", ls=":", lw=1)
        ax.set_title(title, fontsize=10)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].set_ylabel("regret: re-evaluated cost − grid optimum")
    return _saved(fig, path)


def plot_validated_error(runs: list[dict], summary: dict, path: str | Path) -> Path:
    """Validated relative inertia error of xi* per agent (dots: seeds; bar: median)."""
    path = Path(path)
    agents = list(summary["agents"])
    fig, ax = plt.subplots(figsize=(8, 4.5))
    _per_agent_strip(ax, runs, agents, "val_rel_error")
    grid = summary["grid"]
    if grid is not None and grid["val_rel_error"] is not None:
        ax.axhline(grid["val_rel_error"], color="k", ls=":", label="grid optimum's xi")
        ax.legend()
    ax.set_yscale("log")
    ax.set_ylabel("||J_hat − J||_F / ||J||_F after validation")
    ax.grid(True, axis="y", alpha=0.3)
    return _saved(fig, path)


def plot_cost_vs_error(mean_costs: dict, validated_errors, episode_errors, correlations: dict,
                       path: str | Path) -> Path:
    """Does an episode's cost predict the inertia error? One panel per cost kind.

    mean_costs {kind: (K,) mean from-start cost of each xi}; validated_errors (K,) median error
    after a long validation of each xi; episode_errors (K,) median error at the end of its
    episode; correlations {kind: {"rho_episode_error_xi_means", "rho_validated_error_1000s"}}
    (Spearman rho, printed in the titles).
    """
    path = Path(path)
    fig, axes = plt.subplots(1, len(mean_costs), figsize=(5.5 * len(mean_costs), 4.5),
                             squeeze=False)
    for ax, (kind, cost) in zip(axes[0], mean_costs.items()):
        ax.scatter(cost, validated_errors, s=14, label="long validation (median)")
        ax.scatter(cost, episode_errors, s=14, marker="x", label="end of the episode (median)")
        ax.set_yscale("log")
        ax.set_xlabel(f"{kind} cost of one episode from the start (mean over seeds)")
        ax.set_ylabel("relative inertia error")
        r = correlations[kind]
        ax.set_title(f"{kind}: rho = {r['rho_episode_error_xi_means']:.2f} (episode), "
                     f"{r['rho_validated_error_1000s']:.2f} (validation)", fontsize=9)
        ax.legend(fontsize=8)
    return _saved(fig, path)


def plot_tradeoff(runs: list[dict], summary: dict, path: str | Path) -> Path | None:
    """Validated inertia error against the impulse spent per episode: the grid's trade-off
    curve (its cheapest-cost point in each band of impulse) and each agent's xi* (dots: seeds).
    None when the sweep ran without mission limits or without the grid.
    """
    grid = summary["grid"]
    if grid is None or not grid.get("tradeoff"):
        return None
    path = Path(path)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    curve = [row for row in grid["tradeoff"] if row[5] is not None]
    ax.plot([row[3] for row in curve], [row[5] for row in curve], "k.-",
            label="grid: best xi per band of impulse")
    for i, agent in enumerate(summary["agents"]):
        rows = [r for r in runs if r["agent"] == agent and r.get("val_rel_error") is not None]
        ax.scatter([r["impulse_star"] for r in rows], [r["val_rel_error"] for r in rows], s=18,
                   color=f"C{i}", alpha=0.7, label=f"{agent}: xi* per seed")
    if grid.get("val_rel_error") is not None:
        ax.scatter([grid["impulse_star"]], [grid["val_rel_error"]], marker="*", s=160,
                   color="k", zorder=5, label="grid optimum")
    ax.set_yscale("log")
    ax.set_xlabel("impulse spent per episode, N·m·s (sum_i integral |tau_i| dt)")
    ax.set_ylabel("||J_hat − J||_F / ||J||_F after validation")
    return _finish(fig, ax, path)


def _finish(fig, ax, path: Path) -> Path:
    """Grid and legend on ax, then the figure saved (_saved)."""
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    return _saved(fig, path)


def _saved(fig, path: Path) -> Path:
    """The figure laid out, written to path and closed; returns path."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
