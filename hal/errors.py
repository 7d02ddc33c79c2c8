"""The error types the hardware layer raises, so callers can tell a bad file from a dead wire."""


class ConfigError(ValueError):
    """The rig configuration is wrong; the message names the key path and the problem."""


class TransportError(RuntimeError):
    """A transport could not complete a sweep (the caller must trip to the safe state)."""


class TransportTimeout(TransportError):
    """The transport's peer did not answer within its deadline."""


class CommandError(ValueError):
    """An output command cannot be written as given (e.g. non-finite); nothing was written."""
