"""Importers for the two public dVRK PSM joint-state CSV layouts, and an exporter.

- ``wpi``: 21 columns ``q1..q7, dq1..dq7, tau1..tau7``, no header, no time column, sampled
  at a fixed rate (``WPI-AIM/dvrk_dynamics_identification`` measured trajectories).
  Joint 7 is the jaw, returned apart from the six arm joints.
- ``paper``: 19 columns ``t, q1..q6, dq1..dq6, effort1..effort6``, an optional header row
  (the preprocessing layout of Wu et al.'s two-step force estimation).

Units throughout: rad, rad, m, rad, rad, rad; velocities per second; efforts N m, joint 3 N;
t in s. Blank lines and lines starting with ``#`` are skipped.
"""

from __future__ import annotations

import os

import numpy as np

from wrenchd.models.errors import AdapterError, DataError
from wrenchd.models.series import N_JOINTS, JointStates

WPI_COLUMNS = 21
PAPER_COLUMNS = 19
PAPER_HEADER: tuple[str, ...] = (
    ("t",)
    + tuple(f"q{i}" for i in range(1, 7))
    + tuple(f"dq{i}" for i in range(1, 7))
    + tuple(f"effort{i}" for i in range(1, 7))
)
_LAYOUTS = {
    WPI_COLUMNS: "wpi (q1..q7, dq1..dq7, tau1..tau7)",
    PAPER_COLUMNS: "paper (t, q1..q6, dq1..dq6, effort1..effort6)",
}


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


class _Table:
    """The data lines of a CSV file, each with its 1-based line number."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        try:
            with open(self.path, encoding="utf-8") as file:
                text = file.read()
        except OSError as exc:
            raise AdapterError(f"cannot read {self.path}: {exc}") from exc
        except UnicodeDecodeError as exc:
            raise DataError(f"{self.path} is not a UTF-8 text file: {exc}") from exc
        self.numbers: list[int] = []
        self.lines: list[str] = []
        for number, line in enumerate(text.splitlines(), start=1):
            stripped = line.strip()
            if stripped and not stripped.startswith("#"):
                self.numbers.append(number)
                self.lines.append(stripped)
        if not self.lines:
            raise DataError(f"{self.path} has no data rows")

    @property
    def first_columns(self) -> int:
        return self.lines[0].count(",") + 1

    def drop_header(self) -> None:
        """Removes the first line if its first cell is not a number (a column-name row)."""
        if not _is_number(self.lines[0].split(",", 1)[0]):
            self.lines.pop(0)
            self.numbers.pop(0)
            if not self.lines:
                raise DataError(f"{self.path} has a header but no data rows")

    def parse(self, columns: int) -> np.ndarray:
        """(rows, columns) finite floats; DataError names the line of the first bad row."""
        layout = _LAYOUTS.get(columns, f"{columns} columns")
        for number, line in zip(self.numbers, self.lines):
            found = line.count(",") + 1
            if found != columns:
                raise DataError(f"{self.path}: line {number} has {found} columns, expected "
                                f"{columns}: {layout}")
        try:
            values = np.loadtxt(self.lines, delimiter=",", dtype=np.float64, ndmin=2)
        except ValueError as exc:
            for number, line in zip(self.numbers, self.lines):
                for column, cell in enumerate(line.split(","), start=1):
                    if not _is_number(cell):
                        raise DataError(f"{self.path}: line {number}, column {column}: "
                                        f"{cell.strip()!r} is not a number") from exc
            raise DataError(f"{self.path}: cannot parse as numbers: {exc}") from exc
        finite = np.isfinite(values)
        if not finite.all():
            row, column = np.argwhere(~finite)[0]
            raise DataError(f"{self.path}: line {self.numbers[row]}, column {column + 1}: "
                            f"{values[row, column]} is not a finite number")
        return values


def _joint_states(table: _Table, t: np.ndarray, values: np.ndarray,
                  starts: tuple[int, int, int]) -> JointStates:
    """Joint states from the q, dq, tau column blocks starting at ``starts``; t must increase."""
    q, dq, tau = (values[:, s:s + N_JOINTS] for s in starts)
    step = np.diff(t)
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0)) + 1
        raise DataError(f"{table.path}: line {table.numbers[i]}: time {float(t[i])!r} s is not "
                        f"after {float(t[i - 1])!r} s on line {table.numbers[i - 1]}")
    return JointStates(t, q, dq, tau)


#: Sample rates a WPI recording's rate is snapped to when inferred [Hz].
WPI_RATES_HZ = (50.0, 100.0, 125.0, 200.0, 250.0, 400.0, 500.0, 1000.0)
#: The rate of a recording that hardly moves (too little motion to infer one) [Hz].
WPI_DEFAULT_RATE_HZ = 200.0


def wpi_rate(values: np.ndarray, path: object = "") -> float:
    """The sample rate [Hz] that makes a WPI table's velocity columns the time derivative of
    its position columns (joints 1-3), snapped to :data:`WPI_RATES_HZ` within 5 %.

    The files carry no time column and not all were recorded at the same rate: the half-speed
    WPI runs have the full-speed runs' samples per period and half their velocities, i.e.
    100 Hz. A recording with too little motion gets :data:`WPI_DEFAULT_RATE_HZ`.

    Raises:
        DataError: the columns imply a rate far from every rate of :data:`WPI_RATES_HZ`.
    """
    q, dq = values[:, 0:3], values[:, 7:10]
    step, mid = np.diff(q, axis=0), 0.5 * (dq[1:] + dq[:-1])
    power = np.sum(mid ** 2, axis=0)
    moving = power > 1e-6 * max(len(mid), 1)
    if len(values) < 3 or not moving.any():
        return WPI_DEFAULT_RATE_HZ
    dt = float(np.median(np.sum(step * mid, axis=0)[moving] / power[moving]))
    if not dt > 0:
        raise DataError(f"{path}: the velocity columns run against the positions; check the "
                        "column order")
    rate = 1.0 / dt
    best = min(WPI_RATES_HZ, key=lambda r: abs(r / rate - 1.0))
    if abs(best / rate - 1.0) > 0.05:
        raise DataError(f"{path}: the velocity columns imply {rate:.1f} Hz, no usual rate; "
                        "give the rate explicitly")
    return best


def read_wpi_csv(path: str | os.PathLike[str],
                 rate_hz: float | None = None) -> tuple[JointStates, np.ndarray]:
    """Reads a WPI measured-trajectory CSV (21 columns, no header, no time column).

    Args:
        path: the CSV file.
        rate_hz: sample rate [Hz]; sample k is at t = k / rate_hz. ``None``: inferred from
            the velocity columns (:func:`wpi_rate`).

    Returns:
        (joint states of joints 1..6, jaw) where jaw is (N, 3): q7 [rad], dq7 [rad/s], tau7 [N m].

    Raises:
        AdapterError: the file cannot be read.
        DataError: wrong column count, a non-numeric or non-finite cell (names line and column).
    """
    return _wpi(_Table(path), rate_hz)


def _wpi(table: _Table, rate_hz: float | None) -> tuple[JointStates, np.ndarray]:
    if rate_hz is not None and not rate_hz > 0:
        raise DataError(f"rate_hz must be > 0, got {rate_hz}")
    values = table.parse(WPI_COLUMNS)
    if rate_hz is None:
        rate_hz = wpi_rate(values, table.path)
    t = np.arange(values.shape[0]) / float(rate_hz)
    jaw = values[:, [6, 13, 20]].copy()
    return _joint_states(table, t, values, (0, 7, 14)), jaw


def read_paper_csv(path: str | os.PathLike[str]) -> JointStates:
    """Reads the 19-column layout ``t, q1..q6, dq1..dq6, effort1..effort6``, header optional.

    Raises:
        AdapterError: the file cannot be read.
        DataError: wrong column count, a non-numeric or non-finite cell, time not increasing.
    """
    return _paper(_Table(path))


def _paper(table: _Table) -> JointStates:
    table.drop_header()
    values = table.parse(PAPER_COLUMNS)
    return _joint_states(table, values[:, 0].copy(), values, (1, 7, 13))


def write_paper_csv(path: str | os.PathLike[str], js: JointStates, *, header: bool = True) -> None:
    """Writes ``js`` in the 19-column paper layout; ``%.17g`` so it reads back bit for bit.

    Raises:
        AdapterError: the file cannot be written.
    """
    values = np.column_stack([js.t, js.position, js.velocity, js.effort])
    try:
        np.savetxt(os.fspath(path), values, fmt="%.17g", delimiter=",",
                   header=",".join(PAPER_HEADER) if header else "", comments="")
    except OSError as exc:
        raise AdapterError(f"cannot write {path}: {exc}") from exc


def read_psm_csv(path: str | os.PathLike[str], format: str = "auto", *,
                 rate_hz: float | None = None) -> JointStates:
    """Reads either layout; ``format="auto"`` picks it by the column count of the first line.

    Args:
        format: ``"auto"``, ``"wpi"`` or ``"paper"``.
        rate_hz: sample rate of a WPI file [Hz] (it has no time column).

    Returns:
        The six arm joints; a WPI file's jaw is dropped (use :func:`read_wpi_csv` for it).
    """
    if format not in ("auto", "wpi", "paper"):
        raise DataError(f"format must be 'auto', 'wpi' or 'paper', got {format!r}")
    table = _Table(path)
    if format == "auto":
        columns = table.first_columns
        if columns == WPI_COLUMNS:
            format = "wpi"
        elif columns == PAPER_COLUMNS:
            format = "paper"
        else:
            raise DataError(f"{os.fspath(path)}: first line has {columns} columns; expected "
                            f"{WPI_COLUMNS} ({_LAYOUTS[WPI_COLUMNS]}) or {PAPER_COLUMNS} "
                            f"({_LAYOUTS[PAPER_COLUMNS]})")
    if format == "wpi":
        return _wpi(table, rate_hz)[0]
    return _paper(table)
