"""Lifelong adaptation of the correction net: the deterministic adapter and its sample buffer."""
