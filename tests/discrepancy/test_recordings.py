"""Recording I/O: the formats read, and every malformed input ends in RecordingError."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from inertia_gym.discrepancy.recordings import (
    Recording,
    read_recordings,
    read_sidecar,
    write_recording,
)
from inertia_gym.errors import RecordingError

GOOD = "t,wx,wy,wz\n" + "".join(f"{0.1 * i},0.1,0.2,{0.01 * i}\n" for i in range(20))


def _write(tmp_path, text, name="rec.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_reads_project_csv_with_sidecar(tmp_path):
    path = _write(tmp_path, GOOD)
    (tmp_path / "rec.json").write_text('{"gyro_sigma": 0.01, "inertia_nominal": [[1,0,0],[0,2,0],[0,0,3]]}')
    (rec,) = read_recordings(path)
    assert rec.w.shape == (20, 3) and rec.q is None and rec.tau is None
    assert rec.meta["gyro_sigma"] == 0.01 and rec.inertia_nominal[2, 2] == 3.0


@pytest.mark.parametrize("text, match", [
    ("", "empty file"),
    ("t,wx,wy,wz\n", "no data rows"),
    ("t,wx,wy\n" + "0,1,2\n" * 20, "missing column.*wz"),
    (GOOD.replace("0.30000000000000004,0.1", "0.1,0.1"), "row 5, column 't'.*does not increase"),
    (GOOD.replace("0.5,0.1,0.2", "0.5,nan,0.2"), "row 7, column 'wx'.*NaN"),
    (GOOD.replace("0.5,0.1,0.2", "0.5,abc,0.2"), "row 7, column 'wx'.*not a number"),
    (GOOD.replace("0.5,0.1,0.2", "0.5,573.0,0.2"), "row 7, column 'wx'.*deg/s"),
    (GOOD.replace("0.5,0.1,0.2", "0.5,0.1"), "row 7.*fields"),
    ("t,wx,wy,wz\n0,1,1,1\n", "only 1 samples"),
])
def test_malformed_csv_names_file_row_column(tmp_path, text, match):
    path = _write(tmp_path, text)
    with pytest.raises(RecordingError, match=match) as info:
        read_recordings(path)
    assert str(path) in str(info.value)


def test_quaternion_units_and_bad_sidecar(tmp_path):
    rows = "".join(f"{0.1 * i},0.1,0.2,0.3,2,0,0,0\n" for i in range(20))
    path = _write(tmp_path, "t,wx,wy,wz,qw,qx,qy,qz\n" + rows)
    with pytest.raises(RecordingError, match="quaternion norm"):
        read_recordings(path)
    path = _write(tmp_path, GOOD, "b.csv")
    (tmp_path / "b.json").write_text('{"inertia_nominal": [[1,0],[0,1]]}')
    with pytest.raises(RecordingError, match="b.json.*inertia_nominal"):
        read_recordings(path)


def test_write_refuses_to_overwrite_and_round_trips(tmp_path):
    t = np.arange(20) * 0.1
    rec = Recording(t, np.ones((20, 3)), np.tile([1.0, 0, 0, 0], (20, 1)), np.zeros((20, 3)))
    path = tmp_path / "out.csv"
    write_recording(path, rec, {"gyro_sigma": 0.02})
    (back,) = read_recordings(path)
    np.testing.assert_allclose(back.t, t)
    assert back.q is not None and back.tau is not None and back.meta["gyro_sigma"] == 0.02
    with pytest.raises(RecordingError, match="refusing to overwrite"):
        write_recording(path, rec)


def test_parquet(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    t = np.arange(30) * 0.01
    pq.write_table(pa.table({"t": t, "wx": np.sin(t), "wy": t, "wz": t}), tmp_path / "r.parquet")
    (rec,) = read_recordings(tmp_path / "r.parquet")
    assert rec.w.shape == (30, 3)


def _momentum_recording(n=20):
    t = np.arange(n) * 0.1
    h = np.stack([0.5 * np.sin(t), 0.25 * t, np.full(n, -0.125)], axis=1)
    return Recording(t, np.ones((n, 3)), None, np.zeros((n, 3)), {"gyro_sigma": 0.02}, "m", h=h)


def test_momentum_columns_round_trip_csv(tmp_path):
    rec = _momentum_recording()
    assert rec.has_momentum
    write_recording(tmp_path / "h.csv", rec)
    assert (tmp_path / "h.csv").read_text().splitlines()[0] == "t,wx,wy,wz,tau_x,tau_y,tau_z,h_x,h_y,h_z"
    (back,) = read_recordings(tmp_path / "h.csv")
    assert back.h is not None and back.has_momentum and back.q is None
    np.testing.assert_allclose(back.h, rec.h, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(back.tau, rec.tau)


def test_recording_without_momentum_columns_has_none(tmp_path):
    (rec,) = read_recordings(_write(tmp_path, GOOD))
    assert rec.h is None and not rec.has_momentum
    constant = Recording(rec.t, rec.w, h=np.tile([0.1, 0.0, 0.0], (rec.t.size, 1)))
    assert not constant.has_momentum


def test_positional_construction_unchanged():
    t = np.arange(20) * 0.1
    rec = Recording(t, np.ones((20, 3)), None, None, {"a": 1}, "pos")
    assert rec.meta == {"a": 1} and rec.name == "pos" and rec.h is None


def test_momentum_columns_parquet(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    t = np.arange(30) * 0.01
    h = np.stack([np.cos(t), 2 * t, t ** 2], axis=1)
    pq.write_table(pa.table({"t": t, "wx": np.sin(t), "wy": t, "wz": t,
                             "h_x": h[:, 0], "h_y": h[:, 1], "h_z": h[:, 2]}), tmp_path / "h.parquet")
    (rec,) = read_recordings(tmp_path / "h.parquet")
    np.testing.assert_array_equal(rec.h, h)
    assert rec.has_momentum and rec.tau is None


def test_partial_momentum_columns_refused(tmp_path):
    rows = "".join(f"{0.1 * i},0.1,0.2,0.3,{0.01 * i},0.5\n" for i in range(20))
    path = _write(tmp_path, "t,wx,wy,wz,h_x,h_y\n" + rows)
    with pytest.raises(RecordingError) as info:
        read_recordings(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    assert "column 'h_z'" in message and "internal angular momentum" in message


@pytest.mark.parametrize("bad, column", [("nan", "h_y"), ("inf", "h_y"), ("-inf", "h_y")])
def test_non_finite_momentum_refused_with_row_and_column(tmp_path, bad, column):
    rows = [f"{0.1 * i},0.1,0.2,0.3,{0.01 * i},0.5,0.0" for i in range(20)]
    rows[4] = rows[4].replace(",0.5,", f",{bad},")
    path = _write(tmp_path, "t,wx,wy,wz,h_x,h_y,h_z\n" + "\n".join(rows) + "\n")
    with pytest.raises(RecordingError, match=f"row 6, column '{column}'.*NaN or infinite"):
        read_recordings(path)


def test_unknown_sidecar_keys_are_kept(tmp_path):
    path = _write(tmp_path, GOOD)
    provenance = {"git_commit": "abc123", "operator": "bench 2", "rig": {"wheels": [1, 2, 3]}}
    (tmp_path / "rec.json").write_text(json.dumps({"gyro_sigma": 0.01, **provenance}))
    (rec,) = read_recordings(path)
    assert rec.meta == {"gyro_sigma": 0.01, **provenance}
    assert read_sidecar(path) == rec.meta


def _phyphox(tmp_path, segments):
    folder = tmp_path / "Gyroscope rotation rate 1"
    (folder / "meta").mkdir(parents=True)
    t = np.arange(300) * 0.01
    lines = ['"Time (s)","Gyroscope x (rad/s)","Gyroscope y (rad/s)","Gyroscope z (rad/s)",'
             '"Absolute (rad/s)"']
    lines += [f"{x:.5E},{np.sin(x):.5E},1.0E0,0.0E0,1.0E0" for x in t]
    (folder / "Raw Data.csv").write_text("\n".join(lines) + "\n")
    (folder / "meta" / "segments.csv").write_text(segments)
    return folder


def test_phyphox_segments_kept_windows_only(tmp_path):
    folder = _phyphox(tmp_path, "segment,start,end,keep,comment\n"
                                "0,0.2,1.0,,a\n1,1.2,2.0,false,b\n2,2.1,2.9,,c\n")
    recs = read_recordings(folder)
    assert [r.meta["segment"] for r in recs] == [0, 2]
    assert recs[0].t[0] >= 0.2 and recs[0].t[-1] <= 1.0
    assert len(read_recordings(folder / "Raw Data.csv")) == 2


def test_phyphox_bad_segment(tmp_path):
    folder = _phyphox(tmp_path, "segment,start,end,keep,comment\n0,x,1.0,,a\n")
    with pytest.raises(RecordingError, match="segments.csv, row 2"):
        read_recordings(folder)


@settings(max_examples=60, deadline=None)
@given(st.text(alphabet="t,wxyz0123456789.-e\nnaif ", max_size=300))
def test_random_garbage_ends_in_recording_error(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("g") / "g.csv"
    path.write_text(text)
    try:
        (rec,) = read_recordings(path)
    except RecordingError:
        return
    assert np.all(np.isfinite(rec.w)) and np.all(np.diff(rec.t) > 0)
