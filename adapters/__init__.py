"""I/O at the edges: MCAP session files, PSM CSV recordings, zenoh and the simulator.

Nothing in ``models`` imports from here; adapters turn files and messages into the array
types of :mod:`wrenchd.models.series` and back, and wrap library errors in :mod:`wrenchd.models.errors`.
"""

if __name__ != "wrenchd.adapters":  # the folder on sys.path is not the package
    raise ImportError(f"import wrenchd.adapters, not {__name__}: wrenchd installs one import name")
