"""I/O at the edges: MCAP session files, PSM CSV recordings, zenoh and the simulator.

Nothing in ``models`` imports from here; adapters turn files and messages into the array
types of :mod:`models.series` and back, and wrap library errors in :mod:`models.errors`.
"""
