"""The readers and the writer of the file formats: the project's CSV with its JSON sidecar
(read_csv_recording, read_sidecar, write_recording), Parquet (read_parquet_recording) and
phyphox exports, as a folder, a .zip or an .xlsx (read_phyphox), with the column maps and the
time and rate units they take, and the free flights found from the gyro where an export names
no windows (free_flight_windows, window_note).
"""

from __future__ import annotations

import csv
import difflib
import json
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np

from inertia_gym.errors import ConfigError, RecordingError, SidecarKeyWarning, install_hint
from inertia_gym.recording import (
    COLUMN_NAMES,
    GAP_FACTOR,
    GYRO,
    MIN_SAMPLES,
    MOMENTUM,
    QUAT,
    TORQUE,
    Recording,
)
from inertia_gym.recording_checks import _check_arrays, _fail
from inertia_gym.sensors import estimate_white_noise

PHYPHOX_COLUMNS = ("Time (s)", "Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)")
#: Free flight found from the gyro alone (free_flight_windows): the rates' local slope is a
#: least-squares line through FLIGHT_SLOPE_ROWS samples; it may exceed the torque-free bound by
#: FLIGHT_NOISE_Z times its own noise; a flight holds at least FLIGHT_MIN_ROWS samples (what
#: identify and diagnose need) and turns the body at least FLIGHT_MIN_TURN rad (half a turn).
FLIGHT_SLOPE_ROWS, FLIGHT_NOISE_Z, FLIGHT_MIN_ROWS, FLIGHT_MIN_TURN = 5, 5.0, 20, np.pi
#: Seconds per unit of the time column, and rad/s per unit of the gyro columns.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
RATE_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0}


def _apply_column_map(path, header: list[str], columns: dict | None) -> tuple[list[str], dict]:
    """The header with each mapped source column renamed to its target (columns: target ->
    source), and the labels (target -> the file's name) for messages. Unknown targets and
    sources not in the header are refused, naming them.
    """
    labels = {name: name for name in COLUMN_NAMES}
    if not columns:
        return header, labels
    unknown = [target for target in columns if target not in COLUMN_NAMES]
    if unknown:
        raise ConfigError(f"--columns: unknown column name(s) {unknown}; known: {', '.join(COLUMN_NAMES)}")
    absent = [source for source in columns.values() if source not in header]
    if absent:
        raise _fail(path, f"--columns: column(s) {absent} not in the header {header}", 1, absent[0])
    sources = list(columns.values())
    twice = sorted({s for s in sources if sources.count(s) > 1})
    if twice:
        raise ConfigError(f"--columns: column(s) {twice} mapped to more than one name")
    renamed = {source: target for target, source in columns.items()}
    # a column already carrying a mapped target's name gives way to the mapped one
    out = [renamed.get(name, f"{name} (unmapped)" if name in columns else name) for name in header]
    labels.update(columns)
    return out, labels


#: Field delimiters a CSV file may use: phyphox's five CSV exports separate by comma, tab or
#: semicolon, the last two with a decimal point or a decimal comma.
DELIMITERS = (",", "\t", ";")


def _delimiter(lines: list[str]) -> str:
    """The delimiter (DELIMITERS) of a CSV file's lines: the one that splits the header into the
    most fields, among those that split the first data line into as many (any, where none
    does); comma on a tie.
    """
    def fields(line: str, d: str) -> int:
        return len(next(csv.reader([line], delimiter=d), []))

    header = lines[0] if lines else ""
    data = next((line for line in lines[1:] if line.strip()), None)
    agree = [d for d in DELIMITERS if data is None or fields(header, d) == fields(data, d)]
    return max(agree or DELIMITERS, key=lambda d: fields(header, d))


def _read_table(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and float rows of a CSV file separated by comma, tab or semicolon (_csv_rows);
    errors name the row and column.
    """
    try:
        text = path.read_text()
    except OSError as exc:
        raise _fail(path, f"cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise _fail(path, "not a text file") from exc
    return _parse_table(text, path)


def _csv_rows(text: str) -> list[list[str]]:
    """The rows of a CSV file's text split at its delimiter (_delimiter), a byte-order mark (Excel
    writes one) dropped; where the fields are not comma separated, a decimal comma in the rows
    under the header is read as a point.
    """
    lines = text.removeprefix("\ufeff").splitlines()
    delimiter = _delimiter(lines)
    rows = list(csv.reader(lines, delimiter=delimiter))
    if delimiter == ",":
        return rows
    return rows[:1] + [[cell.replace(",", ".", 1) for cell in row] for row in rows[1:]]


def _parse_table(text: str, path) -> tuple[list[str], np.ndarray]:
    """_read_table on the text of a CSV file; path names it in errors."""
    lines = _csv_rows(text)
    if not lines or not any(cell.strip() for cell in lines[0]):
        raise _fail(path, "empty file (a header row is required)", 1)
    header = [cell.strip() for cell in lines[0]]
    rows = []
    for i, row in enumerate(lines[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise _fail(path, f"{len(row)} fields, the header has {len(header)}", i)
        values = []
        for name, cell in zip(header, row):
            try:
                values.append(float(cell))
            except ValueError:
                raise _fail(path, f"not a number: {cell!r}", i, name) from None
        rows.append(values)
    if not rows:
        raise _fail(path, "no data rows after the header", 2)
    return header, np.asarray(rows, dtype=float)


def _columns(path, header, data, names, required, label=None):
    """(n, len(names)) columns, or None when an optional group is absent; a partial group fails."""
    missing = [n for n in names if n not in header]
    if missing and (required or len(missing) < len(names)):
        what = "" if required or label is None else \
            f"{label} given in part ({', '.join(names)} go together): "
        hint = f" (map the file's names with --columns {missing[0]}=NAME,...)" if required else ""
        raise _fail(path, f"{what}missing column(s) {missing}; the header is {header}{hint}", 1, missing[0])
    if missing:
        return None
    return np.stack([data[:, header.index(n)] for n in names], axis=1)


#: The sidecar keys the tool reads, and those its own simulators write (the truth of a synthetic
#: record). Any other key is the user's provenance and passes untouched.
SIDECAR_KEYS = ("inertia_nominal", "gyro_sigma", "quat_sigma", "gyro_scale_sigma", "gyro_full_scale_rad_s",
                "gyro_bias_max", "body", "effect", "effects", "rotor", "seed", "basilisk_truth")
#: What a sidecar's ``body`` object may say the body has (true) or lacks (false): a rotor or
#: wheel, flexible appendages, liquid propellant, and air about it (false in space or vacuum).
#: diagnose names an effect that needs one of them as that physics only where the body may have it.
BODY_PARTS = ("rotor", "appendages", "propellant", "air")
#: An unknown key this similar to a known one (difflib's ratio 2M/T: one or two characters mistyped,
#: dropped or swapped in a key of ten or more) is taken for a typo of it; the provenance keys of
#: real sidecars (gyro_sigma_static, gyro_quantum_rad_s, sample_dt, ...) score under 0.75.
TYPO_SIMILARITY = 0.8


def _warn_typos(meta: dict, side: Path) -> None:
    """One SidecarKeyWarning per key of meta that is not a known key but resembles one."""
    for key in meta:
        if key in SIDECAR_KEYS:
            continue
        near = difflib.get_close_matches(str(key), SIDECAR_KEYS, n=1, cutoff=TYPO_SIMILARITY)
        if near:
            warnings.warn(f"{side}: sidecar key {key!r} is not one the tool reads; did you mean "
                          f"{near[0]!r}? The run goes on without it.", SidecarKeyWarning, stacklevel=3)


def read_sidecar(csv_path: Path) -> dict:
    """The JSON sidecar next to a recording (REC.json for REC.csv), or {} if absent. A key that
    looks like a mistyped known key gets a SidecarKeyWarning naming the key it resembles; other
    unknown keys are provenance, kept as they are.
    """
    side = Path(csv_path).with_suffix(".json")
    if not side.exists():
        return {}
    try:
        meta = json.loads(side.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise _fail(side, f"invalid JSON sidecar: {exc}") from exc
    if not isinstance(meta, dict):
        raise _fail(side, "the sidecar must be a JSON object")
    _warn_typos(meta, side)
    if "inertia_nominal" in meta:
        j = np.asarray(meta["inertia_nominal"], dtype=float) if _is_numeric(meta["inertia_nominal"]) else None
        if j is None or j.shape != (3, 3) or not np.all(np.isfinite(j)) or not np.allclose(j, j.T) \
                or np.linalg.eigvalsh(j).min() <= 0:
            raise _fail(side, "inertia_nominal must be a symmetric positive-definite 3x3 matrix",
                        column="inertia_nominal")
    for key in ("gyro_sigma", "quat_sigma", "gyro_bias_max"):
        if key in meta and not (isinstance(meta[key], (int, float)) and meta[key] > 0):
            raise _fail(side, f"{key} must be a positive number, got {meta[key]!r}", column=key)
    body = meta.get("body")
    if body is not None and not (isinstance(body, dict) and set(body) <= set(BODY_PARTS)
                                 and all(isinstance(v, bool) for v in body.values())):
        raise _fail(side, f"body must be an object whose keys are among {list(BODY_PARTS)}, each true "
                          f"(the body has it) or false (it has none), got {body!r}", column="body")
    scale = meta.get("gyro_scale_sigma")
    if scale is not None and not (isinstance(scale, (int, float)) and 0 <= scale < 1):
        raise _fail(side, f"gyro_scale_sigma (the gyro scale factor's relative 1-sigma uncertainty) must "
                          f"be a number in [0, 1), got {scale!r}", column="gyro_scale_sigma")
    return meta


def _is_numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def read_csv_recording(path: str | Path, columns: dict | None = None, time_unit: str | None = None,
                       rate_unit: str | None = None) -> Recording:
    """Read the project's CSV format (docs/recording-format.md) and its sidecar.

    columns, time_unit, rate_unit: as for read_recordings.
    """
    path = Path(path)
    header, data = _read_table(path)
    return _from_columns(path, header, data, read_sidecar(path), columns, time_unit, rate_unit)


def _unit_factor(option: str, unit: str | None, units: dict) -> float:
    if unit is None:
        return 1.0
    if unit not in units:
        raise ConfigError(f"{option}: unknown unit {unit!r}; known: {', '.join(units)}")
    return units[unit]


def _from_columns(path, header, data, meta, columns=None, time_unit=None, rate_unit=None) -> Recording:
    header, labels = _apply_column_map(path, header, columns)
    seconds = _unit_factor("--time-unit", time_unit, TIME_UNITS)
    t_col = _columns(path, header, data, ("t",), True)[:, 0] * seconds
    w = _columns(path, header, data, GYRO, True) * _unit_factor("--rate-unit", rate_unit, RATE_UNITS)
    q = _columns(path, header, data, QUAT, False, "attitude quaternion")
    tau = _columns(path, header, data, TORQUE, False, "commanded torque")
    h = _columns(path, header, data, MOMENTUM, False, "internal angular momentum")
    _check_arrays(path, t_col, w, q, tau, labels, h=h, time_unit=time_unit, rate_unit=rate_unit)
    if q is not None:
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return Recording(t_col, w, q, tau, meta, path.stem, h=h)


def read_parquet_recording(path: str | Path, columns: dict | None = None, time_unit: str | None = None,
                           rate_unit: str | None = None) -> Recording:
    """Read a Parquet file with the CSV format's column names (and the same sidecar).

    columns, time_unit, rate_unit: as for read_recordings.
    """
    import pyarrow.parquet as pq

    path = Path(path)
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises several unrelated types for a bad file
        raise _fail(path, f"cannot read as Parquet: {exc}") from exc
    header = list(table.column_names)
    if table.num_rows == 0:
        raise _fail(path, "no data rows", 2)
    try:
        data = np.stack([np.asarray(table[c].to_numpy(), dtype=float) for c in header], axis=1)
    except (TypeError, ValueError) as exc:
        raise _fail(path, f"non-numeric column: {exc}") from exc
    return _from_columns(path, header, data, read_sidecar(path), columns, time_unit, rate_unit)


def _phyphox_segments(text: str | None, seg_path) -> list[tuple[int, float, float]] | None:
    """(segment, start, end) of each kept window of an export's meta/segments.csv, given its
    text (None: the export has no such file, and neither has the result); seg_path names it.
    Columns start and end (s, the export's clock) are required; segment (a number; else the
    row's place from 0) and keep (false, 0 or no leave the row out) are optional; names are
    read without regard to case or surrounding spaces.
    """
    if text is None:
        return None
    table = [row for row in _csv_rows(text) if any(cell.strip() for cell in row)]
    header = table[0] if table else []
    names = [name.strip().lower() for name in header]
    if "start" not in names or "end" not in names:
        raise _fail(seg_path, f"needs columns start and end (s); the header is {header}", 1)
    rows = [dict(zip(names, (cell.strip() for cell in row))) for row in table[1:]]
    out = []
    for i, row in enumerate(rows, start=2):
        if row.get("keep", "").lower() in ("false", "0", "no"):
            continue
        try:
            out.append((int(row["segment"]) if row.get("segment") else i - 2, float(row["start"]),
                        float(row["end"])))
        except (KeyError, TypeError, ValueError):
            raise _fail(seg_path, "segment, start and end must be numbers", i) from None
    if not out:
        why = f"{len(rows)} row(s), each with keep false" if rows else "no row under its header"
        raise _fail(seg_path, f"keeps no segment ({why}): nothing to read; keep one, or remove the "
                    "file to have the free flights found")
    return out


def free_flight_windows(t, w) -> list[tuple[int, int]] | None:
    """Rows [start, stop) of each free flight in gyro rows w (n, 3) rad/s at times t (n,) s,
    found from the gyro alone (a phone's export of tosses between which a hand holds it);
    None where no row breaks the torque-free bound (the whole record may be one flight).

    Torque-free, a rigid body's principal rates obey I_i w_i' = (I_j - I_k) w_j w_k, and every
    body's moments satisfy |I_j - I_k| <= I_i, so |w'|^2 <= sum w_j^2 w_k^2 <= |w|^4 / 3 in
    any body frame: the rates cannot change faster than |w|^2 / sqrt(3) (a free body moves no
    faster than it spins). A hand holding, throwing or catching the body breaks the bound. A row
    passes where the rates' local slope (a least-squares line through FLIGHT_SLOPE_ROWS samples)
    is within the bound plus FLIGHT_NOISE_Z times the slope's noise (the white-noise level of
    the record, sensors.estimate_white_noise). A flight is a run of passing rows, less the
    slope's half-width at each end (the rows an impulse there reaches), of at least
    FLIGHT_MIN_ROWS rows, turning the body at least FLIGHT_MIN_TURN rad, where the bound exceeds
    the noise allowance on most rows (a body at rest or turned slowly in the hand passes on noise
    alone), and across no dropout (an interval over GAP_FACTOR times the median: phyphox paused,
    say, while the hand moved the body): [] where the bound is broken or a dropout falls and no
    span qualifies; None also for fewer than FLIGHT_SLOPE_ROWS rows. Free of units: the same
    motion run k times faster (t / k, w k, its noise k) gives the same rows.
    """
    t, w = np.asarray(t, float), np.asarray(w, float)
    half = FLIGHT_SLOPE_ROWS // 2
    if t.size < FLIGHT_SLOPE_ROWS:
        return None
    times = np.lib.stride_tricks.sliding_window_view(t, FLIGHT_SLOPE_ROWS)
    times = times - times.mean(axis=1, keepdims=True)
    spread = np.sum(times ** 2, axis=1)  # (n - 2 half,) s^2
    rates = np.lib.stride_tricks.sliding_window_view(w, FLIGHT_SLOPE_ROWS, axis=0)  # (m, 3, rows)
    slope = np.linalg.norm(np.einsum("kir,kr->ki", rates, times), axis=1) / spread
    speed2 = np.sum(w[half:t.size - half] ** 2, axis=1)
    bound = speed2 / np.sqrt(3.0)
    allowance = FLIGHT_NOISE_Z * np.linalg.norm(estimate_white_noise(w)) / np.sqrt(spread)
    steps = np.diff(t)
    gap = np.r_[steps > GAP_FACTOR * np.median(steps), False]  # a dropout after the row
    across = np.lib.stride_tricks.sliding_window_view(gap, FLIGHT_SLOPE_ROWS)[:, :-1].any(axis=1)
    passed = (slope <= bound + allowance) & ~across  # no flight runs across a dropout
    if passed.all():
        return None
    edges = np.flatnonzero(np.diff(np.r_[0, passed.astype(np.int8), 0]))
    flights = []
    for a, b in zip(edges[::2] + 2 * half, edges[1::2]):  # rows of the run, less half at each end
        if b - a < FLIGHT_MIN_ROWS:
            continue
        turn = np.sum(np.sqrt(np.sum(w[a:b] ** 2, axis=1))[:-1] * np.diff(t[a:b]))
        spins = bound[a - half:b - half] > allowance[a - half:b - half]  # beyond the noise's allowance
        if turn >= FLIGHT_MIN_TURN and spins.mean() > 0.5:
            flights.append((int(a), int(b)))
    return flights


def read_phyphox(path: str | Path, columns: dict | None = None, time_unit: str | None = None,
                 rate_unit: str | None = None) -> list[Recording]:
    """A phyphox export: its folder or "Raw Data.csv", the .zip its CSV export writes (the same
    files) or the .xlsx its Excel export writes (sheet "Raw Data"; optional dependency openpyxl).
    With meta/segments.csv (not written by phyphox: a user's own), each kept free-flight window
    [start, end] becomes its own recording (meta "window", "window_source":
    "meta/segments.csv"). Without it, each free flight the gyro shows (free_flight_windows)
    does, named "NAME flight K" (meta "window_source": WINDOW_FOUND); the whole file is one
    recording where no row breaks the torque-free bound, or, said in its meta (WINDOW_NONE_FOUND),
    where no flight is found. columns (t, wx, wy, wz only) replace phyphox's own names; units as
    for read_recordings.
    """
    path = Path(path)
    if path.suffix.lower() == ".zip":
        label, source, seg_path = path.stem, path, f"{path}: meta/segments.csv"
        (header, data), segments = _zipped_export(path)
    elif path.suffix.lower() == ".xlsx":
        label, source, seg_path = path.stem, path, None
        (header, data), segments = _xlsx_table(path), None
    else:
        source = path / "Raw Data.csv" if path.is_dir() else path
        label, seg_path = source.parent.name, source.parent / "meta" / "segments.csv"
        header, data = _read_table(source)
        segments = _phyphox_segments(seg_path.read_text() if seg_path.exists() else None, seg_path)
    mapping = dict(zip(("t",) + GYRO, PHYPHOX_COLUMNS)) | dict(columns or {})
    missing = [name for target, name in mapping.items()
               if name not in header and target not in (columns or {})]
    if missing:
        raise _fail(source, f"missing phyphox column(s) {missing}", 1, missing[0])
    rec = _from_columns(source, header, data, {"source": str(source)}, mapping, time_unit, rate_unit)
    t, w = rec.t, rec.w
    if segments is None:
        flights = free_flight_windows(t, w)
        if flights is None:
            return [Recording(t, w, meta=rec.meta, name=label)]
        if not flights:  # the gyro shows torques and no free flight: the whole file, said so
            return [Recording(t, w, name=label, meta={**rec.meta, "window": [float(t[0]), float(t[-1])],
                                                       "window_source": WINDOW_NONE_FOUND})]
        return [Recording(t[a:b], w[a:b], name=f"{label} flight {k}", meta={
            "source": str(source), "flight": k, "window": [float(t[a]), float(t[b - 1])],
            "window_source": WINDOW_FOUND}) for k, (a, b) in enumerate(flights, start=1)]
    recs = []
    for seg, start, end in segments:
        mask = (t >= start) & (t <= end)
        if mask.sum() < MIN_SAMPLES:
            raise _fail(seg_path, f"segment {seg} [{start}, {end}] s holds {mask.sum()} samples",
                        column="start")
        recs.append(Recording(t[mask], w[mask], meta={"source": str(source), "segment": seg,
                                                      "window": [start, end],
                                                      "window_source": "meta/segments.csv"},
                              name=f"{label} segment {seg}"))
    return recs


def _zipped_export(path: Path) -> tuple[tuple[list[str], np.ndarray], list | None]:
    """(header, rows) of the "Raw Data.csv" in a zipped phyphox export, and the kept windows of
    its meta/segments.csv (None without one): the files at the archive's top or in one folder.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            members = archive.namelist()
            names = [n for n in members if n.rsplit("/", 1)[-1] == "Raw Data.csv"]
            if len(names) != 1:
                raise _fail(path, f"a phyphox export holds one 'Raw Data.csv'; this archive holds "
                            f"{len(names)}")
            seg_name = names[0][: -len("Raw Data.csv")] + "meta/segments.csv"
            astray = [n for n in members if n.endswith("segments.csv") and n != seg_name]
            if astray:
                raise _fail(path, f"{astray[0]} is not beside {names[0]} (expected {seg_name})")
            table = _parse_table(_text(archive.read(names[0]), path, names[0]), f"{path}: {names[0]}")
            text = _text(archive.read(seg_name), path, seg_name) if seg_name in members else None
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, RuntimeError, NotImplementedError) as exc:
        raise _fail(path, f"cannot read as a zipped phyphox export: {exc}") from exc
    return table, _phyphox_segments(text, f"{path}: {seg_name}")


def _text(data: bytes, path: Path, member: str) -> str:
    """A zip member's bytes as text (UTF-8, a byte-order mark dropped)."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise _fail(path, f"{member} is not a text file") from None


#: The sheet of a phyphox Excel export that holds the gyro (its "Raw Data" set).
PHYPHOX_SHEET = "Raw Data"


def _xlsx_table(path: Path) -> tuple[list[str], np.ndarray]:
    """(header, rows) of the "Raw Data" sheet of a phyphox Excel export (openpyxl reads it):
    the columns under a header cell; an empty or non-numeric cell is refused, naming its row
    and column.
    """
    try:
        import openpyxl
    except ImportError:
        raise _fail(path, f"reading a phyphox Excel export needs openpyxl: {install_hint('xlsx')} "
                    "(or export CSV from phyphox)") from None
    try:
        book = openpyxl.load_workbook(path, read_only=True, data_only=True)
        try:
            if PHYPHOX_SHEET not in book.sheetnames:
                raise _fail(path, f"no sheet {PHYPHOX_SHEET!r} (the sheets are {book.sheetnames}): "
                            "not a phyphox gyro export")
            rows = list(book[PHYPHOX_SHEET].iter_rows(values_only=True))
        finally:
            book.close()
    except RecordingError:
        raise
    except Exception as exc:  # openpyxl raises several unrelated types for a bad file
        raise _fail(path, f"cannot read as an Excel workbook: {exc}") from exc
    named = [i for i, cell in enumerate(rows[0] if rows else ()) if cell is not None and str(cell).strip()]
    if not named:
        raise _fail(path, f"sheet {PHYPHOX_SHEET!r} is empty (a header row is required)", 1)
    header = [str(rows[0][i]).strip() for i in named]
    data = []
    for r, row in enumerate(rows[1:], start=2):
        cells = [row[i] if i < len(row) else None for i in named]
        if all(cell is None for cell in cells):
            continue
        for name, cell in zip(header, cells):
            if not isinstance(cell, (int, float)) or isinstance(cell, bool):
                raise _fail(path, "an empty cell" if cell is None else f"not a number: {cell!r}", r, name)
        data.append([float(cell) for cell in cells])
    if not data:
        raise _fail(path, "no data rows after the header", 2)
    return header, np.asarray(data, dtype=float)


#: meta["window_source"] of a free flight read_phyphox found from the gyro, and of an export
#: without meta/segments.csv where it found none.
WINDOW_FOUND = "found from the gyro (the export has no meta/segments.csv)"
WINDOW_NONE_FOUND = ("the whole export: it has no meta/segments.csv, and the gyro shows no free flight "
                     f"(the rates break the torque-free bound, and no span within it holds "
                     f"{FLIGHT_MIN_ROWS} samples turning half a turn)")


def window_note(start: float, end: float, source: str) -> str | None:
    """A sentence on the window from start to end (s) of a phyphox export without
    meta/segments.csv (source: WINDOW_FOUND or WINDOW_NONE_FOUND); None for any other source.
    """
    how = "write meta/segments.csv (segment,start,end) to choose the windows yourself"
    if source == WINDOW_NONE_FOUND:
        return f"{source}: its free flights, if any, were not found; {how}"
    if source != WINDOW_FOUND:
        return None
    return (f"free flight from t = {start:.6g} to {end:.6g} s, found from the gyro: the export has no "
            "meta/segments.csv, and there the rates stay within what a free body's own motion "
            f"allows (|dw/dt| <= |w|^2/sqrt(3)); {how}")


def write_recording(path: str | Path, rec: Recording, sidecar: dict | None = None) -> None:
    """Write rec as the project's CSV (and REC.json). Refuses to overwrite an existing file.

    Optional column groups (q, tau, h) are written when present; sidecar defaults to rec.meta.
    """
    path = Path(path)
    side = path.with_suffix(".json")
    for target in (path, side):
        if target.exists():
            raise RecordingError(f"{target}: exists; refusing to overwrite (choose another --out)")
    cols = [rec.t[:, None], rec.w]
    names = ["t", *GYRO]
    if rec.q is not None:
        cols.append(rec.q)
        names += QUAT
    if rec.tau is not None:
        cols.append(rec.tau)
        names += TORQUE
    if rec.h is not None:
        cols.append(rec.h)
        names += MOMENTUM
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = ["%.17g"] + ["%.10g"] * (len(names) - 1)  # time in full: a clock of 1.7e9 s keeps its ms
    np.savetxt(path, np.hstack(cols), delimiter=",", header=",".join(names), comments="", fmt=fmt)
    side.write_text(json.dumps(sidecar if sidecar is not None else rec.meta, indent=2) + "\n")
