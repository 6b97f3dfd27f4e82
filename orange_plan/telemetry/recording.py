"""Recordings: the telemetry table of the recording format (docs/formats.md), loaded, checked, cleaned and completed.

(The time-series maths of rule 13 is ``telemetry.derive``; a recording's MotionState is
``telemetry.state.recording_state``.)

A recording is one row per sample with ``t_s`` and the battery power (``power_W``, or
``voltage_V`` and ``current_A``) and the motion (``x_m``/``y_m`` or ``v_mps``). Loading
applies the rules below, in this order. Every rule that changes or drops something is
reported as a :class:`DataIssue` (kind, count, first row, rule text): nothing is silent.
Row numbers are 0-based positions in the input table (CSV line = row + 2).

Rules
-----
1. ``file``: ``.csv`` / ``.csv.gz`` or ``.parquet`` / ``.pq``; anything else, an empty file
   or a table without data rows is refused (RecordingError).
2. ``missing_column``: ``t_s``; ``power_W`` or both ``voltage_V`` and ``current_A``;
   ``x_m`` and ``y_m``, or ``v_mps``. A missing one is refused, naming it.
3. ``text``: a value that is not a number in a numeric column of the recording format (docs/formats.md) is refused, naming
   the column, the first bad row and the value (empty cells are missing values, not text).
3b. ``physical_range``: an infinite value in any numeric column of the recording format (docs/formats.md), or a finite one
   outside that column's physical range (``PHYSICAL_RANGES``, table below), is refused with
   one line naming the column, the value, its first row and the allowed range: no sensor
   reads it, so the file is corrupt or in other units, and a value like 1e308 would only
   turn energies into inf or NaN downstream. Missing values (empty cells, NaN) are not
   checked here: rules 5 and 9 handle them. A derived ``power_W`` (voltage x current) is
   held to the same range. The ranges are deliberately generous, so that no real robot,
   vehicle or aircraft is refused:

   ==================  ===================  ===============================================
   column              allowed              why that is generous
   ==================  ===================  ===============================================
   power_W             [-1e7, 1e7] W        10 MW; an electric truck peaks near 1 MW, a
                                            field robot below 10 kW (negative: charging)
   voltage_V           [-2000, 2000] V      2 kV; traction packs are 400-900 V (either sign:
                                            a log's sign convention is not judged here)
   current_A           [-1e4, 1e4] A        10 kA; EVs peak at 1-2 kA
   v_mps               [-150, 150] m/s      540 km/h; negative is reversing (rule 11)
   accel_mps2          [-1e4, 1e4] m/s^2    1000 g; accelerometers saturate at 16-200 g
   yaw_rate_radps      [-100, 100] rad/s    16 turns/s; gyros saturate at 35-70 rad/s
   x_m, y_m            [-1e8, 1e8] m        2.5 x Earth's circumference
   z_m                 [-1.2e4, 1e5] m      the Mariana Trench to the edge of space
   ambient_C,          [-90, 150] C         record cold -89 C; a battery or a desert surface
   battery_C                                stays below 100 C
   soc                 [0, 1]               the documented fraction (a percent is refused with a
                                            hint to divide by 100)
   wind_mps            [-150, 150] m/s      record gust 113 m/s (either sign tolerated)
   wind_from_deg       [-3600, 3600] deg    any finite direction: it wraps, ten turns at most
   payload_kg          [-1e6, 1e6] kg       1000 t; a heavy truck carries 40 t (negative:
                                            lighter than the scenario's mass, as the
                                            simulator writes a dropped load)
   sensor_rate_Hz      [0, 1e6] Hz          1 MHz; lidars and cameras run below 100 kHz
   ==================  ===================  ===============================================

4. ``timestamps``: an infinite ``t_s``, ``|t_s| > 1e12`` (epoch milli/nanoseconds) or a span
   of more than 1e7 s (116 days) is refused with a hint to convert to seconds. Epoch
   *seconds* (first stamp beyond 1e7 s) are shifted so the first sample is at 0 s
   (``rebased``).
5. ``missing_value``: a row with a missing value (empty cell, NaN) in a needed column
   (``t_s``, the power columns used, the motion columns used) is dropped (an infinite value
   is refused by rule 3b).
6. ``backwards``: a row stamped earlier than the latest earlier row is dropped (running
   maximum; after a clock reset the rows are dropped until time catches up).
7. ``duplicate``: a row with the same stamp as the latest earlier row is dropped (the first
   of equal stamps is kept).
8. ``too_short``: fewer than 2 rows left is refused.
9. ``optional_missing``: missing values in an optional numeric column are filled by linear
   interpolation in time (held constant before the first and after the last known value);
   a column with no value at all is removed.
10. ``gap``: an interval longer than ``5 x`` the median interval is a gap. Gaps are kept but
    never bridged: integrals (energy, distance) skip the gap interval, so energy over a gap
    is neither recorded nor predicted (both sides of a comparison skip the same intervals),
    while ``duration_s`` is the full span. Smoothing and derivatives work per gap-free piece.
11. ``reverse``: a negative ``v_mps`` (driving backwards) is replaced by its magnitude, the
    ground speed.
12. ``import``: what an importer had to decide (e.g. a fallback channel), passed in
    ``frame.attrs["import_notes"]``, is reported as it is.
13. Derived channels (``derived``, reported with the rows they fill):
    ``power_W = voltage_V * current_A``; positions -> speed: centred moving average of
    ``x_m``/``y_m`` over ``derive.SMOOTH_WINDOW_S`` = 0.5 s (counted in samples at the median
    interval: at least 3, odd; ends padded by point reflection so a steady trend passes
    unchanged), then central differences (``numpy.gradient`` on the time stamps); yaw rate:
    heading ``atan2(dy, dx)`` of the smoothed positions, unwrapped, held while the horizontal
    speed (or ``v_mps``) is below ``derive.STILL_SPEED_MPS`` (a climb on the spot has no
    heading), central differences; acceleration: central differences of the speed after the
    same moving average. Without positions
    and without ``yaw_rate_radps`` the yaw rate is 0 (reported).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from orange_plan.atomic import atomic_path
from orange_plan.errors import RecordingError
from orange_plan.files import csv_delimiter_hint, require_file
from orange_plan.telemetry.derive import (
    STILL_SPEED_MPS,
    derivative,
    duration_s,
    gap_free_pieces,
    position_yaw_rate_radps,
    smooth_pieces,
    window_samples,
)

SPEC_COLUMNS = (
    "t_s", "power_W", "voltage_V", "current_A", "x_m", "y_m", "z_m", "v_mps",
    "yaw_rate_radps", "accel_mps2", "soc", "ambient_C", "battery_C", "wind_mps",
    "wind_from_deg", "payload_kg", "surface", "sensor_rate_Hz",
)
"""recording columns (docs/formats.md) in their documented order."""

TEXT_COLUMNS = ("surface",)
NUMERIC_COLUMNS = tuple(c for c in SPEC_COLUMNS if c not in TEXT_COLUMNS)

MAX_ABS_TIME_S = 1e12
"""Beyond this a stamp is epoch milli- or nanoseconds, not seconds [s]."""
MAX_SPAN_S = 1e7
"""Longest accepted recording (about 116 days) [s]."""
REBASE_T0_S = 1e7
"""A first stamp beyond this is taken as epoch seconds and shifted to 0 [s]."""
GAP_FACTOR = 5.0
"""An interval longer than this times the median interval is a gap [-]."""

READ_EXTENSIONS = (".csv", ".csv.gz", ".parquet", ".pq")

PHYSICAL_RANGES = {
    "power_W": (-1e7, 1e7, "W"),
    "voltage_V": (-2e3, 2e3, "V"),
    "current_A": (-1e4, 1e4, "A"),
    "v_mps": (-150.0, 150.0, "m/s"),
    "accel_mps2": (-1e4, 1e4, "m/s^2"),
    "yaw_rate_radps": (-100.0, 100.0, "rad/s"),
    "x_m": (-1e8, 1e8, "m"),
    "y_m": (-1e8, 1e8, "m"),
    "z_m": (-1.2e4, 1e5, "m"),
    "ambient_C": (-90.0, 150.0, "C"),
    "battery_C": (-90.0, 150.0, "C"),
    "soc": (0.0, 1.0, "(fraction)"),
    "wind_mps": (-150.0, 150.0, "m/s"),
    "wind_from_deg": (-3600.0, 3600.0, "deg"),
    "payload_kg": (-1e6, 1e6, "kg"),
    "sensor_rate_Hz": (0.0, 1e6, "Hz"),
}
"""Physical range (low, high, unit) of each numeric the recording format (docs/formats.md) column but ``t_s`` (rule 4):
rule 3b's table, with why each is generous."""


@dataclass(frozen=True)
class DataIssue:
    """One validation finding and the rule applied to it.

    Attributes
    ----------
    kind : rule id (``missing_value``, ``backwards``, ``duplicate``, ``gap``, ``derived``...)
    count : number of rows (or intervals, for gaps) concerned
    first_row : 0-based position of the first one in the input table (-1: whole column)
    rule : what was done, one sentence
    """

    kind: str
    count: int
    first_row: int
    rule: str

    def __str__(self) -> str:
        where = f", first at row {self.first_row}" if self.first_row >= 0 else ""
        unit = "interval(s)" if self.kind == "gap" else "row(s)"
        return f"{self.kind}: {self.count} {unit}{where}: {self.rule}"

    def to_dict(self) -> dict:
        return {"kind": self.kind, "count": self.count, "first_row": self.first_row,
                "rule": self.rule}


@dataclass(frozen=True, eq=False)  # eq=False: comparing DataFrames with == is ambiguous
class Recording:
    """A cleaned, time-ordered recording (recording columns (docs/formats.md) plus derived channels).

    Attributes
    ----------
    frame : the table; always ``t_s`` [s], ``power_W`` [W], ``v_mps`` [m/s],
        ``yaw_rate_radps`` [rad/s], ``accel_mps2`` [m/s^2]; ``x_m``, ``y_m``, ``z_m`` [m]
        when recorded; other columns kept
    source : where it came from (a path or a label)
    issues : what validation found and which rule was applied
    gap_threshold_s : intervals longer than this are gaps, skipped by integrals [s]
    """

    frame: pd.DataFrame
    source: str
    issues: tuple[DataIssue, ...] = ()
    gap_threshold_s: float = float("inf")

    @property
    def t_s(self) -> np.ndarray:
        """Sample times [s]."""
        return self.frame["t_s"].to_numpy(float)

    @property
    def interval_ok(self) -> np.ndarray:
        """True for each interval between consecutive samples that is not a gap (n-1,)."""
        return np.diff(self.t_s) <= self.gap_threshold_s

    @property
    def duration_s(self) -> float:
        """Span from the first to the last sample, gaps included [s]."""
        return duration_s(self.t_s)

    @property
    def energy_J(self) -> float:
        """Recorded battery energy: trapezoid of ``power_W`` over time, gaps skipped [J]."""
        return integrate_J(self, self.frame["power_W"].to_numpy(float))

    @property
    def distance_m(self) -> float:
        """Distance travelled: trapezoid of ``v_mps`` over time, gaps skipped [m]."""
        return integrate_J(self, self.frame["v_mps"].to_numpy(float))

    def has(self, column: str) -> bool:
        return column in self.frame.columns


def integrate_J(recording: Recording, values) -> float:
    """Trapezoid integral of per-sample ``values`` over the recording's time, gaps skipped.

    Parameters
    ----------
    recording : gives the times and which intervals are gaps
    values : one value per sample (e.g. power [W] -> energy [J])

    Returns
    -------
    float
        The integral (unit of ``values`` x s).
    """
    return float(cumulative_J(recording, values)[-1])


def cumulative_J(recording: Recording, values) -> np.ndarray:
    """Running trapezoid integral (first sample 0), gap intervals adding nothing (n,)."""
    v = np.asarray(values, dtype=float)
    t = recording.t_s
    steps = 0.5 * (v[1:] + v[:-1]) * np.diff(t) * recording.interval_ok
    return np.concatenate([[0.0], np.cumsum(steps)])


# --- reading and writing ------------------------------------------------------------------


def load_recording(path: str | Path) -> Recording:
    """Read a CSV or Parquet recording and apply the checks of the module docstring.

    Raises
    ------
    RecordingError
        Unknown extension, unreadable or empty file, or a rule that refuses the data.
    """
    path = Path(path)
    require_file(path, "recording", RecordingError)
    frame = _read_table(path)
    return recording_from_frame(frame, source=str(path))


def recording_extension(path: Path) -> str:
    name = path.name.lower()
    for ext in READ_EXTENSIONS:
        if name.endswith(ext):
            return ext
    raise RecordingError(
        f"{path}: unknown recording extension; use one of {', '.join(READ_EXTENSIONS)}"
    )


def _read_table(path: Path) -> pd.DataFrame:
    ext = recording_extension(path)
    try:
        if ext in (".parquet", ".pq"):
            return pd.read_parquet(path)
        return pd.read_csv(path, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise RecordingError(f"{path}: the recording file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError, OSError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RecordingError(f"{path}: cannot read the recording: {first}") from None


def write_recording(recording: Recording | pd.DataFrame, path: str | Path) -> Path:
    """Write a recording (or a frame in recording columns (docs/formats.md)) atomically as CSV or Parquet.

    The table goes to a temporary file in the same folder, then replaces ``path`` in one
    step, so a reader never sees half a file.
    """
    path = Path(path)
    ext = recording_extension(path)
    frame = recording.frame if isinstance(recording, Recording) else recording
    with atomic_path(path) as tmp:
        if ext in (".parquet", ".pq"):
            frame.to_parquet(tmp, index=False)
        else:
            frame.to_csv(tmp, index=False, compression="gzip" if ext == ".csv.gz" else None)
    return path


# --- validation -----------------------------------------------------------------------------


def recording_from_frame(df: pd.DataFrame, source: str = "<frame>") -> Recording:
    """Validate, clean and complete an in-memory table (rules of the module docstring).

    Parameters
    ----------
    df : table with recording columns (docs/formats.md) (not modified)
    source : label used in messages and kept on the Recording

    Returns
    -------
    Recording

    Raises
    ------
    RecordingError
        One line naming the problem (missing column, text in a number, empty, bad stamps).

    Notes
    -----
    The rules work on the columns as arrays (``Columns``) and the table is built once at the
    end: a mission session cleans every telemetry batch of a few dozen rows, where a pandas
    operation per rule would cost more than the rules themselves.
    """
    if len(df.columns) == 0 or len(df) == 0:
        raise RecordingError(f"{source}: the recording has no data rows")
    if len(df) < 2:
        raise RecordingError(f"{source}: the recording has only one row; at least 2 are needed")
    cols = _columns(df, source)
    _check_required(cols, source)
    _to_numbers(cols, df, source)
    # Importers leave what they had to decide (e.g. a fallback channel) in attrs.
    issues = [DataIssue("import", cols.n, -1, str(note))
              for note in df.attrs.get("import_notes", ())]
    _check_timestamps(cols, source, issues)
    _check_ranges(cols, source)
    _drop_missing(cols, _needed_columns(cols), issues)
    _drop_unordered(cols, issues)
    if cols.n < 2:
        raise RecordingError(
            f"{source}: fewer than 2 usable rows remain after cleaning ("
            + "; ".join(str(i) for i in issues) + ")"
        )
    _fill_optional(cols, issues)
    t = cols["t_s"]
    gap_threshold_s = _gap_threshold(t, issues, cols.rows)
    pieces = gap_free_pieces(t, gap_threshold_s)
    _derive(cols, pieces, issues, source)
    frame = pd.DataFrame(_ordered(cols.data), copy=False)
    frame.attrs.update(df.attrs)
    return Recording(frame, source, tuple(issues), gap_threshold_s)


class Columns:
    """A table being cleaned: column name -> array (numbers as float arrays, other columns
    as pandas arrays, which keep their dtype) and each row's position in the input."""

    def __init__(self, data: dict, n: int):
        self.data, self.n = data, n
        self.rows = np.arange(n)

    def __contains__(self, name: str) -> bool:
        return name in self.data

    def __getitem__(self, name: str):
        return self.data[name]

    def __setitem__(self, name: str, values) -> None:
        self.data[name] = values

    def keep(self, mask: np.ndarray) -> None:
        """Keep the rows where ``mask`` is true, in every column."""
        if mask.all():
            return
        self.data = {k: v[mask] for k, v in self.data.items()}
        self.rows = self.rows[mask]
        self.n = int(self.rows.size)


def _columns(df: pd.DataFrame, source: str) -> Columns:
    names = [str(c).strip() for c in df.columns]
    seen = set()
    for name in names:
        if name in seen:
            raise RecordingError(f"{source}: column {name!r} appears twice")
        seen.add(name)
    data = {name: df.iloc[:, i].array for i, name in enumerate(names)}
    return Columns(data, len(df))


def _check_required(cols: Columns, source: str) -> None:
    names = set(cols.data)
    if "t_s" not in names:
        raise RecordingError(f"{source}: missing required column 't_s'" + _have(names))
    if "power_W" not in names:
        lacking = [c for c in ("voltage_V", "current_A") if c not in names]
        if lacking:
            raise RecordingError(
                f"{source}: missing column 'power_W' (or '{lacking[0]}' to derive it from "
                "voltage_V x current_A)" + _have(names)
            )
    if "v_mps" not in names:
        lacking = [c for c in ("x_m", "y_m") if c not in names]
        if lacking:
            raise RecordingError(
                f"{source}: missing column 'v_mps' (or '{lacking[0]}': speed needs x_m and "
                "y_m)" + _have(names)
            )


def _have(cols) -> str:
    shown = sorted(cols)[:12]
    return (f"; columns present: {', '.join(shown)}" + (" ..." if len(cols) > 12 else "")
            + csv_delimiter_hint(cols))


def _to_numbers(cols: Columns, df: pd.DataFrame, source: str) -> None:
    for col in NUMERIC_COLUMNS:
        if col not in cols:
            continue
        raw = cols[col]
        if pd.api.types.is_bool_dtype(raw.dtype):
            raise RecordingError(f"{source}: column '{col}' holds true/false values, not numbers")
        if pd.api.types.is_numeric_dtype(raw.dtype):  # numbers already: no text to report
            cols[col] = raw.to_numpy(dtype=float, na_value=np.nan)
            continue
        series = pd.Series(raw, copy=False)
        numbers = pd.to_numeric(series, errors="coerce")
        text = numbers.isna() & series.notna() & (series.astype(str).str.strip() != "")
        if text.any():
            row = int(np.flatnonzero(text.to_numpy())[0])
            raise RecordingError(
                f"{source}: column '{col}' holds text {str(series.iloc[row])!r} at row {row} "
                f"(CSV line {row + 2}); numbers expected"
            )
        cols[col] = numbers.to_numpy(dtype=float, na_value=np.nan)


def _check_timestamps(cols: Columns, source: str, issues: list) -> None:
    t = cols["t_s"]
    hint = "; t_s must be seconds since the start (convert ms or ns, or subtract the first stamp)"
    if np.any(np.isinf(t)):
        row = int(np.flatnonzero(np.isinf(t))[0])
        raise RecordingError(f"{source}: t_s is infinite at row {row}{hint}")
    finite = t[np.isfinite(t)]
    if finite.size == 0:
        raise RecordingError(f"{source}: t_s has no value at all")
    if np.max(np.abs(finite)) > MAX_ABS_TIME_S:
        row = int(np.flatnonzero(np.abs(t) > MAX_ABS_TIME_S)[0])
        raise RecordingError(
            f"{source}: t_s = {t[row]:.6g} at row {row} is too large for seconds "
            f"(looks like epoch milli- or nanoseconds){hint}"
        )
    span = float(np.max(finite) - np.min(finite))
    if span > MAX_SPAN_S:
        raise RecordingError(
            f"{source}: t_s spans {span:.3g} s (more than {MAX_SPAN_S:.0e} s){hint}"
        )
    t0 = float(finite[0])
    if abs(t0) > REBASE_T0_S:
        cols["t_s"] = t - t0
        issues.append(DataIssue("rebased", int(finite.size), 0,
                                f"t_s starts at {t0:.6g} s (epoch seconds): shifted so the "
                                "first sample is at 0 s"))


def _check_ranges(cols: Columns, source: str, names=tuple(PHYSICAL_RANGES),
                  derived: str = "") -> None:
    """Rule 3b: refuse an infinite or out-of-range value (missing values are left to rules
    5 and 9), naming the column, the value, its first row and the allowed range."""
    for col in names:
        if col not in cols:
            continue
        low, high, unit = PHYSICAL_RANGES[col]
        v = cols[col]
        bad = np.isinf(v) | (v < low) | (v > high)  # NaN compares false: not flagged
        if not bad.any():
            continue
        i = int(np.flatnonzero(bad)[0])
        row = int(cols.rows[i])
        hint = ""
        if col == "soc" and 1.0 < np.nanmax(v[np.isfinite(v)]) <= 100.0:
            hint = "; soc is a fraction 0..1: a percentage must be divided by 100"
        raise RecordingError(
            f"{source}: column '{col}'{derived} = {v[i]:.6g} at row {row} (CSV line {row + 2}) "
            f"is outside its physical range [{low:.6g}, {high:.6g}] {unit}"
            f"{hint}; fix or remove the value (docs/guide/recordings.md)"
        )


def _needed_columns(cols) -> list[str]:
    needed = ["t_s"]
    needed += ["power_W"] if "power_W" in cols else ["voltage_V", "current_A"]
    needed += ["v_mps"] if "v_mps" in cols else ["x_m", "y_m"]
    return needed


def _drop_missing(cols: Columns, needed: list[str], issues: list) -> None:
    finite = np.column_stack([np.isfinite(cols[c]) for c in needed])
    bad = ~np.all(finite, axis=1)
    if bad.any():
        names = [c for c, b in zip(needed, (~finite).any(axis=0)) if b]
        issues.append(DataIssue("missing_value", int(bad.sum()), int(cols.rows[bad][0]),
                                f"rows with a missing or non-finite {', '.join(names)} dropped"))
        cols.keep(~bad)


def _drop_unordered(cols: Columns, issues: list) -> None:
    t = cols["t_s"]
    latest = np.concatenate([[-np.inf], np.maximum.accumulate(t)[:-1]])
    backwards, duplicate = t < latest, t == latest
    rows = cols.rows
    if backwards.any():
        issues.append(DataIssue("backwards", int(backwards.sum()), int(rows[backwards][0]),
                                "rows stamped earlier than an earlier row dropped"))
    if duplicate.any():
        issues.append(DataIssue("duplicate", int(duplicate.sum()), int(rows[duplicate][0]),
                                "rows repeating the previous stamp dropped (first kept)"))
    cols.keep(~(backwards | duplicate))


def _fill_optional(cols: Columns, issues: list) -> None:
    needed = set(_needed_columns(cols))
    t = cols["t_s"]
    for col in NUMERIC_COLUMNS:
        if col not in cols or col in needed:
            continue
        v = cols[col]
        ok = np.isfinite(v)
        if ok.all():
            continue
        if not ok.any():
            del cols.data[col]
            issues.append(DataIssue("optional_missing", len(v), -1,
                                    f"optional column {col} has no value: removed"))
            continue
        cols[col] = np.interp(t, t[ok], v[ok])
        issues.append(DataIssue("optional_missing", int((~ok).sum()), int(cols.rows[~ok][0]),
                                f"missing {col} interpolated linearly in time"))


def _gap_threshold(t: np.ndarray, issues: list, rows: np.ndarray) -> float:
    dt = np.diff(t)
    threshold = GAP_FACTOR * float(np.median(dt))
    gaps = dt > threshold
    if gaps.any():
        first = int(np.flatnonzero(gaps)[0])
        issues.append(DataIssue(
            "gap", int(gaps.sum()), int(rows[first + 1]),
            f"intervals longer than {GAP_FACTOR:g} x median ({threshold:.3g} s; longest "
            f"{dt.max():.3g} s) are not bridged: integrals skip them",
        ))
    return threshold


# --- derived channels ---------------------------------------------------------------------------


def _derive(cols: Columns, pieces: list[slice], issues: list, source: str) -> None:
    t = cols["t_s"]
    n, w = cols.n, window_samples(t)
    has_xy = "x_m" in cols and "y_m" in cols
    if "power_W" not in cols:
        cols["power_W"] = cols["voltage_V"] * cols["current_A"]
        _check_ranges(cols, source, ("power_W",), " (voltage_V x current_A)")
        issues.append(DataIssue("derived", n, 0, "power_W = voltage_V x current_A"))
    if "v_mps" not in cols:
        xs = smooth_pieces(cols["x_m"], w, pieces)
        ys = smooth_pieces(cols["y_m"], w, pieces)
        cols["v_mps"] = np.hypot(derivative(xs, t, pieces), derivative(ys, t, pieces))
        issues.append(DataIssue("derived", n, 0, f"v_mps from positions: {w}-sample centred "
                                "moving average, then central differences"))
    v = cols["v_mps"]
    if (v < 0).any():
        issues.append(DataIssue("reverse", int((v < 0).sum()), int(np.flatnonzero(v < 0)[0]),
                                "negative v_mps (reversing) replaced by its magnitude"))
        cols["v_mps"] = np.abs(v)
    if "yaw_rate_radps" not in cols:
        if has_xy:
            cols["yaw_rate_radps"] = position_yaw_rate_radps(cols["x_m"], cols["y_m"], t, pieces,
                                                             cols["v_mps"])
            rule = (f"yaw_rate_radps from the heading of positions ({w}-sample moving "
                    f"average, unwrapped, held below {STILL_SPEED_MPS} m/s of horizontal "
                    "speed), central differences")
        else:
            cols["yaw_rate_radps"] = np.zeros(n)
            rule = "no yaw_rate_radps and no positions: yaw rate set to 0"
        issues.append(DataIssue("derived", n, 0, rule))
    if "accel_mps2" not in cols:
        vs = smooth_pieces(cols["v_mps"], w, pieces)
        cols["accel_mps2"] = derivative(vs, t, pieces)
        issues.append(DataIssue("derived", n, 0, f"accel_mps2 from v_mps: {w}-sample centred "
                                "moving average, then central differences"))


def _ordered(data: dict) -> dict:
    """recording columns (docs/formats.md) first, in their documented order, then the others as they came."""
    first = [c for c in SPEC_COLUMNS if c in data]
    return {c: data[c] for c in first + [c for c in data if c not in first]}


# --- blocks ---------------------------------------------------------------------


def split_blocks(recording: Recording, n_blocks: int) -> list[Recording]:
    """Cut a recording into ``n_blocks`` contiguous blocks of equal time span.

    Used for held-out evaluation (fit on some blocks, test on the others). Each block keeps
    the parent's issues and gap threshold; a block with fewer than 2 samples is refused.
    """
    if int(n_blocks) != n_blocks or n_blocks < 1:
        raise RecordingError(f"n_blocks = {n_blocks!r} must be a positive integer")
    t = recording.t_s
    edges = np.linspace(t[0], t[-1], int(n_blocks) + 1)
    index = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, int(n_blocks) - 1)
    blocks = []
    for k in range(int(n_blocks)):
        part = recording.frame[index == k].reset_index(drop=True)
        if len(part) < 2:
            raise RecordingError(
                f"{recording.source}: block {k + 1} of {n_blocks} has {len(part)} sample(s); "
                "use fewer blocks"
            )
        blocks.append(Recording(part, f"{recording.source}[block {k + 1}/{n_blocks}]",
                                recording.issues, recording.gap_threshold_s))
    return blocks
