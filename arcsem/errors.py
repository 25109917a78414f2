"""Errors that end a run with one line naming what is wrong (file, view, key), not a traceback.

Everything the user can get wrong raises an :class:`ArcsemError` subclass; the CLI entry points
catch it, print ``error: <message>`` and exit with code 2 (``ARCSEM_DEBUG=1`` or ``--debug``
shows the traceback instead).
"""
from __future__ import annotations

__all__ = ["ArcsemError", "ConfigError", "DataError", "Interrupted", "OutputError", "PluginError", "TrainingError"]


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
