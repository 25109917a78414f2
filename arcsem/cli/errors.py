"""One-line errors for the console scripts: ``error: <message>`` on stderr and exit code 2.

User errors are :class:`~arcsem.errors.ArcsemError` and Hydra/OmegaConf config errors (unknown
override key, missing config option, bad value). Anything else is a bug and keeps its traceback.
``debug=true`` on the command line or ``ARCSEM_DEBUG=1`` re-raises every error with its traceback.
"""
from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import Any

from ..errors import ArcsemError

__all__ = ["EXIT_USER_ERROR", "call_reporting_errors", "debug_requested", "one_line", "with_error_handling"]

EXIT_USER_ERROR = 2


def debug_requested(argv: list[str] | None = None) -> bool:
    """True with ``ARCSEM_DEBUG=1`` or a ``debug=true`` (``+debug=true``, ``--debug``) argument."""
    if os.environ.get("ARCSEM_DEBUG", "") not in ("", "0", "false", "False"):
        return True
    argv = sys.argv[1:] if argv is None else argv
    return any(a.lstrip("+~").lower() in ("debug=true", "debug=1", "debug=yes") or a == "--debug" for a in argv)


def _user_error_types() -> tuple[type[BaseException], ...]:
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
    if cause is not None and isinstance(cause, _user_error_types()) and str(cause).strip() not in msg:
        msg += f" ({'; '.join(ln.strip() for ln in str(cause).splitlines() if ln.strip())})"
    return msg


def call_reporting_errors(call: Callable[[], Any], debug: bool = False) -> Any:
    """``call()``; a user error prints one ``error:`` line and returns 2 (re-raised when ``debug``)."""
    debug = debug or debug_requested([])
    try:
        return call()
    except _user_error_types() as exc:
        if debug:
            raise
        print(f"error: {one_line(exc)}", file=sys.stderr)
        return EXIT_USER_ERROR


def with_error_handling(func: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a console-script ``main``: user errors print one ``error:`` line and exit 2."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        debug = debug_requested()
        if not debug:
            os.environ.setdefault("HYDRA_FULL_ERROR", "1")  # Hydra re-raises; we print the one line
        result = call_reporting_errors(lambda: func(*args, **kwargs), debug)
        if result == EXIT_USER_ERROR:
            sys.exit(EXIT_USER_ERROR)
        return result

    return wrapper
