"""One-line errors for the console scripts: ``error: <message>`` on stderr and an exit code.

What the user can cause or fix ends with one line and no traceback:

* :class:`~arcsem.errors.ArcsemError` and Hydra/OmegaConf config errors (unknown key, bad value): exit 2;
* the environment: a folder that cannot be written (permission, read-only file system), a full disk, a
  file too large: exit 2, with what to do;
* Ctrl-C (``KeyboardInterrupt``, :class:`~arcsem.errors.Interrupted`): exit 130.

Anything else is a bug and keeps its traceback. ``debug=true`` on the command line or ``ARCSEM_DEBUG=1``
re-raises every error with its traceback.
"""
from __future__ import annotations

import errno
import functools
import os
import sys
from collections.abc import Callable
from typing import Any

from ..errors import Interrupted, config_error_types, one_line

__all__ = ["EXIT_INTERRUPTED", "EXIT_USER_ERROR", "call_reporting_errors", "debug_requested", "describe",
           "exit_code", "with_error_handling"]

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as shells report Ctrl-C

_ENV_ERRNOS = {
    errno.EACCES: "permission denied; choose a folder you can write (hydra.run.dir=... or --out)",
    errno.EPERM: "operation not permitted; choose a folder you can write (hydra.run.dir=... or --out)",
    errno.EROFS: "the file system is read-only; choose a writable folder (hydra.run.dir=... or --out)",
    errno.ENOSPC: "no space left on the device; free some space and run the same command again (finished "
                  "stages and checkpoints already on disk are kept)",
    errno.EDQUOT: "disk quota exceeded; free some space and run the same command again",
    errno.EFBIG: "file too large for this file system or process limit",
}


def debug_requested(argv: list[str] | None = None) -> bool:
    """True with ``ARCSEM_DEBUG=1`` or a ``debug=true`` (``+debug=true``, ``--debug``) argument."""
    if os.environ.get("ARCSEM_DEBUG", "") not in ("", "0", "false", "False"):
        return True
    argv = sys.argv[1:] if argv is None else argv
    return any(a.lstrip("+~").lower() in ("debug=true", "debug=1", "debug=yes") or a == "--debug" for a in argv)


def exit_code(exc: BaseException) -> int | None:
    """The exit code of an error the user can cause or fix, or None for a bug (keep the traceback)."""
    if isinstance(exc, (KeyboardInterrupt, Interrupted)):
        return EXIT_INTERRUPTED
    if isinstance(exc, config_error_types()):
        return EXIT_USER_ERROR
    if isinstance(exc, OSError) and exc.errno in _ENV_ERRNOS:
        return EXIT_USER_ERROR
    return None


def _unknown_schema_key(exc: BaseException) -> str | None:
    """For a key missing from a Hydra schema (a typo): the key and the schema's keys, without Hydra's hint
    to append it with ``+`` (which would only move the error to the run's own check)."""
    import dataclasses

    from omegaconf.errors import ConfigAttributeError, ConfigKeyError

    cause = exc
    while cause is not None and not isinstance(cause, (ConfigAttributeError, ConfigKeyError)):
        cause = cause.__cause__ or cause.__context__
    schema = getattr(cause, "object_type", None)
    if cause is None or schema is None or not dataclasses.is_dataclass(schema):
        return None
    keys = ", ".join(f.name for f in dataclasses.fields(schema))
    return f"{cause.full_key}: unknown key; valid keys: {keys}"


def _unparsable_override(exc: BaseException) -> str | None:
    """For an override Hydra's grammar cannot read (a non-ASCII letter in a path: ``LexerNoViableAltException``):
    the override and how to quote its value."""
    from hydra.errors import OverrideParseException

    if not isinstance(exc, OverrideParseException) or "NoViableAlt" not in str(exc) or "=" not in exc.override:
        return None
    key, value = exc.override.split("=", 1)
    return (f"{exc.override}: Hydra's override grammar does not take this value unquoted (a non-ASCII letter or "
            f"another special character); quote it, in a shell: \"{key}='{value}'\"")


def _missing_option(exc: BaseException) -> str | None:
    """For a config group option that does not exist (``backbone=gs4d``): the option, the nearest name and the
    group's options, without the schemas Hydra lists among them (``gs2d_schema``) or its search path."""
    import difflib

    from hydra.errors import MissingConfigException

    missing = getattr(exc, "missing_cfg_file", None)
    if not isinstance(exc, MissingConfigException) or not missing or "/" not in missing or exc.options is None:
        return None
    group, name = missing.rsplit("/", 1)
    options = [o for o in exc.options if not o.endswith("_schema")]
    near = difflib.get_close_matches(name, options, n=1)
    hint = f"did you mean {group}={near[0]}? " if near else ""
    return f"{group}={name}: no such option; {hint}available: {', '.join(options) or 'none'}"


def _preset_on_a_run(exc: BaseException) -> str | None:
    """``preset=quick`` on a single run (presets are chosen in the studies' defaults): what a run takes instead."""
    import re

    from hydra.errors import ConfigCompositionException

    found = re.search(r"Could not override 'preset'\. No match.*use \+preset=(\S+)", str(exc), re.DOTALL)
    if not isinstance(exc, ConfigCompositionException) or found is None:
        return None
    v = found.group(1)
    return (f"preset={v}: a preset is chosen on a study (experiment=<study> preset={v}); a single run takes "
            f"train={v} colorize={v} (quick: the default), or +preset={v}")


def describe(exc: BaseException) -> str:
    """The one-line message for a user-facing error (see :func:`exit_code`)."""
    unknown = _unknown_schema_key(exc) or _unparsable_override(exc) or _missing_option(exc) or _preset_on_a_run(exc)
    if unknown:
        return unknown
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted (Ctrl-C)"
    if isinstance(exc, OSError) and exc.errno in _ENV_ERRNOS:
        where = exc.filename or "a file"
        return f"cannot write {where}: {_ENV_ERRNOS[exc.errno]}"
    return one_line(exc)


def call_reporting_errors(call: Callable[[], Any], debug: bool = False, prefix: str = "") -> Any:
    """``call()``; a user error prints one ``error:`` line (after ``prefix``) and returns its exit code."""
    debug = debug or debug_requested([])
    try:
        return call()
    except BaseException as exc:
        code = exit_code(exc)
        if code is None or debug:
            raise
        print(f"error: {prefix}{describe(exc)}", file=sys.stderr, flush=True)
        return code


def with_error_handling(func: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a console-script ``main``: user errors print one ``error:`` line and exit with their code."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        debug = debug_requested()
        if not debug:
            os.environ.setdefault("HYDRA_FULL_ERROR", "1")  # Hydra re-raises; we print the one line
        result = call_reporting_errors(lambda: func(*args, **kwargs), debug)
        if isinstance(result, int) and not isinstance(result, bool) and result in (EXIT_USER_ERROR, EXIT_INTERRUPTED):
            sys.exit(result)
        return result

    return wrapper
