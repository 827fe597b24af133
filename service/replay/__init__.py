"""Replay of recorded sessions through the daemon's pipeline: source, loop, output, metrics."""
