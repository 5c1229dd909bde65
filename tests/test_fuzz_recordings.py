"""Fuzz `identify` and `diagnose` over damaged recordings (issue 12, must-show 5).

A simulated recording (gyro, attitude, torque, rotor momentum) is written with its time in
µs or ms, its rates in °/s, columns renamed (mapped back with --columns or not), columns
dropped, cells replaced by NaN, infinity or junk, scales over many decades, a constant
clock or a handful of rows. Every outcome must be a valid result (exit 0, strict JSON with
finite numbers, a physically possible inertia) or one line on stderr with exit 2: never a
traceback, an internal error (exit 1), a RuntimeWarning, or nonsense with exit 0.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from inertia_gym.cli import main
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.recordings import COLUMN_NAMES
from inertia_gym.scenario import Scenario

ROWS = 101  # 1 s at 100 Hz: enough for both commands, small enough to fuzz


@pytest.fixture(scope="module")
def base() -> tuple[dict[str, np.ndarray], dict]:
    """Columns of a 1-s recording of the paper's body with torque bursts and a rotor, and its sidecar."""
    rec, side = simulate_recording(Scenario(), (ROWS - 1) * 0.01, seed=4, rotor_h_max=5.0)
    arrays = np.hstack([rec.t[:, None], rec.w, rec.q, rec.tau, rec.h])
    return dict(zip(COLUMN_NAMES, arrays.T, strict=True)), side


def _json_constant(name):
    raise ValueError(f"{name} in JSON output")


def _finite_numbers(value) -> bool:
    if isinstance(value, dict):
        return all(_finite_numbers(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite_numbers(v) for v in value)
    return not isinstance(value, float) or np.isfinite(value)


def _physical(inertia) -> bool:
    moments = np.linalg.eigvalsh(np.asarray(inertia, dtype=float))
    return bool(moments[0] > 0 and moments[2] <= (moments[0] + moments[1]) * (1 + 1e-6))


def _sometimes(draw, strategy, default):
    """Draw from strategy one time in three, else the default: most plans keep most things whole."""
    return draw(strategy) if draw(st.integers(0, 2)) == 1 else default


@st.composite
def damaged(draw):
    """A plan of damage to the base recording (see _write)."""
    return dict(
        n=_sometimes(draw, st.sampled_from([1, 5, 12, 40]), ROWS),
        time_unit=_sometimes(draw, st.sampled_from(["ms", "us"]), "s"),
        rate_unit=_sometimes(draw, st.just("deg/s"), "rad/s"),
        stated=_sometimes(draw, st.sampled_from(["time", "rate", "both", "wrong"]), "none"),
        scales={group: 10.0 ** _sometimes(draw, st.integers(-8, 8), 0) for group in ("t", "w", "tau", "h")},
        constant_time=_sometimes(draw, st.booleans(), False) and draw(st.booleans()),
        keep=_sometimes(draw, st.lists(st.sampled_from(COLUMN_NAMES), unique=True,
                                       max_size=len(COLUMN_NAMES)), list(COLUMN_NAMES)),
        renamed=_sometimes(draw, st.dictionaries(
            st.sampled_from(COLUMN_NAMES), st.sampled_from(["time", "gx", "gy", "gz", "Tx", "q0", "col"]),
            max_size=4), {}),
        map_back=_sometimes(draw, st.sampled_from(["no", "unknown target", "missing source"]), "yes"),
        cells=_sometimes(draw, st.lists(st.tuples(st.integers(0, ROWS - 1), st.sampled_from(COLUMN_NAMES),
                                                  st.sampled_from(["nan", "inf", "-inf", "", "abc", "1e308",
                                                                   "-1e308"])), max_size=3), []),
        sidecar=_sometimes(draw, st.sampled_from(["none", "bad sigma"]), "keep"),
    )


def _write(folder: Path, plan: dict, base) -> list[str]:
    """Write the damaged recording into folder; return the CLI arguments that read it."""
    columns, side = base
    factor = {"s": 1.0, "ms": 1e3, "us": 1e6}[plan["time_unit"]]
    table = {}
    for name in plan["keep"]:
        values = columns[name][: plan["n"]].copy()
        if name == "t":
            values = np.full_like(values, 3.0) if plan["constant_time"] else values
            values = values * factor * plan["scales"]["t"]
        elif name in ("wx", "wy", "wz"):
            values = values * (180.0 / np.pi if plan["rate_unit"] == "deg/s" else 1.0) * plan["scales"]["w"]
        elif name.startswith("tau"):
            values = values * plan["scales"]["tau"]
        elif name.startswith("h_"):
            values = values * plan["scales"]["h"]
        table[name] = [f"{v:.10g}" for v in values]
    for row, name, text in plan["cells"]:
        if name in table and row < len(table[name]):
            table[name][row] = text
    header = {name: plan["renamed"].get(name, name) for name in table}
    if len(set(header.values())) < len(header):  # two columns renamed alike: keep the names
        header = {name: name for name in table}
    path = folder / "rec.csv"
    lines = [",".join(header[name] for name in table)]
    lines += [",".join(table[name][i] for name in table) for i in range(plan["n"])]
    path.write_text("\n".join(lines) + "\n")
    if plan["sidecar"] != "none":
        meta = dict(side, gyro_sigma=-1.0) if plan["sidecar"] == "bad sigma" else side
        (folder / "rec.json").write_text(json.dumps(meta))
    args = [str(path)]
    mapping = {target: source for target, source in header.items() if target != source}
    if plan["map_back"] == "unknown target":
        mapping["omega_x"] = header.get("wx", "wx")
    elif plan["map_back"] == "missing source":
        mapping["wx"] = "no_such_column"
    if mapping and plan["map_back"] != "no":
        args += ["--columns", ",".join(f"{t}={s}" for t, s in mapping.items())]
    stated = plan["stated"]
    if stated in ("time", "both"):
        args += ["--time-unit", plan["time_unit"]]
    if stated in ("rate", "both"):
        args += ["--rate-unit", plan["rate_unit"]]
    if stated == "wrong":
        args += ["--time-unit", "s" if plan["time_unit"] != "s" else "ms"]
    return args


def _check_outcome(command: str, folder: Path, args: list[str], capsys) -> tuple[int, str]:
    """Run the command in-process; assert the outcome is valid; return (exit code, stderr)."""
    out = folder / "out"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main([command, *args, "--no-plots", "--out", str(out)])
    err = capsys.readouterr().err
    runtime = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert not runtime, runtime
    assert "Traceback" not in err and "Warning" not in err, err
    assert code in (0, 2), err
    if code == 2:
        assert err.strip() and err.strip().count("\n") == 0, err
        assert err.startswith(f"inertia-gym {command}: error: "), err
        return code, err
    reports = sorted(out.rglob("identify.json" if command == "identify" else "report.json"))
    assert reports
    for path in reports:
        report = json.loads(path.read_text(), parse_constant=_json_constant)
        assert _finite_numbers(report)
        inertia = report["inertia"] if command == "identify" else report["fit_after"]["inertia"]
        assert _physical(inertia), inertia
    return code, err


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(plan=damaged())
def test_identify_on_damaged_recordings_gives_a_result_or_one_line(plan, base, tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("fuzz")
    code, err = _check_outcome("identify", folder, _write(folder, plan, base), capsys)
    event(f"exit {code}: {err.split('rec.csv')[-1].strip()[:50] if code else 'identify'}")


#: The rotor's momentum logged 1000x too large: the explanation's inertia_offset can get a
#: covariance so wide that draws from it overflow, and principal ratios' intervals of NaN would be
#: refused by the JSON writer (an internal error).
LOGGED_MOMENTUM_1000X = {
    "n": ROWS, "time_unit": "s", "rate_unit": "rad/s", "stated": "none",
    "scales": {"t": 1.0, "w": 1.0, "tau": 1.0, "h": 1000.0}, "constant_time": False,
    "keep": list(COLUMN_NAMES), "renamed": {}, "map_back": "yes", "cells": [], "sidecar": "keep"}


@pytest.mark.slow
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(plan=damaged())
@example(plan=LOGGED_MOMENTUM_1000X)
def test_diagnose_on_damaged_recordings_gives_a_result_or_one_line(plan, base, tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("fuzz")
    code, err = _check_outcome("diagnose", folder, _write(folder, plan, base), capsys)
    event(f"exit {code}: {err.split('rec.csv')[-1].strip()[:50] if code else 'diagnose'}")


@pytest.mark.parametrize("time_factor, rate_factor, momentum_factor, stated, expected", [
    (1e6, 1.0, 1.0, [], "time in us"),
    (1e3, 1.0, 1.0, [], "time in ms"),
    (1.0, 180.0 / np.pi, 1.0, [], "deg/s"),
    (1e3, 1.0, 1.0, ["--time-unit", "ms"], None),
    (1.0, 180.0 / np.pi, 1.0, ["--rate-unit", "deg/s"], None),
    (1e8, 1.0, 1.0, ["--time-unit", "s", "--rate-unit", "rad/s"], "cut the recording"),
    (1.0, 10.0, 1.0, ["--time-unit", "s", "--rate-unit", "rad/s"], "does not explain this recording"),
    pytest.param(1e3, 1.0, 100.0, ["--time-unit", "s", "--rate-unit", "rad/s"], "times the nominal's",
                 marks=pytest.mark.science),
])
def test_units_of_a_simulated_recording_are_refused_or_converted(base, tmp_path, capsys, time_factor,
                                                                  rate_factor, momentum_factor, stated,
                                                                  expected):
    """Units that break a fit unless read: t in µs (a traceback), rates in °/s (an indefinite
    inertia); time stated in s but 1e8 times too long (identify would integrate ~1e7 rad between
    samples for minutes), rates stated in rad/s but 10 times too large (the model-error
    covariance can overflow, an internal error: refused, or reported with notes that the
    residuals and the samples' own scatter are ten times the sidecar's noise), time 1000 and the
    rotor's momentum 100 times too large (a finite model-error covariance of 1e306 whose error
    bars would overflow into NaN in identify.json, an internal error: refused as several times
    the nominal)."""
    columns, side = base
    factors = {"t": time_factor, "wx": rate_factor, "wy": rate_factor, "wz": rate_factor,
               "h_x": momentum_factor, "h_y": momentum_factor, "h_z": momentum_factor}
    data = np.stack([columns[name] * factors.get(name, 1.0) for name in COLUMN_NAMES], axis=1)
    path = tmp_path / "rec.csv"
    np.savetxt(path, data, delimiter=",", header=",".join(COLUMN_NAMES), comments="", fmt="%.10g")
    (tmp_path / "rec.json").write_text(json.dumps(side))
    code, err = _check_outcome("identify", tmp_path, [str(path), *stated], capsys)
    if expected is None:
        assert code == 0
        summary = json.loads((tmp_path / "out" / "identify.json").read_text())
        inertia, truth = np.array(summary["inertia"]), Scenario().inertia_true_array
        shape_error = np.linalg.norm(inertia / np.trace(inertia) - truth / np.trace(truth))
        assert shape_error < 0.05 * np.linalg.norm(truth / np.trace(truth)), shape_error
    elif code == 0:  # not refused: the result itself says the record is not what the sidecar states
        notes = " ".join(json.loads((tmp_path / "out" / "identify.json").read_text())["notes"])
        assert "times the sidecar's gyro_sigma" in notes and "the rigid model leaves" in notes
        assert expected == "does not explain this recording"
    else:
        assert code == 2 and expected in err


@pytest.mark.parametrize("command", ["diagnose", "identify"])
@pytest.mark.parametrize("case, message", [
    ("single row", "only 1 samples"),
    ("short", "needs at least"),
    ("constant time", "time does not increase"),
    ("huge values", "beyond any physical scale"),
    ("NaN column", "column 'wy': value is NaN"),
    ("empty segment", "segment 1 .* holds 0 samples"),
    ("clipped", r"the gyro clipped at its full scale in \d+ of 101 (samples|rows)"),
])
def test_odd_inputs_end_in_one_line(base, tmp_path, capsys, write_phyphox, command, case, message):
    columns, _ = base
    if case == "empty segment":
        t = np.arange(300) * 0.01
        w = np.stack([np.sin(t), np.ones_like(t), np.cos(t)], axis=1)
        path = write_phyphox(tmp_path / "Gyroscope rotation rate 1", t, w,
                             "segment,start,end,keep\n0,0.5,2.5,\n1,5.0,6.0,\n")
    else:
        data = {name: columns[name].copy() for name in ("t", "wx", "wy", "wz")}
        rows = {"single row": 1, "short": 15}.get(case, ROWS)
        if case == "constant time":
            data["t"][:] = 2.0
        elif case == "huge values":
            data["wz"] = data["wz"] * 1e300
        elif case == "NaN column":
            data["wy"][:] = np.nan
        elif case == "clipped":  # a gyro whose range the body's rates exceed on 90 % of the rows
            w = np.stack([data[name] for name in ("wx", "wy", "wz")], axis=1)
            limit = np.percentile(np.abs(w).max(axis=1), 10)
            for name in ("wx", "wy", "wz"):
                data[name] = np.clip(data[name], -limit, limit)
        path = tmp_path / "rec.csv"
        np.savetxt(path, np.stack(list(data.values()), axis=1)[:rows], delimiter=",", header="t,wx,wy,wz",
                   comments="", fmt="%.10g")
    code, err = _check_outcome(command, tmp_path, [str(path)], capsys)
    assert code == 2 and re.search(message, err), err
