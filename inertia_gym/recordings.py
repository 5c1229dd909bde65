"""Recordings: the project's CSV (+ sidecar JSON), Parquet, phyphox exports (folder, .zip, .xlsx).

A recording holds gyro samples and, optionally, attitude, commanded torque and known internal
angular momentum (docs/recording-format.md; docs/contracts.md). Columns (one row per gyro sample):

    t                    s, strictly increasing (required)
    wx, wy, wz           rad/s, body-frame gyro (required)
    qw, qx, qy, qz       body-to-inertial unit quaternion, scalar first (optional, all four)
    tau_x, tau_y, tau_z  N·m, commanded body-frame torque held from each row on (optional, all three)
    h_x, h_y, h_z        kg·m²/s, known internal angular momentum relative to the body (reaction
                         wheels, a rotor), body frame, linearly interpolated between rows
                         (optional, all three)

The body then obeys J w_dot + h_dot + w x (J w + h) = tau: a known, changing h fixes the
inertia's scale just as a known torque does. An optional group given in part (h_x, h_y without
h_z) is refused. The JSON sidecar REC.json next to REC.csv holds metadata (inertia_nominal,
gyro_sigma, quat_sigma, gyro_scale_sigma, simulation truth ...); keys it does not know
(provenance) are kept.

Every reader validates its input and raises RecordingError naming the file, row and column;
readers never write to the input. Columns named otherwise are mapped with ``columns`` (target ->
source, e.g. {"t": "time", "wx": "gx"}); units that are evidently not s and rad/s are refused
(check_units; the rule is in docs/recording-format.md) unless stated with ``time_unit`` /
``rate_unit``, which also converts them.

Gaps: where a commanded torque or a changing internal momentum is logged, a row interval over
GAP_FACTOR times the median one is a dropout, across which what the inputs did is unknown (the
format would hold the torque and interpolate h). read_recordings splits such a recording at its
gaps (split_at_gaps): each piece is a recording of its own; identify and diagnose refuse an
unsplit one (check_input_gaps). A torque-free gap is kept: the motion across it is determined.

The modules: recording.py (Recording, the format's column names, gaps and the regular clock),
recording_checks.py (the checks of a read table: values, units, total turn, attitude frame) and
recording_io.py (the readers and the writer of each file format, and the free flights found
from the gyro). This module reads any input (read_recordings) and gathers their public names:
the package, the commands, the scripts and the tests import them from here.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from inertia_gym.errors import RecordingError
from inertia_gym.recording import (
    CLOCK_KEEP_STAMPS_Z,
    CLOCK_OFFSET_MAX,
    CLOCK_SCATTER_MIN,
    COLUMN_NAMES,
    CUBIC_NODES,
    GAP_FACTOR,
    GYRO,
    MIN_SAMPLES,
    MOMENTUM,
    QUAT,
    TORQUE,
    Recording,
    check_input_gaps,
    input_gaps,
    interpolation_residual,
    regular_clock,
    retimed,
    retimed_note,
    split_at_gaps,
)
from inertia_gym.recording_checks import (
    ATTITUDE_AGREEMENT,
    ATTITUDE_RATIO_BOUNDS,
    ATTITUDE_READINGS,
    MAX_MAGNITUDE,
    MAX_PLAUSIBLE_RATE,
    MAX_TOTAL_TURN,
    MAX_TURN_PER_SAMPLE,
    MIN_RATE_CHANGE_PER_RADIAN,
    TYPICAL_TURN_PER_SAMPLE,
    UNIT_SUSPECTS,
    check_attitude_frame,
    check_total_turn,
    check_units,
)
from inertia_gym.recording_io import (
    BODY_PARTS,
    DELIMITERS,
    FLIGHT_MIN_ROWS,
    FLIGHT_MIN_TURN,
    FLIGHT_NOISE_Z,
    FLIGHT_SLOPE_ROWS,
    PHYPHOX_COLUMNS,
    PHYPHOX_SHEET,
    RATE_UNITS,
    SIDECAR_KEYS,
    TIME_UNITS,
    TYPO_SIMILARITY,
    WINDOW_FOUND,
    WINDOW_NONE_FOUND,
    free_flight_windows,
    read_csv_recording,
    read_parquet_recording,
    read_phyphox,
    read_sidecar,
    window_note,
    write_recording,
)


def read_recordings(path: str | Path, columns: dict | None = None, time_unit: str | None = None,
                    rate_unit: str | None = None) -> list[Recording]:
    """Any supported input: project CSV, Parquet, a phyphox export (its folder or "Raw Data.csv",
    or the .zip or .xlsx phyphox writes), or a folder holding recordings at any depth
    (recording_sources: phyphox export folders, project CSV and Parquet files, each then named
    by its path below that folder, e.g. "round1/Gyroscope rotation rate ... segment 0" or
    "throws/LOG00186"). Returns one or more.

    columns: {format name: the file's column name}, e.g. {"t": "time", "wx": "gx"}: format names
        as in COLUMN_NAMES; an unknown one, or a file column not in the header, is refused.
    time_unit: "s", "ms" or "us"; rate_unit: "rad/s" or "deg/s". None (default): seconds and
        rad/s, refused when evidently otherwise (check_units). Stated: converted and trusted.
    A recording whose logged torque or momentum has gaps comes as its pieces (split_at_gaps).
    """
    path = Path(path)
    if not path.is_dir() or (path / "Raw Data.csv").exists():
        return read_source(path, None, columns, time_unit, rate_unit)
    return [rec for name, source in recording_sources(path)
            for rec in read_source(source, name, columns, time_unit, rate_unit)]


#: Suffixes of the recording files a folder is searched for: the project's CSV and Parquet (a
#: phyphox .zip or .xlsx is read when given itself: in a data folder such files are as often an
#: export's copy beside it unzipped, or a spreadsheet of results).
RECORDING_SUFFIXES = (".csv", ".parquet")


def recording_sources(folder: str | Path) -> list[tuple[str, Path]]:
    """(name, path) of every recording a folder holds at any depth, sorted: each phyphox export
    (a folder holding 'Raw Data.csv'; its own meta/ files are not recordings) and each file
    outside the exports with a suffix of RECORDING_SUFFIXES (project CSV or Parquet), named by
    its path below folder (a file without its suffix, but with it where another source would
    have the same name: X.csv beside X.parquet or beside the export X/). RecordingError where
    it holds none.
    """
    folder = Path(folder)
    exports = sorted(raw.parent for raw in folder.rglob("Raw Data.csv"))
    files = sorted(f for f in folder.rglob("*") if f.is_file() and f.suffix.lower() in RECORDING_SUFFIXES
                   and not any(export in f.parents for export in exports))
    sources = [(export.relative_to(folder).as_posix(), export) for export in exports]
    exported = {name for name, _ in sources}
    for f in files:  # a file named as an export or another file (X.csv beside X/) keeps its suffix
        name = f.relative_to(folder).with_suffix("").as_posix()
        clash = name in exported or sum(g.with_suffix("") == f.with_suffix("") for g in files) > 1
        sources.append((f.relative_to(folder).as_posix() if clash else name, f))
    if not sources:
        raise RecordingError(f"{folder}: a folder must be a phyphox export holding 'Raw Data.csv', or hold "
                             "such exports or recordings (.csv, .parquet) at any depth")
    return sorted(sources)


def read_source(path: str | Path, name: str | None = None, columns: dict | None = None,
                time_unit: str | None = None, rate_unit: str | None = None) -> list[Recording]:
    """The recordings of one file or phyphox export (read_recordings' options), named name (and
    the segment or piece, if any) in place of the reader's own name where name is given.
    """
    label, recs = _read_any(Path(path), dict(columns=columns, time_unit=time_unit, rate_unit=rate_unit))
    return [piece if name is None else dataclasses.replace(piece, name=name + piece.name[len(label):])
            for rec in recs for piece in split_at_gaps(rec)]


def _read_any(path: Path, units: dict) -> tuple[str, list[Recording]]:
    """(the reader's name of the recording, its recordings) of one file or phyphox export."""
    if not path.exists():
        raise RecordingError(f"{path}: no such file or folder")
    if path.is_dir():
        return path.name, read_phyphox(path, **units)
    if path.suffix.lower() == ".parquet":
        return path.stem, [read_parquet_recording(path, **units)]
    if path.suffix.lower() in (".zip", ".xlsx"):
        return path.stem, read_phyphox(path, **units)
    with path.open(errors="replace") as fh:
        first = fh.readline()
    if "Gyroscope x" in first:
        return path.parent.name, read_phyphox(path, **units)
    return path.stem, [read_csv_recording(path, **units)]


__all__ = [
    "ATTITUDE_AGREEMENT",
    "ATTITUDE_RATIO_BOUNDS",
    "ATTITUDE_READINGS",
    "BODY_PARTS",
    "CLOCK_KEEP_STAMPS_Z",
    "CLOCK_OFFSET_MAX",
    "CLOCK_SCATTER_MIN",
    "COLUMN_NAMES",
    "CUBIC_NODES",
    "DELIMITERS",
    "FLIGHT_MIN_ROWS",
    "FLIGHT_MIN_TURN",
    "FLIGHT_NOISE_Z",
    "FLIGHT_SLOPE_ROWS",
    "GAP_FACTOR",
    "GYRO",
    "MAX_MAGNITUDE",
    "MAX_PLAUSIBLE_RATE",
    "MAX_TOTAL_TURN",
    "MAX_TURN_PER_SAMPLE",
    "MIN_RATE_CHANGE_PER_RADIAN",
    "MIN_SAMPLES",
    "MOMENTUM",
    "PHYPHOX_COLUMNS",
    "PHYPHOX_SHEET",
    "QUAT",
    "RATE_UNITS",
    "RECORDING_SUFFIXES",
    "Recording",
    "SIDECAR_KEYS",
    "TIME_UNITS",
    "TORQUE",
    "TYPICAL_TURN_PER_SAMPLE",
    "TYPO_SIMILARITY",
    "UNIT_SUSPECTS",
    "WINDOW_FOUND",
    "WINDOW_NONE_FOUND",
    "check_attitude_frame",
    "check_input_gaps",
    "check_total_turn",
    "check_units",
    "free_flight_windows",
    "input_gaps",
    "interpolation_residual",
    "read_csv_recording",
    "read_parquet_recording",
    "read_phyphox",
    "read_recordings",
    "read_sidecar",
    "read_source",
    "recording_sources",
    "regular_clock",
    "retimed",
    "retimed_note",
    "split_at_gaps",
    "window_note",
    "write_recording",
]
