"""The daemon: one zenoh session, per-arm runtimes, the adaptation worker, the log writer."""
