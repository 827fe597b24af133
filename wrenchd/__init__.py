"""wrenchd: sensorless tip-wrench estimation for the dVRK Patient Side Manipulator.

One import name for the three floors, which live at the top of the repository and are mapped
here by ``pyproject.toml``:

- :mod:`wrenchd.models`: the pure core (physics, estimator, gate, adaptation, discrepancy);
  arrays in, arrays out, no I/O.
- :mod:`wrenchd.adapters`: I/O at the edges (zenoh, MCAP, ROS 2 bags, CSV, the simulator).
- :mod:`wrenchd.service`: the daemon, the pipeline it shares with replay, the CLI, studies
  and benches.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("wrenchd")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
