"""The renderers of docs/results.py: each turns a study's output folder into the markdown of
its table(s).

A renderer reads the files the study's commands write (result.json, benchmark.json, a script's
JSON) or capture (``stdout.md``: the standard output of the commands, holding the markdown
tables or the one-line JSON records some scripts print), and raises (OSError, KeyError,
ValueError, ...) where an output is missing or not what the command writes.
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path

# ---- formatting helpers ---------------------------------------------------------------------

SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def pct(x: float | None) -> str:
    """A fraction as a percentage with three significant digits ("–" for None)."""
    return "–" if x is None else f"{100 * x:.3g} %"


def secs(x: float) -> str:
    """Seconds with three significant digits."""
    return f"{x:.3g} s"


def sci(x: float) -> str:
    """Two significant digits, powers of ten written 6.6·10⁻⁶."""
    text = f"{x:.2g}"
    if "e" not in text:
        return text
    mantissa, exponent = text.split("e")
    return f"{mantissa}·10{str(int(exponent)).translate(SUPERSCRIPT)}"


def quartiles(stat: dict | None, scale: float = 1.0, unit: str = "") -> str:
    """A benchmark statistic {"median", "q25", "q75"} as 'median unit [q25, q75]'."""
    if stat is None:
        return "–"
    m, lo, hi = (f"{scale * stat[k]:.3g}" for k in ("median", "q25", "q75"))
    return f"{m}{unit} [{lo}, {hi}]"


def plural(n: int, word: str) -> str:
    """'1 seed', '4 seeds'."""
    return f"{n} {word}{'s' * (n != 1)}"


def table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


def load(path: Path) -> dict:
    """A JSON file's content."""
    return json.loads(path.read_text())


def json_lines(folder: Path) -> list[dict]:
    """The one-line JSON objects a study printed (stdout.md), in order."""
    out = []
    for line in (folder / "stdout.md").read_text().splitlines():
        if line.startswith("{") and line.endswith("}"):
            out.append(json.loads(line))
    return out


def stdout_chunks(folder: Path) -> list[str]:
    """The markdown a study printed (stdout.md) in chunks separated by blank lines: tables,
    bullets and sentences; one-line JSON progress records are left out.
    """
    lines = [ln.rstrip() for ln in (folder / "stdout.md").read_text().splitlines()
             if not (ln.startswith("{") and ln.endswith("}"))]
    chunks = [c.strip() for c in "\n".join(lines).split("\n\n") if c.strip()]
    if not any(c.startswith("|") for c in chunks):
        raise ValueError(f"no markdown table in {folder / 'stdout.md'}")
    return chunks


# ---- renderers: output folder -> markdown -----------------------------------------------------

def render_optimize(folder: Path) -> str:
    """The result.json of `inertia-gym optimize`: xi* and its validation."""
    d = load(folder / "result.json")
    agent = {"bo": "BO", "random": "random search"}.get(d["agent"], d["agent"])
    err = "every run diverged" if d.get("val_rel_error") is None else pct(d["val_rel_error"])
    runs = f"{plural(len(d['val_seeds']), 'seed')} × {d['val_duration']:g} s"
    return table(["agent, budget", "ξ\\* = (a, b, T_on)", f"validated median error of ξ\\* ({runs})",
                  "scale identified"],
                 [[f"{agent}, M = {d['budget']}, seed {d['seed']}",
                   "(" + ", ".join(f"{x:.4g}" for x in d["xi_star"]) + ")", err,
                   "yes" if d["val_scale_identified"] else "no"]])


def xi_label(xi) -> str:
    """A grid point: '(a, b, T_on)', or '(no torque)' where a = b = 0."""
    return "(no torque)" if xi[0] == 0 and xi[1] == 0 else "(" + ", ".join(f"{x:.3g}" for x in xi) + ")"


BENCHMARK_OBJECTIVES = (("default", "default (from the start, posterior cost)"),
                        ("algorithm1", "`--carry-over --cost info` (Algorithm 1)"))


def interval(bounds: list | None) -> str:
    """[lo, hi] to 3 significant digits, or – for none."""
    return "–" if bounds is None else f"[{bounds[0]:.3g}, {bounds[1]:.3g}]"


def agent_rows(agents: dict, label: str, cells) -> list[list[str]]:
    """One row per agent of a benchmark summary: the label on the first, the agent's name, the
    cells(stats) columns, and how many seeds BO won against it.
    """
    rows, bo = [], agents.get("bo")
    for i, (name, s) in enumerate(agents.items()):
        wins = "–"
        if bo is not None and name != "bo" and bo["win_rate"].get(name) is not None:
            n = bo["win_seeds"][name]
            wins = f"{bo['win_rate'][name] * n:g} of {n}"
        rows.append([label if i == 0 else "", name, *cells(s), wins])
    return rows


def validated(record: dict) -> str:
    """A record's validated error in percent, or "diverged"."""
    return "diverged" if record["val_rel_error"] is None else pct(record["val_rel_error"])


def sweep_rows(folder: Path, sweeps, cells, grid_cells) -> list[list[str]]:
    """The rows of several sweeps (folder/SUB/benchmark.json for each (SUB, label) of sweeps):
    each agent's (agent_rows with cells), then the grid optimum's with grid_cells(grid record).
    """
    rows = []
    for sub, label in sweeps:
        summary = load(folder / sub / "benchmark.json")["summary"]
        rows += agent_rows(summary["agents"], label, cells)
        grid = summary["grid"]
        if grid is not None:
            rows.append(["", f"grid optimum {xi_label(grid['xi_star'])}", *grid_cells(grid), ""])
    return rows


def render_benchmark(folder: Path) -> str:
    """The two sweeps' benchmark.json: regrets, validated errors and BO's wins per objective."""
    rows = sweep_rows(folder, BENCHMARK_OBJECTIVES, lambda s: [
        quartiles(s["regret"]), quartiles(s["regret_observed_best"]),
        quartiles(s["val_rel_error"], 100.0, " %")], lambda grid: ["0", "–", validated(grid)])
    return table(["objective", "agent", "regret of ξ\\*", "regret of the observed best",
                  "validated error of ξ\\*", "BO wins"], rows)


BUDGET_SCENARIOS = (("paper-budget", "the paper's body, 13 N·m·s per episode"),
                    ("cubesat-6u-budget", "6U CubeSat, 2 mN·m·s per episode"))
#: Where the results page's figures live (docs/figures), written by the renderers that show one.
FIGURES = Path(__file__).parent / "figures"


def render_benchmark_budget(folder: Path) -> str:
    """Each budgeted sweep's benchmark.json: regret, validated error, impulse and the share
    within the limits per agent, the grid optimum; and the paper body's trade-off figure,
    copied into docs/figures.
    """
    rows = sweep_rows(folder, BUDGET_SCENARIOS, lambda s: [
        quartiles(s["regret"]), interval(s["regret_median_ci95"]),
        quartiles(s["val_rel_error"], 100.0, " %"),
        quartiles(s["impulse_star"]), f"{100 * s['within_limits']:.0f} %"],
        lambda grid: ["0", "–", validated(grid), f"{grid['impulse_star']:.3g}", "100 %"])
    FIGURES.mkdir(exist_ok=True)
    (FIGURES / "tradeoff-paper-budget.png").write_bytes(
        (folder / "paper-budget" / "tradeoff.png").read_bytes())
    return (table(["scenario", "agent", "regret of ξ\\*", "95 % interval of the median regret",
                   "validated error of ξ\\*",
                   "impulse of ξ\\* per episode", "ξ\\* within the limits", "BO wins"], rows)
            + "\n\n![Validated error against the impulse spent per episode, paper-budget]"
              "(figures/tradeoff-paper-budget.png)")


def render_cost_vs_error(folder: Path) -> str:
    """benchmark_studies.py cost-vs-error's cost_vs_error.json: Spearman rho of each cost."""
    a = load(folder / "cost_vs_error.json")["A_from_start"]
    names = {"info": "info (the paper's J)", "posterior": "posterior (change of log det P_θ)"}
    return table(["cost", "Spearman ρ (cost of one episode from the start, 1000-s validated error), "
                          f"{a['n_xi']} Sobol ξ"],
                 [[names[k], f"{a[k]['rho_validated_error_1000s']:.2f}"] for k in names])


def coverage(x: float | None) -> str:
    """A share of intervals holding the truth, in whole percent."""
    return "–" if x is None else f"{100 * x:.0f} %"


def render_validate_paper(folder: Path) -> str:
    """The result.json of `inertia-gym validate`: the filter and its batch-ML refinement."""
    d = load(folder / "result.json")
    n = len(d["seeds"])
    refined = pct(d.get("refined_median_rel_error"))
    if d.get("refined_errors_are_ratios"):
        refined += " (ratios)"
    efficiency = "–" if d.get("efficiency") is None else f"{d['efficiency']:.2f} (median)"
    return table(["estimator", "median ‖Ĵ−J‖_F/‖J‖_F", "trace-normalised", "95 % coverage",
                  "error / Cramér–Rao bound", "diverged", "scale identified"],
                 [["joint EKF", pct(d["median_rel_error"]), pct(d["median_ratio_rel_error"]),
                   coverage(d["ci95_coverage"]), "–", f"{d['diverged']} of {n}",
                   f"{sum(d['scale_identified_per_seed'])} of {n}"],
                  ["batch ML refinement", refined, "–", coverage(d.get("refined_ci95_coverage")),
                   efficiency, "–", "–"]])


VALIDATE_SCENARIOS = ("none", "cubesat-6u", "upper-stage")


def render_validate_scenarios(folder: Path) -> str:
    """Each validate run's result.json (one folder per scenario): the filter's scores."""
    rows = []
    for name in VALIDATE_SCENARIOS:
        d = load(folder / name / "result.json")
        n = len(d["seeds"])
        if d["xi"] is None:
            label = "paper, no torque"
        else:
            label = f"shipped `{name}`, (" + ", ".join(f"{x:g}" for x in d["xi"]) + ")"
        if d["scale_identified"]:
            worst = max(e for e in d["rel_errors"] if e is not None)
            rows.append([label, pct(d["median_rel_error"]), pct(worst), coverage(d["ci95_coverage"]),
                         str(d["diverged"]), f"{sum(d['scale_identified_per_seed'])} of {n}"])
        else:  # the scale is not seen: the error is the scale's; the shape is the trace-normalised one
            rows.append([label, f"{pct(d['median_rel_error'])} (trace-normalised "
                                f"{pct(d['median_ratio_rel_error'])})", "–", "–", str(d["diverged"]), "no"])
    return table(["scenario, ξ", "EKF median error", "worst", "95 % coverage", "diverged",
                  "scale identified"], rows)


def render_stdout(folder: Path) -> str:
    """A script's own markdown (stdout.md): its tables with the lines that sum them up."""
    return "\n\n".join(stdout_chunks(folder))


def render_basilisk_identify(folder: Path) -> str:
    """basilisk_harness.py identify's printed tables: the per-kind summary first, then per
    kind and body class.
    """
    tables = [c for c in stdout_chunks(folder) if c.startswith("|")]
    return "\n\n".join([tables[-1], *tables[:-1]])


#: The concealed components of scripts/basilisk_harness.py diagnose, in the page's words.
CONCEALED = {"slosh": "slosh", "slosh_damped": "slosh damped past resonance", "panel": "hinged panel",
             "hidden_wheels": "reaction wheels, momentum hidden",
             "hidden_torque": "constant body torque", "gyro_bias": "gyro bias", "gyro_scale": "gyro scale",
             "gyro_drift": "gyro bias drifting"}


def span(values, fmt: str) -> str:
    """'lo–hi' of the values (one value alone; '–' for none)."""
    if not values:
        return "–"
    lo, hi = format(min(values), fmt), format(max(values), fmt)
    return lo if lo == hi else f"{lo}–{hi}"


def render_basilisk_diagnose(folder: Path) -> str:
    """basilisk_harness.py diagnose's basilisk_harness.json: cases per concealed component,
    how far off the nominal is, how many are correct, the rms left, and the misses.
    """
    d = load(folder / "basilisk_harness.json")
    rows, totals = d["rows"], d["totals"]
    groups = [("nothing (controls)", [r for r in rows if not r["components"]])]
    groups += [(label, [r for r in rows if r["components"] == [name]]) for name, label in CONCEALED.items()]
    groups.append(("pairs of the above", [r for r in rows if len(r["components"]) > 1]))
    out = []
    for label, members in groups:
        if not members:
            continue
        rms = [max(r["rms_over_noise_after"]) for r in members if r["rms_over_noise_after"]]
        off = [100 * r["nominal_error"] for r in members]
        out.append([label, str(len(members)), str(sum(r["correct"] for r in members)),
                    str(sum(bool(r["outside_truth"]) for r in members)), span(off, ".1f") + " %",
                    span(rms, ".2f")])
    out.append(["**all**", f"**{len(rows)}**", f"**{totals['cases_correct']} of {totals['cases']}, "
                f"controls {totals['controls_clean']} of {totals['controls']}**",
                f"**{sum(bool(r['outside_truth']) for r in rows)}**", "", ""])
    text = table(["concealed", "cases", "correct", "naming physics the truth lacks", "nominal off by",
                  "worst-axis rms / noise after the explanation"], out)
    damped = [r for r in rows if "slosh_damped" in r["components"]]
    if damped:
        text += (f"\n\nSlosh damped past resonance read as internal dissipation: "
                 f"{sum(r['reads_dissipation'] for r in damped)} of {len(damped)}.")
    misses = [r for r in rows if not r["correct"]]
    lines = [f"- `{r['case']}`: concealed {', '.join(r['components']) or 'nothing'}; named "
             f"{', '.join(r['named']) or 'nothing'}" for r in misses]
    padded = [f"- `{r['case']}`: {', '.join(r['outside_truth'])} beside "
              f"{', '.join(n for n in r['named'] if n not in r['outside_truth']) or 'nothing'}"
              for r in rows if r["outside_truth"] and r["correct"]]
    text += "\n\nCases not correct:" + ("\n\n" + "\n".join(lines) if lines else " none.")
    if padded:
        text += ("\n\nCorrect cases whose explanation also names physics the truth lacks:\n\n"
                 + "\n".join(padded))
    return text


def render_basilisk_diagnose_cases(folder: Path) -> str:
    """render_basilisk_diagnose, then every case on a row: what was concealed, how far off the
    nominal is, the names diagnose gave and those of them the truth lacks, whether the explanation
    reads as dissipation, the rms left and whether the case is correct.
    """
    rows = load(folder / "basilisk_harness.json")["rows"]
    out = [[f"`{r['case']}`", ", ".join(r["components"]) or "— (control)",
            f"{100 * r['nominal_error']:.1f} %", ", ".join(r["named"]) or "—",
            ", ".join(r["outside_truth"]) or "—", "yes" if r["reads_dissipation"] else "no",
            f"{max(r['rms_over_noise_after']):.2f}" if r["rms_over_noise_after"] else "–",
            "yes" if r["correct"] else "no"] for r in rows]
    return (render_basilisk_diagnose(folder) + "\n\nEvery case:\n\n"
            + table(["case", "concealed", "nominal off by", "named", "of which not in the truth",
                     "read as dissipation", "worst-axis rms / noise after", "correct"], out))


def render_diagnose_harness(folder: Path) -> str:
    """confusion_matrix.py's cm.json: the harness's figures."""
    d = load(folder / "cm.json")
    f = d["figures"]
    params = f"{f['params_within_20pc']} / {f['singles_correct']}"
    if f["param_error_median"] is not None:
        params += f" (median error {pct(f['param_error_median'])})"
    return table(["measure", "result"], [
        ["single effects: the hidden effect leads (top-1)", f"{f['singles_correct']} / {f['singles']}"],
        ["pairs: both effects in the explanation", f"{f['pairs_both_named']} / {f['pairs']}"],
        ["false alarms on clean controls", f"{f['false_alarms']} / {f['controls']}"],
        ["correct single effects with fitted parameters within 20 % of the truth", params],
        ["recordings fitted to ≤ 1.2× the noise on every axis after the explanation",
         f"{f['rms_within_1p2']} / {f['recordings']} (median {f['rms_over_noise_median']:.3f})"],
        ["wall time per recording (median)", secs(statistics.median(r["wall_s"] for r in d["rows"]))]])


def render_bench_speed(folder: Path) -> str:
    """bench_speed.py's JSON line: the closed loop against the filterpy peer."""
    d = json_lines(folder)[-1]
    return table(["", "inertia-gym", "filterpy peer", "ratio"], [
        [f"{d['duration_s']:g} s of truth + EKF",
         f"{secs(d['wall_s_project'])} (median of {len(d['wall_s_project_runs'])} runs)",
         secs(d["wall_s_peer"]), f"{d['speedup']:.0f}×"],
        ["final trace-normalised inertia error", pct(d["ratio_error_project"]),
         pct(d["ratio_error_peer"]), ""]])


def identify_case_row(d: dict) -> list[str]:
    """One bench_identify.py case (a or b): identify against least_squares."""
    hz = (d["n_samples"] - 1) / d["duration_s"]
    rate = f"{hz / 1000:g} kHz" if hz >= 1000 else f"{hz:g} Hz"
    what = ("paper's scenario" if d["case"] == "a" else "rotor throw") + f", {d['duration_s']:g} s at {rate}"
    what += ", bursts" if d["torque"] else ", a rotor's momentum" if d["rotor_h"] else ""
    what += " and attitude" if d["attitude"] else ", gyro only"
    if d["rel_error_identify"] is None:
        ours = f"failed: {d['identify_error']}"
    else:
        runs = d["wall_s_identify_runs"]
        ours = secs(d["wall_s_identify"]) + (f" ({min(runs):.3g}–{max(runs):.3g})" if len(runs) > 1 else "")
        ours += f", error {sci(d['rel_error_identify'])} against its bound {sci(d['crlb_identify'])}"
    peer = secs(d["wall_s_peer"])
    if d["peer_reached_identify"]:
        peer += ", same optimum"
    else:
        peer += f", error {sci(d['rel_error_peer'])} (its start: {sci(d['rel_error_start'])})"
    return [what, ours, peer]


def render_bench_identify(folder: Path) -> str:
    """bench_identify.py's JSON lines and the ekf run's identify.json against its recording."""
    rows = []
    for d in json_lines(folder):
        if d["case"] == "c":
            rows.append([f"`identify_joint` of {d['throws']} such throws",
                         f"{secs(d['wall_s_joint'])}, error {sci(d['rel_error_joint'])}",
                         f"{d['throws']} `identify` calls: {secs(d['wall_s_singles'])}, error of their "
                         f"mean {sci(d['rel_error_singles_mean'])}"])
        else:
            rows.append(identify_case_row(d))
    ekf = load(folder / "ekf" / "identify.json")
    truth = load(folder / "R.json")["inertia_nominal"]  # simulate writes the true inertia here
    err = sum((a - b) ** 2 for ra, rb in zip(ekf["inertia"], truth) for a, b in zip(ra, rb)) ** 0.5
    err /= sum(b ** 2 for rb in truth for b in rb) ** 0.5
    rows.append([f"`identify --method ekf` on a {ekf['duration_s']:g}-s simulated recording",
                 f"{pct(err)} error in {secs(ekf['wall_s'])}", "–"])
    return table(["recording", "identify", "peer"], rows)


DIAGNOSE_CASES = {"toss_1s_100hz": "1-s racquet toss at 100 Hz with drag",
                  "600s_10hz": "600-s recording at 10 Hz (attitude, torque, a wheel's momentum concealed)"}


def render_bench_diagnose(folder: Path) -> str:
    """bench_diagnose.py's JSON: whole diagnoses against their limits, the rigid fit's peer."""
    d = load(folder / "bench_diagnose.json")
    rows = [[label, secs(d[key]["diagnose_s"]), f"{d[key]['limit_s']:g} s"]
            for key, label in DIAGNOSE_CASES.items()]
    if "racquet_tosses" in d:
        r = d["racquet_tosses"]
        rows.append([f"the {r['tosses']} real racquet tosses, each about 1 s",
                     f"median {secs(r['median_s'])}, max {secs(r['max_s'])}",
                     f"{r['limit_s']:g} s each" + ("" if r["within_limit"] else " (`within_limit: false`)")])
    long = d["600s_10hz"]
    rows.append(["the rigid fit alone on the 600-s record, against `least_squares`",
                 f"{secs(long['nominal_fit_s'])} vs {secs(long['peer_least_squares_s'])}", "–"])
    return table(["recording", "wall", "limit"], rows)


def render_bench_other(folder: Path) -> str:
    """bench_bo.py's bench_bo.json and bench_vector_env.py's JSON lines."""
    s = load(folder / "bench_bo.json")["summary"]
    ours, stock = s["project"], s["stock"]
    rows = [[f"BO loop, M = {s['budget']}, {plural(s['seeds'], 'seed')}, same objective and acquisition",
             f"{secs(ours['total_wall_s'])}, mean best cost {ours['mean_best_cost']:.3g}",
             f"stock BoTorch loop: {secs(stock['total_wall_s'])} ({s['speedup_vs_stock']:.1f}× slower), "
             f"{stock['mean_best_cost']:.3g}"]]
    vec = sorted((d for d in json_lines(folder) if "wall_s_native" in d), key=lambda d: -d["threads"])
    if vec:
        # speedup: the sync env's wall time over the native one's; cpu_ratio: the same of CPU time
        runs = "; ".join(f"{d['speedup']:.2f}× the wall speed and {d['cpu_ratio']:.2f}× less CPU time "
                         f"with {plural(d['threads'], 'numba thread')}" for d in vec)
        rows.append([f"native vector env, {plural(vec[0]['num_envs'], 'env')} × "
                     f"{plural(vec[0]['steps'], 'step')}", f"against `SyncVectorEnv`: {runs}",
                     "gymnasium `SyncVectorEnv` of single envs"])
    return table(["what", "inertia-gym", "peer"], rows)


FIRST_COMMANDS = {
    "example": "`inertia-gym example thrown-rotor`",
    "identify": "`inertia-gym identify` of the thrown-rotor example (0.5 s, 1 kHz)",
    "diagnose": "`inertia-gym diagnose` of the phone-toss example (1 s, 100 Hz)",
    "simulate": "`inertia-gym simulate --duration 2`",
    "optimize": "`inertia-gym optimize --budget 2` (compiles the excitation design's simulation loop)",
}


def render_first_run(folder: Path) -> str:
    """bench_first_run.py's JSON line: each command cold and warm."""
    d = json_lines(folder)[-1]
    rows = [[FIRST_COMMANDS.get(name, f"`inertia-gym {name}`"), secs(t["cold_s"]), secs(t["warm_s"])]
            for name, t in d["commands"].items()]
    if "make_run_s" in d:
        rows.append(["`make run` in a clone, install included", secs(d["make_run_s"]), "–"])
    return table(["command", "first run (empty cache)", "again (cached)"], rows)
