"""The wrenchd exception tree.

Every error wrenchd raises on purpose derives from :class:`WrenchdError`, so a caller
(the CLI, the daemon loop) can tell "our validation said no" from a bug. Library errors
are wrapped where they enter (``raise DataError(...) from exc``).
"""


class WrenchdError(Exception):
    """Base of every error wrenchd raises deliberately."""


class ConfigError(WrenchdError):
    """A configuration or model file is invalid; the message names the bad value."""


class DataError(WrenchdError):
    """Input data (a file, a payload, an array) is malformed or physically implausible."""


class AdapterError(WrenchdError):
    """An I/O adapter (MCAP, CSV, zenoh, CDR) failed to read or write."""
