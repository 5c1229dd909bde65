"""docs/results.py, the generator of docs/results.md: its blocks, its registry and its renderers.

Each renderer runs on a real output where its command makes one in seconds (the CLI in this
process, small scripts as subprocesses, all with tiny options); the others run on a fixture
with the keys the real command writes, the command named beside it.
"""

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
if str(REPO / "docs") not in sys.path:
    sys.path.insert(0, str(REPO / "docs"))

import results  # noqa: E402
import results_tables as tables  # noqa: E402

from inertia_gym.cli import main as cli  # noqa: E402

PAGE = """# Title

Prose with a number 3.14, trailing spaces\x20\x20\x20
and a quoted marker `<!-- generated: a -->` inside a line.

<!-- generated: a -->
old a
<!-- end generated: a -->

Between, unicode ξ\\* ‖Ĵ−J‖.

<!-- generated: b -->

| old | b |

<!-- end generated: b -->
tail without a final newline"""


def row_cells(text: str, first: str) -> list[str]:
    """The cells of the markdown table row of `text` whose first cell is `first`."""
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0] == first:
            return cells
    raise AssertionError(f"no row {first!r} in\n{text}")


def page_study(key: str, commands, render=lambda folder: "| new |", needs=()) -> results.Study:
    return results.Study(key, tuple(commands), render, tuple(needs))


# ---- blocks ---------------------------------------------------------------------------------

def test_replacing_a_block_keeps_the_prose_byte_for_byte():
    spans = results.blocks(PAGE)
    assert list(spans) == ["a", "b"]
    out = results.replace_blocks(PAGE, {"b": "\nNEW\n"})
    start, end = spans["b"]
    assert out == PAGE[:start] + "\nNEW\n" + PAGE[end:]
    assert out.endswith("<!-- end generated: b -->\ntail without a final newline")
    # replacing a block by its own content changes nothing at all
    assert results.replace_blocks(PAGE, {k: PAGE[s:e] for k, (s, e) in spans.items()}) == PAGE


@pytest.mark.parametrize("broken", [
    PAGE.replace("<!-- end generated: a -->\n", ""),  # a start without its end
    PAGE + "\n<!-- generated: a -->\nx\n<!-- end generated: a -->\n",  # a key twice
])
def test_unpaired_or_repeated_markers_are_refused(broken):
    with pytest.raises(ValueError):
        results.blocks(broken)


def test_every_block_of_the_page_has_a_study_and_shows_its_commands():
    text = results.PAGE.read_text()
    spans = results.blocks(text)
    assert set(spans) == {s.key for s in results.STUDIES}
    results.check_registry(text, results.STUDIES)  # the check main runs before anything
    for study in results.STUDIES:
        start, end = spans[study.key]
        body = text[start:end]
        assert body.rstrip().endswith("```bash\n" + "\n".join(study.shown()) + "\n```"), study.key


# ---- the generator's behaviour --------------------------------------------------------------

def test_a_missing_prerequisite_keeps_the_old_block_and_is_reported(tmp_path, capsys):
    page = tmp_path / "page.md"
    page.write_text(PAGE)
    need = results.Prerequisite("a thing", lambda: "the thing is not here")
    studies = (page_study("a", ["touch {out}/ran"], needs=[need]), page_study("b", ["true"]))
    assert results.main(["--only", "a", "--out-root", str(tmp_path / "out")], studies, page) == 0
    assert page.read_text() == PAGE
    assert not (tmp_path / "out" / "a").exists()  # the command did not run
    assert "a: not run, a prerequisite is missing: the thing is not here" in capsys.readouterr().out


def test_a_failing_command_keeps_the_old_block_and_fails_the_run(tmp_path, capsys):
    page = tmp_path / "page.md"
    page.write_text(PAGE)
    studies = (page_study("a", ["echo broken input >&2; exit 3"]), page_study("b", ["true"]))
    assert results.main(["--out-root", str(tmp_path / "out")], studies, page) == 1
    out = capsys.readouterr().out
    assert "exited with status 3: broken input" in out
    text = page.read_text()
    assert text == results.replace_blocks(PAGE, {"b": "\n| new |\n\n```bash\ntrue\n```\n\n"})


def test_render_only_without_outputs_keeps_every_block(tmp_path, capsys):
    page = tmp_path / "results.md"
    shutil.copy(results.PAGE, page)
    assert results.main(["--render-only", "--out-root", str(tmp_path / "empty")], page=page) == 0
    assert page.read_bytes() == results.PAGE.read_bytes()
    out = capsys.readouterr().out
    for study in results.STUDIES:
        assert f"{study.key}: its outputs are missing" in out


def test_end_to_end_a_real_validate_rewrites_its_block_only(tmp_path):
    """The registry's validate-paper study with a tiny command, through main on a copy of the page."""
    page = tmp_path / "results.md"
    shutil.copy(results.PAGE, page)
    tiny = {"validate-paper": ("inertia-gym validate --xi 0.4,4,1 --seeds 2 --duration 20 --out {out}",)}
    studies = tuple(dataclasses.replace(s, commands=tiny.get(s.key, s.commands))
                    for s in results.STUDIES)
    out = tmp_path / "out"
    assert results.main(["--only", "validate-paper", "--out-root", str(out)], studies, page) == 0
    before, after = results.PAGE.read_text(), page.read_text()
    (s0, e0), (s1, e1) = results.blocks(before)["validate-paper"], results.blocks(after)["validate-paper"]
    assert after[:s1] == before[:s0] and after[e1:] == before[e0:]
    data = json.loads((out / "validate-paper" / "result.json").read_text())
    cells = row_cells(after[s1:e1], "joint EKF")
    assert cells[1] == tables.pct(data["median_rel_error"]) and cells[5] == "0 of 2"
    assert tiny["validate-paper"][0].replace("{out}", "runs/results/validate-paper") in after[s1:e1]


# ---- renderers on real outputs --------------------------------------------------------------

@pytest.fixture(scope="module")
def cli_outputs(tmp_path_factory):
    """Tiny runs of the CLI commands behind the page, in this process: {name: folder}."""
    root = tmp_path_factory.mktemp("cli")
    runs = {
        "optimize": ["optimize", "--budget", "2", "--val-seeds", "1", "--val-duration", "20",
                     "--no-progress"],
        "validate/none": ["validate", "--xi", "none", "--seeds", "2", "--duration", "20"],
        "validate/cubesat-6u": ["validate", "--scenario", "cubesat-6u", "--xi", "0.0047036,0.0005,0.525",
                                "--seeds", "2", "--duration", "20"],
        "validate/upper-stage": ["validate", "--scenario", "upper-stage", "--xi", "811.107,50,0.525",
                                 "--seeds", "2", "--duration", "200"],
    }
    sweep = ["benchmark", "--agents", "bo,random,grid", "--seeds", "2", "--budget", "2",
             "--grid-points", "2", "--eval-seeds", "1", "--val-seeds", "1", "--val-duration", "20",
             "--workers", "1", "--no-progress"]
    runs["benchmark/default"] = sweep
    runs["benchmark/algorithm1"] = [*sweep, "--carry-over", "--cost", "info"]
    for name, argv in runs.items():
        assert cli([*argv, "--out", str(root / name)]) == 0, name
    rec = str(root / "ekf" / "R.csv")
    assert cli(["simulate", "--duration", "20", "--sample-dt", "0.01", "--out", rec]) == 0
    assert cli(["identify", rec, "--method", "ekf", "--no-plots",
                "--out", str(root / "ekf" / "ekf")]) == 0
    return root


def test_render_optimize_on_a_real_result(cli_outputs):
    data = json.loads((cli_outputs / "optimize" / "result.json").read_text())
    text = tables.render_optimize(cli_outputs / "optimize")
    cells = row_cells(text, "BO, M = 2, seed 0")
    assert cells[1] == "(" + ", ".join(f"{x:.4g}" for x in data["xi_star"]) + ")"
    assert cells[2:] == [tables.pct(data["val_rel_error"]), "yes" if data["val_scale_identified"] else "no"]
    assert "(1 seed × 20 s)" in text


def test_render_validate_scenarios_on_real_results(cli_outputs):
    text = tables.render_validate_scenarios(cli_outputs / "validate")
    none = json.loads((cli_outputs / "validate" / "none" / "result.json").read_text())
    assert not none["scale_identified"]  # no torque: the shape alone, as the row says
    shape = tables.pct(none["median_ratio_rel_error"])
    assert row_cells(text, "paper, no torque")[1] == (
        f"{tables.pct(none['median_rel_error'])} (trace-normalised {shape})")
    stage = json.loads((cli_outputs / "validate" / "upper-stage" / "result.json").read_text())
    cells = row_cells(text, "shipped `upper-stage`, (811.107, 50, 0.525)")
    assert stage["scale_identified"]
    assert cells[1:3] == [tables.pct(stage["median_rel_error"]), tables.pct(max(stage["rel_errors"]))]
    assert cells[5] == f"{sum(stage['scale_identified_per_seed'])} of 2"
    assert "shipped `cubesat-6u`, (0.0047036, 0.0005, 0.525)" in text


def test_render_benchmark_on_real_sweeps(cli_outputs):
    text = tables.render_benchmark(cli_outputs / "benchmark")
    rows = [ln for ln in text.splitlines()[2:]]
    assert len(rows) == 6  # bo, random and the grid under each of the two objectives
    report = json.loads((cli_outputs / "benchmark" / "algorithm1" / "benchmark.json").read_text())
    bo = report["summary"]["agents"]["bo"]
    wins = f"{bo['win_rate']['random'] * bo['win_seeds']['random']:g} of 2"
    assert rows[4].endswith(f"| {wins} |") and "| random |" in rows[4]
    assert rows[3].startswith("| `--carry-over --cost info` (Algorithm 1) | bo | "
                              + tables.quartiles(bo["regret"]))
    grid = report["summary"]["grid"]
    assert f"grid optimum {tables.xi_label(grid['xi_star'])}" in rows[5]


def test_render_bench_identify_on_a_real_ekf_run(cli_outputs, tmp_path):
    folder = tmp_path / "bench-identify"
    shutil.copytree(cli_outputs / "ekf", folder)
    # the lines `python scripts/bench_identify.py --duration-a 20` prints (case a trimmed), then
    # what simulate and identify print
    (folder / "stdout.md").write_text(
        '{"case": "a", "n_samples": 2001, "duration_s": 20.0, "attitude": true, "torque": true, '
        '"rotor_h": false, "wall_s_identify": 0.8358, "wall_s_identify_runs": [0.8526, 0.8191], '
        '"rel_error_identify": 0.000926, "crlb_identify": 0.00099, "identify_converged": true, '
        '"n_params": 15, "rel_error_start": 0.4706, "wall_s_peer": 0.144, "speedup": 0.2, '
        '"rel_error_peer": 0.0609, "peer_reached_identify": false}\n'
        '{"case": "c", "throws": 11, "wall_s_joint": 1.486, "wall_s_singles": 1.071, '
        '"estimator": "output error", "rel_error_joint": 6.62e-06, "rel_error_singles_mean": 0.000451, '
        '"agreement_p": 0.57}\n'
        "wrote R.csv (2001 rows), effect: none\n")
    text = tables.render_bench_identify(folder)
    assert row_cells(text, "paper's scenario, 20 s at 100 Hz, bursts and attitude")[1:] == [
        "0.836 s (0.819–0.853), error 0.00093 against its bound 0.00099",
        "0.144 s, error 0.061 (its start: 0.47)"]
    assert row_cells(text, "`identify_joint` of 11 such throws")[1] == "1.49 s, error 6.6·10⁻⁶"
    ekf = json.loads((folder / "ekf" / "identify.json").read_text())
    assert row_cells(text, "`identify --method ekf` on a 20-s simulated recording")[1].endswith(
        f"error in {tables.secs(ekf['wall_s'])}")


def script(tmp_path, *argv) -> Path:
    """Run a script of scripts/ as the generator does, its stdout captured to stdout.md."""
    folder = tmp_path / "out"
    folder.mkdir(exist_ok=True)
    with open(folder / "stdout.md", "a") as out:
        subprocess.run([sys.executable, *argv], cwd=REPO, stdout=out, check=True,
                       env={**os.environ, "PYTHONPATH": ".:tests"})
    return folder


def test_render_bench_speed_on_a_real_run(tmp_path):
    folder = script(tmp_path, "scripts/bench_speed.py", "--duration", "2", "--repeats", "3")
    line = json.loads((folder / "stdout.md").read_text())
    cells = row_cells(tables.render_bench_speed(folder), "2 s of truth + EKF")
    assert cells[1:] == [f"{tables.secs(line['wall_s_project'])} (median of 3 runs)",
                         tables.secs(line["wall_s_peer"]), f"{line['speedup']:.0f}×"]


def test_render_identify_families_splices_the_printed_table(tmp_path):
    folder = script(tmp_path, "scripts/identify_tables.py", "families", "--seeds", "1")
    text = tables.render_stdout(folder)
    assert text.startswith("| case | within 3 sigma and 0.5 % |")
    assert len([ln for ln in text.splitlines() if ln.startswith("| flat ")]) == 24
    symmetric = ("| oblate ", "| prolate ", "| near-spherical ")
    assert len([ln for ln in text.splitlines() if ln.startswith(symmetric)]) == 10
    assert row_cells(text, "satellite, five torque pulses")[1:3] == ["1/1", "–"]
    # an efficient estimator's expected passes of the one seed: a probability
    for case in ("flat 0.2:0.8 delta 0.02 5 rad/s noise 0.001", "prolate 0.3:1:1.02 5 rad/s noise 0.001"):
        assert 0.0 <= float(row_cells(text, case)[2]) <= 1.0
    assert text.splitlines()[-1].endswith("of the 34 tossed cases")  # the totals under the table


def test_render_cost_vs_error_on_a_real_run(tmp_path):
    folder = tmp_path / "out"
    subprocess.run([sys.executable, "scripts/benchmark_studies.py", "cost-vs-error", "--xis", "3",
                    "--seeds", "1", "--val-seeds", "1", "--runs", "1", "--budget", "12",
                    "--out", str(folder)],
                   cwd=REPO, check=True, capture_output=True)
    a = json.loads((folder / "cost_vs_error.json").read_text())["A_from_start"]
    text = tables.render_cost_vs_error(folder)
    assert "3 Sobol ξ" in text.splitlines()[0]
    assert row_cells(text, "info (the paper's J)")[1] == f"{a['info']['rho_validated_error_1000s']:.2f}"


# ---- renderers on fixtures ------------------------------------------------------------------

def test_render_bench_other_on_fixtures(tmp_path):
    # bench_bo.json as `python scripts/bench_bo.py --out DIR` writes it (its summary; runs trimmed)
    (tmp_path / "bench_bo.json").write_text(json.dumps({"summary": {
        "budget": 100, "seeds": 4, "torch_default_threads": 2,
        "project": {"total_wall_s": 22.1, "mean_best_cost": -0.119},
        "stock": {"total_wall_s": 70.9, "mean_best_cost": -0.113},
        "stock_1thread": {"total_wall_s": 50.0, "mean_best_cost": -0.113},
        "speedup_vs_stock": 3.21, "speedup_vs_stock_1thread": 2.26}, "runs": []}))
    # the lines `python scripts/bench_vector_env.py` prints, with 2 numba threads and with 1
    line = {"wall_s_native": 0.1, "wall_s_sync": 0.19, "speedup": 1.9, "cpu_s_native": 0.14,
            "cpu_s_sync": 0.19, "cpu_ratio": 1.36, "num_envs": 8, "steps": 3, "threads": 2,
            "same_results": True}
    (tmp_path / "stdout.md").write_text("seed 0: project 5.5 s\n{\n \"budget\": 100\n}\n"
                                        + json.dumps(line) + "\n" + json.dumps({**line, "threads": 1}) + "\n")
    text = tables.render_bench_other(tmp_path)
    assert row_cells(text, "BO loop, M = 100, 4 seeds, same objective and acquisition")[1:] == [
        "22.1 s, mean best cost -0.119", "stock BoTorch loop: 70.9 s (3.2× slower), -0.113"]
    vec = row_cells(text, "native vector env, 8 envs × 3 steps")[1]
    assert vec.index("with 2 numba threads") < vec.index("with 1 numba thread")
    assert "1.90× the wall speed and 1.36× less CPU time" in vec


def test_render_bench_diagnose_on_a_fixture(tmp_path):
    # the --json file of `python scripts/bench_diagnose.py --repeat 3 --json FILE` (keys the
    # renderer does not read trimmed)
    case = {"rows": 6000, "segments": 1, "within_limit": True, "nominal_fit_s": 0.043,
            "peer_least_squares_s": 5.62, "speedup": 130.7}
    (tmp_path / "bench_diagnose.json").write_text(json.dumps({
        "helpers": 1, "600s_10hz": {**case, "diagnose_s": 8.82, "limit_s": 10.0},
        "toss_1s_100hz": {**case, "diagnose_s": 1.07, "limit_s": 5.0},
        "racquet_tosses": {"tosses": 12, "median_s": 3.64, "max_s": 5.76, "limit_s": 5.0,
                           "within_limit": False}}))
    text = tables.render_bench_diagnose(tmp_path)
    assert row_cells(text, "1-s racquet toss at 100 Hz with drag")[1:] == ["1.07 s", "5 s"]
    assert row_cells(text, "the 12 real racquet tosses, each about 1 s")[1:] == [
        "median 3.64 s, max 5.76 s", "5 s each (`within_limit: false`)"]
    rigid = row_cells(text, "the rigid fit alone on the 600-s record, against `least_squares`")
    assert rigid[1] == "0.043 s vs 5.62 s"
    # without the racquet data the script writes no racquet_tosses and the row is left out
    data = json.loads((tmp_path / "bench_diagnose.json").read_text())
    del data["racquet_tosses"]
    (tmp_path / "bench_diagnose.json").write_text(json.dumps(data))
    assert "racquet tosses" not in tables.render_bench_diagnose(tmp_path)


def test_render_first_run_on_a_fixture(tmp_path):
    # the line `PYTHONPATH=. python scripts/bench_first_run.py --make-run` prints
    (tmp_path / "stdout.md").write_text(json.dumps({"commands": {
        "example": {"cold_s": 1.8, "warm_s": 1.7}, "optimize": {"cold_s": 168.4, "warm_s": 5.0}},
        "make_run_s": 400.2}) + "\n")
    text = tables.render_first_run(tmp_path)
    assert row_cells(text, "`inertia-gym example thrown-rotor`")[1:] == ["1.8 s", "1.7 s"]
    assert row_cells(text, tables.FIRST_COMMANDS["optimize"])[1:] == ["168 s", "5 s"]
    assert row_cells(text, "`make run` in a clone, install included")[1] == "400 s"


def test_render_diagnose_harness_on_a_fixture(tmp_path):
    # the --out file of `PYTHONPATH=. python scripts/confusion_matrix.py --out FILE` (rows trimmed)
    figures = {"singles_correct": 45, "singles": 45, "pairs_both_named": 16, "pairs": 16, "false_alarms": 0,
               "controls": 40, "params_within_20pc": 45, "param_error_median": 0.006, "rms_within_1p2": 101,
               "recordings": 101, "rms_over_noise_median": 1.0012}
    rows = [{"label": "none", "seed": 1000, "top": "none", "explanation": [], "wall_s": w,
             "rms_over_noise": 1.0} for w in (7.0, 7.6, 9.0)]
    (tmp_path / "cm.json").write_text(json.dumps({"figures": figures, "wall_s": 700.0, "rows": rows,
                                                  "args": {}}))
    text = tables.render_diagnose_harness(tmp_path)
    assert row_cells(text, "false alarms on clean controls")[1] == "0 / 40"
    assert row_cells(text, "correct single effects with fitted parameters within 20 % of the truth")[1] == (
        "45 / 45 (median error 0.6 %)")
    assert row_cells(text, "wall time per recording (median)")[1] == "7.6 s"


def test_render_basilisk_diagnose_on_a_fixture(tmp_path):
    # basilisk_harness.json of `PYTHONPATH=.:tests python scripts/basilisk_harness.py diagnose
    # --out DIR` (keys the renderer does not read trimmed)
    def row(case, components, named, correct, rms, off, outside=(), dissipation=False):
        return {"case": case, "components": components, "named": named, "correct": correct,
                "mismatch_detected": bool(components), "rms_over_noise_after": rms, "nominal_error": off,
                "outside_truth": list(outside), "reads_dissipation": dissipation}

    rows = [row("control_smallsat_bursts", [], [], True, [0.99, 1.0, 1.01], 0.0),
            row("control_bus_free", [], [], True, [1.06, 1.0, 1.0], 0.0),
            row("slosh_smallsat_bursts", ["slosh"], ["inertia_offset"], True, [1.08, 1.16, 1.2], 0.0696),
            row("slosh_damped_bus_bursts", ["slosh_damped"], ["inertia_offset", "internal_dissipation"], True,
                [1.0, 1.1, 1.0], 0.05, dissipation=True),
            row("slosh_damped_smallsat_bursts", ["slosh_damped"], ["inertia_offset", "constant_body_torque"],
                True, [1.0, 1.3, 1.0], 0.07, outside=["constant_body_torque"]),
            row("pair_panel_torque", ["panel", "hidden_torque"], ["inertia_offset"], False,
                [1.1, 3.55, 1.0], 0.25),
            row("drift_bus_long", ["gyro_drift"], [], False, None, 0.0)]
    totals = {"cases": 5, "cases_correct": 3, "controls": 2, "controls_clean": 2, "wall_s": 60.0,
              "duration_s": 60.0, "stamp_scatter": 0.0, "gyro_step": 20.0}
    (tmp_path / "basilisk_harness.json").write_text(json.dumps({"totals": totals, "rows": rows}))
    text = tables.render_basilisk_diagnose(tmp_path)
    assert row_cells(text, "nothing (controls)")[1:] == ["2", "2", "0", "0.0 %", "1.01–1.06"]
    assert row_cells(text, "slosh")[1:] == ["1", "1", "0", "7.0 %", "1.20"]
    assert row_cells(text, "slosh damped past resonance")[1:] == ["2", "2", "1", "5.0–7.0 %", "1.10–1.30"]
    assert row_cells(text, "pairs of the above")[1:] == ["1", "0", "0", "25.0 %", "3.55"]
    assert row_cells(text, "gyro bias drifting")[1:] == ["1", "0", "0", "0.0 %", "–"]
    assert row_cells(text, "**all**")[2:4] == ["**3 of 5, controls 2 of 2**", "**1**"]
    assert "read as internal dissipation: 1 of 2." in text
    assert "- `pair_panel_torque`: concealed panel, hidden_torque; named inertia_offset" in text
    assert "- `drift_bus_long`: concealed gyro_drift; named nothing" in text
    assert "- `slosh_damped_smallsat_bursts`: constant_body_torque beside inertia_offset" in text
    every = tables.render_basilisk_diagnose_cases(tmp_path)
    assert every.startswith(text)
    assert row_cells(every, "`slosh_damped_smallsat_bursts`")[1:] == [
        "slosh_damped", "7.0 %", "inertia_offset, constant_body_torque", "constant_body_torque", "no", "1.30",
        "yes"]
    assert row_cells(every, "`drift_bus_long`")[-2:] == ["–", "no"]


def test_render_basilisk_identify_puts_the_per_kind_table_first(tmp_path):
    # what `PYTHONPATH=.:tests python scripts/basilisk_harness.py identify --seeds 1 --kinds
    # bursts,panel --bodies device,smallsat` prints
    head = ("| kind | body | cases | median error | worst | 95 % coverage | rms z | scale identified "
            "| rms/noise |\n|---|---|---|---|---|---|---|---|---|\n")
    (tmp_path / "stdout.md").write_text(
        '{"bursts/device": {"cases": 1, "median_error": 0.000183}}\n'
        + head + "| bursts | device | 1 | 0.0183 % | 0.0183 % | 6/6 | 1.07 | 1/1 | 0.99 |\n"
        "| panel | smallsat | 1 | 0.0832 % | 0.0832 % | 6/6 | 0.05 | 1/1 | 16.76 |\n\n"
        + head + "| bursts | all | 2 | 0.0115 % | 0.0183 % | 12/12 | 0.94 | 2/2 | 1.00 |\n"
        "| panel | all | 2 | 0.0848 % | 0.0864 % | 12/12 | 0.04 | 2/2 | 12.17 |\n\nwall 7 s\n")
    text = tables.render_basilisk_identify(tmp_path)
    first, second = text.split("\n\n")
    assert "| panel | all | 2 |" in first and "| panel | smallsat | 1 |" in second
    assert "wall" not in text and "{" not in text


def test_render_identify_rotor_splices_tables_and_lines(tmp_path):
    # what `PYTHONPATH=. python scripts/identify_tables.py rotor` prints (one configuration kept)
    printed = (
        "| configuration | estimator | median Frobenius % | worst Frobenius % | median worst-moment % "
        "| worst moment % |\n|---|---|---|---|---|---|\n| A (11) | identify | 2.47 | 5.97 | 2.13 | 5.58 |\n\n"
        "- scale identified on 31 of 31; principal moments' 95 % intervals hold the reference's on 85 of 93\n"
        "- identify's wall time: median 0.34 s, max 0.46 s\n\n"
        "| body | joint principal moments, error % | 95 % half-width % | covered | agreement p "
        "| classic's mean, error % | wall s |\n|---|---|---|---|---|---|---|\n"
        "| A (11) | +1.79, +0.02, +0.13 | 0.70, 0.78, 0.79 | 2/3 | 0.139 | +2.45, +0.39, +0.36 | 3.6 |\n")
    (tmp_path / "stdout.md").write_text(printed)
    assert tables.render_stdout(tmp_path) == printed.strip()
    # without the data the script prints one line and no table: nothing to splice
    (tmp_path / "stdout.md").write_text("no rotor-throw data at /x (truth.json missing): nothing to do\n")
    with pytest.raises(ValueError, match="no markdown table"):
        tables.render_stdout(tmp_path)


def test_number_formats():
    assert [tables.pct(0.00298), tables.pct(0.15), tables.pct(None)] == ["0.298 %", "15 %", "–"]
    assert [tables.sci(6.6e-6), tables.sci(1.12e-15), tables.sci(0.139)] == ["6.6·10⁻⁶", "1.1·10⁻¹⁵", "0.14"]
    assert tables.quartiles({"median": 0.00351, "q25": 0.00339, "q75": 0.00357}, 100.0, " %") == (
        "0.351 % [0.339, 0.357]")
