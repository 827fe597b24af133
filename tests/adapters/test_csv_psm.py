"""PSM CSV importers: the real WPI recordings, the paper layout round trip, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from wrenchd.adapters.csv_psm import (
    PAPER_HEADER,
    read_paper_csv,
    read_psm_csv,
    read_wpi_csv,
    write_paper_csv,
)
from wrenchd.models.errors import DataError
from wrenchd.models.series import JointStates

def test_wpi_recording_reads_in_physical_units(wpi_data):
    js, jaw = read_wpi_csv(wpi_data / "one_no_weight.csv")
    assert len(js) == 5999 and js.position.shape == (5999, 6)
    assert jaw.shape == (5999, 3)
    np.testing.assert_allclose(np.diff(js.t), 0.005, rtol=0, atol=1e-12)
    assert js.t[0] == 0.0 and js.rate_hz == pytest.approx(200.0)
    insertion = js.position[:, 2]
    assert np.all((insertion > 0.0) & (insertion < 0.3)), "insertion must be in metres"
    revolute = js.position[:, [0, 1, 3, 4, 5]]
    assert np.all(np.abs(revolute) <= np.pi)
    assert np.all(np.abs(js.effort) < 20.0)
    assert np.all(np.abs(jaw[:, 0]) <= np.pi) and np.all(np.abs(jaw[:, 2]) < 20.0)
    # the columns are q, dq, tau in that order: velocity is the derivative of position
    dq_numeric = np.gradient(js.position[:, 0], js.t)
    assert np.corrcoef(dq_numeric, js.velocity[:, 0])[0, 1] > 0.99


def test_every_wpi_file_reads_and_auto_detects(wpi_data):
    files = sorted(wpi_data.glob("*.csv"))
    assert len(files) == 6
    for path in files:
        js, _ = read_wpi_csv(path)
        auto = read_psm_csv(path)
        assert len(js) == 5999, path.name
        np.testing.assert_array_equal(auto.position, js.position)


def test_paper_layout_round_trips_the_real_data_exactly(wpi_data, tmp_path):
    js, _ = read_wpi_csv(wpi_data / "two.csv")
    for header in (True, False):
        path = tmp_path / f"paper_{header}.csv"
        write_paper_csv(path, js, header=header)
        first = path.read_text().splitlines()[0]
        assert (first == ",".join(PAPER_HEADER)) == header
        for back in (read_paper_csv(path), read_psm_csv(path), read_psm_csv(path, "paper")):
            for name in ("t", "position", "velocity", "effort"):
                np.testing.assert_array_equal(getattr(back, name), getattr(js, name))


def _synthetic(n: int = 5) -> JointStates:
    rng = np.random.default_rng(3)
    return JointStates(np.arange(n) * 0.01, rng.standard_normal((n, 6)),
                       rng.standard_normal((n, 6)), rng.standard_normal((n, 6)))


def _write_rows(path: Path, rows: list[list[str]]) -> Path:
    path.write_text("\n".join(",".join(row) for row in rows) + "\n")
    return path


def _wpi_rows(n: int = 4, columns: int = 21) -> list[list[str]]:
    return [[f"{0.01 * (k + 1) + 0.001 * c:.6f}" for c in range(columns)] for k in range(n)]


def test_wrong_column_count_names_line_and_count(tmp_path):
    path = _write_rows(tmp_path / "twenty.csv", _wpi_rows(columns=20))
    with pytest.raises(DataError, match="line 1 has 20 columns, expected 21"):
        read_wpi_csv(path)
    with pytest.raises(DataError, match="first line has 20 columns"):
        read_psm_csv(path)
    rows = _wpi_rows()
    rows[2] = rows[2][:-1]
    with pytest.raises(DataError, match="line 3 has 20 columns, expected 21"):
        read_wpi_csv(_write_rows(tmp_path / "ragged.csv", rows))


def test_non_numeric_and_non_finite_cells_name_line_and_column(tmp_path):
    rows = _wpi_rows()
    rows[1][4] = "abc"
    with pytest.raises(DataError, match="line 2, column 5: 'abc' is not a number"):
        read_wpi_csv(_write_rows(tmp_path / "text.csv", rows))
    rows = _wpi_rows()
    rows[3][0] = ""
    with pytest.raises(DataError, match="line 4, column 1: '' is not a number"):
        read_psm_csv(_write_rows(tmp_path / "empty_cell.csv", rows))
    rows = _wpi_rows()
    rows[2][7] = "nan"
    with pytest.raises(DataError, match="line 3, column 8: nan is not a finite number"):
        read_wpi_csv(_write_rows(tmp_path / "nan.csv", rows))


def test_paper_layout_header_is_optional_and_time_must_increase(tmp_path):
    js = _synthetic()
    path = tmp_path / "p.csv"
    write_paper_csv(path, js, header=False)
    lines = path.read_text().splitlines()
    (tmp_path / "h.csv").write_text("time,a,b,c,d,e,f,g,h,i,j,k,l,m,n,o,p,q,r\n"
                                    + "\n".join(lines) + "\n")
    np.testing.assert_array_equal(read_paper_csv(tmp_path / "h.csv").effort, js.effort)
    cells = lines[3].split(",")
    cells[0] = lines[2].split(",")[0]  # line 4 repeats the time of line 3
    lines[3] = ",".join(cells)
    (tmp_path / "dup.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match="line 4: time .* is not after .* on line 3"):
        read_paper_csv(tmp_path / "dup.csv")


def test_a_header_is_not_tolerated_in_the_wpi_layout(tmp_path):
    rows = [[f"q{c}" for c in range(21)]] + _wpi_rows()
    with pytest.raises(DataError, match="line 1, column 1: 'q0' is not a number"):
        read_psm_csv(_write_rows(tmp_path / "header.csv", rows))


def test_bad_format_and_empty_file(tmp_path):
    with pytest.raises(DataError, match="format must be"):
        read_psm_csv(tmp_path / "whatever.csv", format="bag")
    (tmp_path / "empty.csv").write_text("\n\n")
    with pytest.raises(DataError, match="no data rows"):
        read_psm_csv(tmp_path / "empty.csv")


def test_the_wpi_rate_comes_from_the_velocity_columns(wpi_data, tmp_path):
    """The half-speed runs repeat trajectory one with its samples per period and half its
    velocities: 100 Hz, not the 200 Hz of the others; an explicit rate still wins."""
    from wrenchd.adapters.csv_psm import read_wpi_csv

    fast, _ = read_wpi_csv(wpi_data / "one_no_weight.csv")
    slow, _ = read_wpi_csv(wpi_data / "one_slow_105g_parallel.csv")
    assert fast.rate_hz == pytest.approx(200.0) and slow.rate_hz == pytest.approx(100.0)
    assert read_wpi_csv(wpi_data / "one_slow_105g_parallel.csv", 200.0)[0].rate_hz == \
        pytest.approx(200.0)
    # A table whose velocities match no usual rate is refused, naming the rate.
    values = np.loadtxt(wpi_data / "one_no_weight.csv", delimiter=",")[:400]
    values[:, 7:14] *= 1.37
    path = tmp_path / "odd.csv"
    np.savetxt(path, values, delimiter=",")
    with pytest.raises(DataError, match="imply 274"):
        read_wpi_csv(path)
    # A still recording has no rate to infer: the default.
    values[:, 7:14] = 0.0
    np.savetxt(path, values, delimiter=",")
    assert read_wpi_csv(path)[0].rate_hz == pytest.approx(200.0)
