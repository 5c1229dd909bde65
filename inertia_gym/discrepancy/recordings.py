"""Recordings: the project's CSV (+ sidecar JSON), phyphox exports, Parquet.

A recording holds gyro samples and, optionally, attitude, commanded torque and known internal
angular momentum (README.md, "Recording format"; docs/contracts.md). Columns (one row per gyro sample):

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
gyro_sigma, quat_sigma, simulation truth ...); keys it does not know (provenance) are kept.

Every reader validates its input and raises RecordingError naming the file, row and column;
readers never write to the input.
"""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np

from inertia_gym.errors import RecordingError

GYRO = ("wx", "wy", "wz")
QUAT = ("qw", "qx", "qy", "qz")
TORQUE = ("tau_x", "tau_y", "tau_z")
MOMENTUM = ("h_x", "h_y", "h_z")
PHYPHOX_COLUMNS = ("Time (s)", "Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)")
MAX_PLAUSIBLE_RATE = 200.0  # rad/s; larger gyro values almost surely are deg/s or mdps
MIN_SAMPLES = 10


@dataclasses.dataclass(frozen=True)
class Recording:
    """One free-flight recording.

    Attributes
    ----------
    t : (n,) s, strictly increasing.
    w : (n, 3) rad/s, body-frame gyro.
    q : (n, 4) body-to-inertial unit quaternions (scalar first), or None.
    tau : (n, 3) N·m commanded torque held from each row on, or None.
    meta : sidecar contents (inertia_nominal, gyro_sigma, quat_sigma, effect truth ...).
    name : label for reports (file name, plus the segment for phyphox windows).
    h : (n, 3) kg·m²/s known internal angular momentum relative to the body (reaction wheels,
        a rotor), body frame, sampled like the gyro and linearly interpolated between rows,
        or None. Last so that positional construction (t, w, q, tau, meta, name) still works.

    Properties: ``has_torque`` (a non-zero commanded torque), ``has_momentum`` (h present and
    not constant: only a changing h carries information on the inertia's scale),
    ``inertia_nominal`` (from the sidecar).

    """

    t: np.ndarray
    w: np.ndarray
    q: np.ndarray | None = None
    tau: np.ndarray | None = None
    meta: dict = dataclasses.field(default_factory=dict)
    name: str = "recording"
    h: np.ndarray | None = None

    @property
    def has_torque(self) -> bool:
        """True when a commanded torque is present and not identically zero."""
        return self.tau is not None and bool(np.any(self.tau != 0.0))

    @property
    def has_momentum(self) -> bool:
        """True when a known internal momentum h is present and not constant over the recording."""
        return self.h is not None and bool(np.ptp(self.h, axis=0).max() > 0)

    @property
    def inertia_nominal(self) -> np.ndarray | None:
        """(3, 3) kg·m² from the sidecar, or None."""
        value = self.meta.get("inertia_nominal")
        return None if value is None else np.asarray(value, dtype=float)


def _fail(path, message, row=None, column=None) -> RecordingError:
    where = str(path)
    if row is not None:
        where += f", row {row}"
    if column is not None:
        where += f", column {column!r}"
    return RecordingError(f"{where}: {message}")


def _check_arrays(path, t, w, q, tau, columns, first_row=2, h=None) -> None:
    """Validate finiteness, time order, length and plausible units. Row numbers are file lines."""
    if t.size < MIN_SAMPLES:
        raise _fail(path, f"only {t.size} samples; at least {MIN_SAMPLES} are needed")
    named = [("t", t[:, None], ("t",)), ("gyro", w, columns[1:4])]
    if q is not None:
        named.append(("q", q, QUAT))
    if tau is not None:
        named.append(("tau", tau, TORQUE))
    if h is not None:
        named.append(("h", h, MOMENTUM))
    for _, arr, cols in named:
        bad = ~np.isfinite(arr)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise _fail(path, "value is NaN or infinite", first_row + r, cols[c])
    dt = np.diff(t)
    if np.any(dt <= 0):
        r = int(np.argmax(dt <= 0)) + 1
        raise _fail(path, f"time does not increase ({t[r - 1]!r} then {t[r]!r})", first_row + r, columns[0])
    big = np.abs(w) > MAX_PLAUSIBLE_RATE
    if big.any():
        r, c = np.argwhere(big)[0]
        raise _fail(
            path, f"gyro value {w[r, c]!r} exceeds {MAX_PLAUSIBLE_RATE} rad/s: units look like deg/s "
            "(convert to rad/s)", first_row + r, columns[1 + c],
        )
    if q is not None:
        norm = np.linalg.norm(q, axis=1)
        bad = np.abs(norm - 1.0) > 0.2
        if bad.any():
            r = int(np.argmax(bad))
            raise _fail(path, f"quaternion norm {norm[r]:.3g} is not close to 1 (units or column order?)",
                        first_row + r, "qw")


def _read_table(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and float rows of a CSV file; errors name the row and column."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise _fail(path, f"cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise _fail(path, "not a text file") from exc
    lines = [row for row in csv.reader(text.splitlines())]
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
        raise _fail(path, f"{what}missing column(s) {missing}; the header is {header}", 1, missing[0])
    if missing:
        return None
    return np.stack([data[:, header.index(n)] for n in names], axis=1)


def read_sidecar(csv_path: Path) -> dict:
    """The JSON sidecar next to a recording (REC.json for REC.csv), or {} if absent."""
    side = Path(csv_path).with_suffix(".json")
    if not side.exists():
        return {}
    try:
        meta = json.loads(side.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise _fail(side, f"invalid JSON sidecar: {exc}") from exc
    if not isinstance(meta, dict):
        raise _fail(side, "the sidecar must be a JSON object")
    if "inertia_nominal" in meta:
        j = np.asarray(meta["inertia_nominal"], dtype=float) if _is_numeric(meta["inertia_nominal"]) else None
        if j is None or j.shape != (3, 3) or not np.all(np.isfinite(j)) or not np.allclose(j, j.T) \
                or np.linalg.eigvalsh(j).min() <= 0:
            raise _fail(side, "inertia_nominal must be a symmetric positive-definite 3x3 matrix",
                        column="inertia_nominal")
    for key in ("gyro_sigma", "quat_sigma"):
        if key in meta and not (isinstance(meta[key], (int, float)) and meta[key] > 0):
            raise _fail(side, f"{key} must be a positive number, got {meta[key]!r}", column=key)
    return meta


def _is_numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def read_csv_recording(path: str | Path) -> Recording:
    """Read the project's CSV format (README.md, "Recording format") and its sidecar."""
    path = Path(path)
    header, data = _read_table(path)
    return _from_columns(path, header, data, read_sidecar(path))


def _from_columns(path, header, data, meta) -> Recording:
    t_col = _columns(path, header, data, ("t",), True)[:, 0]
    w = _columns(path, header, data, GYRO, True)
    q = _columns(path, header, data, QUAT, False, "attitude quaternion")
    tau = _columns(path, header, data, TORQUE, False, "commanded torque")
    h = _columns(path, header, data, MOMENTUM, False, "internal angular momentum")
    _check_arrays(path, t_col, w, q, tau, ("t",) + GYRO, h=h)
    if q is not None:
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return Recording(t_col, w, q, tau, meta, path.stem, h=h)


def read_parquet_recording(path: str | Path) -> Recording:
    """Read a Parquet file with the CSV format's column names (and the same sidecar)."""
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
    return _from_columns(path, header, data, read_sidecar(path))


def _phyphox_segments(folder: Path) -> list[tuple[int, float, float]]:
    seg_path = folder / "meta" / "segments.csv"
    if not seg_path.exists():
        return []
    with seg_path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    out = []
    for i, row in enumerate(rows, start=2):
        keep = (row.get("keep") or "").strip().lower()
        if keep in ("false", "0", "no"):
            continue
        try:
            out.append((int(row["segment"]), float(row["start"]), float(row["end"])))
        except (KeyError, TypeError, ValueError):
            raise _fail(seg_path, "segment, start and end must be numbers", i) from None
    return out


def read_phyphox(path: str | Path) -> list[Recording]:
    """A phyphox export: "Raw Data.csv" (or its folder). With meta/segments.csv, each kept
    free-flight window [start, end] becomes its own recording; otherwise the whole file.
    """
    path = Path(path)
    csv_path = path / "Raw Data.csv" if path.is_dir() else path
    folder = csv_path.parent
    header, data = _read_table(csv_path)
    missing = [c for c in PHYPHOX_COLUMNS if c not in header]
    if missing:
        raise _fail(csv_path, f"missing phyphox column(s) {missing}", 1, missing[0])
    cols = [header.index(c) for c in PHYPHOX_COLUMNS]
    t, w = data[:, cols[0]], data[:, cols[1:]]
    _check_arrays(csv_path, t, w, None, None, PHYPHOX_COLUMNS)
    label = folder.name
    segments = _phyphox_segments(folder)
    if not segments:
        return [Recording(t, w, meta={"source": str(csv_path)}, name=label)]
    recs = []
    for seg, start, end in segments:
        mask = (t >= start) & (t <= end)
        if mask.sum() < MIN_SAMPLES:
            raise _fail(folder / "meta" / "segments.csv",
                        f"segment {seg} [{start}, {end}] s holds {mask.sum()} samples", column="start")
        recs.append(Recording(t[mask], w[mask], meta={"source": str(csv_path), "segment": seg,
                                                      "window": [start, end]},
                              name=f"{label} segment {seg}"))
    return recs


def read_recordings(path: str | Path) -> list[Recording]:
    """Any supported input: project CSV, Parquet, phyphox file or folder. Returns one or more."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file or folder")
    if path.is_dir():
        if (path / "Raw Data.csv").exists():
            return read_phyphox(path)
        raise RecordingError(f"{path}: a folder must be a phyphox export holding 'Raw Data.csv'")
    if path.suffix.lower() == ".parquet":
        return [read_parquet_recording(path)]
    with path.open(errors="replace") as fh:
        first = fh.readline()
    if "Gyroscope x" in first:
        return read_phyphox(path)
    return [read_csv_recording(path)]


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
    np.savetxt(path, np.hstack(cols), delimiter=",", header=",".join(names), comments="", fmt="%.10g")
    side.write_text(json.dumps(sidecar if sidecar is not None else rec.meta, indent=2) + "\n")
