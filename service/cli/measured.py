"""``--measured``, ``--format`` and ``--rate``: the recording ``identify`` and ``discrepancy`` read."""

from __future__ import annotations

from wrenchd.models.errors import DataError

FORMATS = ("auto", "wpi", "paper", "mcap")


def add_measured_options(parser) -> None:
    """Add ``--measured`` (required), ``--format`` and ``--rate`` to ``parser``."""
    parser.add_argument("--measured", required=True, help="CSV (WPI or paper layout) or .mcap")
    parser.add_argument("--format", default="auto", choices=FORMATS)
    parser.add_argument("--rate", type=float, default=200.0,
                        help="sample rate of a WPI CSV [Hz]")


def read_measured(path: str, fmt: str = "auto", rate_hz: float = 200.0):
    """Joint states (``JointStates``) of a recording: CSV (WPI or paper layout) or an MCAP
    session."""
    if fmt == "mcap" or (fmt == "auto" and str(path).endswith(".mcap")):
        from wrenchd.adapters.mcap_session_reader import read_session
        return read_session(path).joint_states
    from wrenchd.adapters.csv_psm import read_psm_csv
    if fmt not in ("auto", "wpi", "paper"):
        raise DataError(f"--format must be one of {FORMATS}, got {fmt!r}")
    return read_psm_csv(path, fmt, rate_hz=rate_hz)
