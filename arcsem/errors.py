"""Errors that end a run with one line naming what is wrong (file, view, key), not a traceback.

Everything the user can get wrong raises an :class:`ArcsemError` subclass; the CLI entry points
catch it, print ``error: <message>`` and exit with code 2 (``ARCSEM_DEBUG=1`` or ``--debug``
shows the traceback instead).
"""
from __future__ import annotations

__all__ = ["ArcsemError", "ConfigError", "DataError", "Interrupted", "OutputError", "PluginError", "TrainingError",
           "config_error_types", "one_line"]


class ArcsemError(Exception):
    """Base class: a user-facing error with a one-line message."""


class ConfigError(ArcsemError):
    """A config key is unknown, mistyped or has a wrong type/value."""


class DataError(ArcsemError):
    """A dataset file is missing, malformed or inconsistent (names the file or view)."""


class PluginError(ArcsemError):
    """A plugin name is unknown or a plugin cannot be loaded/built."""


class TrainingError(ArcsemError):
    """Training diverged or cannot resume (names the step / term / keys)."""


class OutputError(ArcsemError):
    """An output cannot or must not be written: outside the run folder, onto an input, disk full, read-only."""


class Interrupted(ArcsemError):
    """The user stopped the run (Ctrl-C); says what was saved. The CLI exits with code 130."""


def config_error_types() -> tuple[type[BaseException], ...]:
    """The errors a user causes through the config: ours, Hydra's and OmegaConf's (imported on use)."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    return ArcsemError, HydraException, OmegaConfBaseException


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (Hydra's multi-line messages joined with ``; ``)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    cause = exc.__cause__
    if not lines and cause is not None:
        return one_line(cause)
    msg = "; ".join(lines) or type(exc).__name__
    if cause is not None and isinstance(cause, config_error_types()) and str(cause).strip() not in msg:
        msg += f" ({'; '.join(ln.strip() for ln in str(cause).splitlines() if ln.strip())})"
    return msg
