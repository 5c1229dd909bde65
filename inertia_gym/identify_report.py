"""summary.md of identify and joint.md of a joint identification: what people read.

Pure functions over the JSON summaries that identify writes (identify.json, joint.json).
"""

from __future__ import annotations

LABELS = ("Jxx", "Jxy", "Jxz", "Jyy", "Jyz", "Jzz")


def markdown(summary: dict, plots=()) -> str:
    """summary.md of one identify.json summary (plots: file names to link)."""
    unit = "kg·m²" if summary["scale_identified"] else "normalised"
    lines = [f"# Inertia of {summary['name']} ({summary['method']})", ""]
    if not summary["scale_identified"]:
        lines += ["**Scale not identified**: neither a known torque nor a known non-zero "
                  "internal momentum fixed the inertia's absolute size. The values are ratios, normalised "
                  "to the trace shown; their intervals are those of the ratios.", ""]
    lines += [f"| parameter | estimate ({unit}) | 95 % interval |", "|---|---|---|"]
    for name, value, (lo, hi) in zip(LABELS, summary["theta"], summary["ci95"]):
        lines.append(f"| {name} | {value:.6g} | [{lo:.6g}, {hi:.6g}] |")
    lines += ["", "| principal moment | 95 % interval | axis (body frame) | axis 95 % cone |",
              "|---|---|---|---|"]
    for m, (lo, hi), ax, cone in zip(summary["principal_moments"], summary["principal_moments_ci95"],
                                     summary["principal_axes"], summary["principal_axes_ci95_deg"]):
        axis = ", ".join(f"{a:+.4f}" for a in ax)
        lines.append(f"| {m:.6g} | [{lo:.6g}, {hi:.6g}] | ({axis}) | {cone:.2f}° |")
    shape = ", ".join(f"{r:.6g} [{lo:.6g}, {hi:.6g}]" for r, (lo, hi) in
                      zip(summary["principal_ratios"][1:], summary["principal_ratios_ci95"][1:]))
    lines += ["", f"Shape (the principal moments over the largest, with 95 % intervals that follow the "
              f"likelihood): 1, {shape}."]
    ee = summary.get("equation_error")
    if ee is not None:
        vals = ", ".join(f"{m:.6g} [{lo:.6g}, {hi:.6g}]" for m, (lo, hi) in
                         zip(ee["principal_moments"], ee["principal_moments_ci95"]))
        lines += ["", f"Reported: the {summary.get('estimator', 'output error')} estimate. The "
                  f"equation-error estimate beside it has principal moments {vals}"
                  + (f" (agreement chi-square {ee['agreement_chi2']:.3g} on {ee['agreement_dof']} dof, "
                     f"p = {ee['agreement_p']:.3g})" if "agreement_chi2" in ee else "") + "."]
    lines += ["", f"- Cramér-Rao bound (relative Frobenius error): {summary['crlb']:.3%}",
              f"- post-fit gyro rms: {', '.join(f'{r:.3g}' for r in summary['rms'])} rad/s "
              f"({summary['rms_over_noise']:.2f}x the noise)",
              f"- noise model: {summary['noise_model']}",
              f"- {summary['n_samples']} samples over {summary['duration_s']:.3f} s; "
              f"converged: {summary['converged']}; {summary['wall_s']:.2f} s"]
    if summary.get("gyro_bias") is not None:
        lines.append(f"- gyro bias: {', '.join(f'{b:.3g}' for b in summary['gyro_bias'])} rad/s")
    if summary.get("air_drag") is not None:
        lines.append(f"- air drag c: {', '.join(f'{c:.3g}' for c in summary['air_drag'])} N·m·s²")
    lines += [f"- note: {n}" for n in summary["notes"]]
    lines += [""] + [f"![{p}]({p})" for p in plots]
    return "\n".join(lines) + "\n"


def joint_markdown(summary: dict) -> str:
    """joint.md of one joint.json summary."""
    unit = "kg·m²" if summary["scale_identified"] else "normalised"
    lines = [f"# One inertia from {len(summary['names'])} recordings ({summary['estimator']})", "",
             "| principal moment | 95 % interval |", "|---|---|"]
    for m, (lo, hi) in zip(summary["principal_moments"], summary["principal_moments_ci95"]):
        lines.append(f"| {m:.6g} {unit} | [{lo:.6g}, {hi:.6g}] |")
    lines += ["", f"| parameter | estimate ({unit}) | 95 % interval |", "|---|---|---|"]
    for name, value, (lo, hi) in zip(LABELS, summary["theta"], summary["ci95"]):
        lines.append(f"| {name} | {value:.6g} | [{lo:.6g}, {hi:.6g}] |")
    lines += ["", "Each recording on its own:", "", "| recording | estimator | principal moments |",
              "|---|---|---|"]
    for row in summary["per_recording"]:
        moments = ", ".join(f"{m:.5g}" for m in row["principal_moments"])
        lines.append(f"| {row['name']} | {row['estimator']} | {moments} |")
    lines += ["", f"- agreement of the recordings' estimates: chi-square {summary['agreement_chi2']:.3g} on "
              f"{summary['agreement_dof']} degrees of freedom, p = {summary['agreement_p']:.3g}",
              f"- {summary['wall_s']:.2f} s"]
    lines += [f"- note: {n}" for n in summary["notes"]]
    return "\n".join(lines) + "\n"
