"""The figures of one diagnosis: the residuals before and after the explanation with the located
windows shaded, the residual accumulated over the record, the residual's spectrum and the
invariants over the record, each written as a PNG into the folder given.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from inertia_gym.discrepancy.report import Diagnosis


def write_plots(out: Path, diagnosis: Diagnosis, stem: str = "") -> list[str]:
    """The plots of one diagnosis into the folder out: residuals.png (located windows shaded),
    overlay.png, spectrum.png and, where the invariants apply, invariants.png; their paths.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    report = diagnosis.report
    t = diagnosis.t_rows
    fig, axs = plt.subplots(3, 1, sharex=True, figsize=(9, 6))
    added = " + ".join(e["name"] for e in report["explanation"]) or "nothing"
    for i, ax in enumerate(axs):
        ax.plot(t, diagnosis.residual_before[:, i], lw=0.7, label="nominal")
        ax.plot(t, diagnosis.residual_after[:, i], lw=0.7, label=f"+ {added}")
        for loc in report["locations"]:
            if "xyz"[i] in loc["axes"]:
                ax.axvspan(loc["t_start"], loc["t_end"], color="red", alpha=0.15)
        ax.set_ylabel(f"r_{'xyz'[i]} (rad/s)")
    axs[0].legend(loc="upper right", fontsize=8)
    axs[-1].set_xlabel("t (s)")
    fig.suptitle("interval-prediction residuals (shaded: located mismatch)")
    files.append(_save(fig, out / f"{stem}residuals.png"))
    d = diagnosis.data
    fig, axs = plt.subplots(3, 1, sharex=True, figsize=(9, 6))
    for i, ax in enumerate(axs):
        ax.plot(t, np.cumsum(diagnosis.residual_before[:, i]), label="nominal, accumulated miss")
        ax.plot(t, np.cumsum(diagnosis.residual_after[:, i]), label="after fit, accumulated miss")
        ax.set_ylabel(f"{'xyz'[i]} (rad/s)")
    axs[0].legend(fontsize=8)
    axs[-1].set_xlabel("t (s)")
    fig.suptitle("before / after: accumulated interval residual (a random walk when explained)")
    files.append(_save(fig, out / f"{stem}overlay.png"))
    fig, ax = plt.subplots(figsize=(7, 4))
    for i in range(3):
        ax.semilogy(diagnosis.frequency, diagnosis.power[:, i] + 1e-30, label="xyz"[i])
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD of nominal residual")
    ax.legend()
    files.append(_save(fig, out / f"{stem}spectrum.png"))
    inv = diagnosis.invariants
    if inv.get("applicable"):
        fig, axs = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
        for ax, key in zip(axs, ("momentum", "energy")):
            y = inv["series"][key]
            ax.plot(d.t, y / np.mean(y), lw=0.7)
            ax.set_ylabel(f"{key} / mean")
        axs[-1].set_xlabel("t (s)")
        fig.suptitle(f"invariants (fitted J): {inv['verdict']}")
        files.append(_save(fig, out / f"{stem}invariants.png"))
    return files


def _save(fig, path: Path) -> str:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path.name
