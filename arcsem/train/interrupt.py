"""Ctrl-C during training: finish the step in progress, write a checkpoint, stop.

Inside ``with stop:`` (``stop = StopRequest()``) the first SIGINT only sets ``stop.requested`` (the training loop
checks it after every step, saves and raises :class:`~arcsem.errors.Interrupted`); a second SIGINT
raises ``KeyboardInterrupt`` at once. Outside the main thread (where Python delivers no signals) it
does nothing.
"""
from __future__ import annotations

import signal
import sys
import threading
from types import FrameType
from typing import Any

__all__ = ["StopRequest"]


class StopRequest:
    """A context manager that turns the first Ctrl-C into a request to stop cleanly."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: Any = None

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:  # second Ctrl-C: stop now
            raise KeyboardInterrupt
        self.requested = True
        print("\nCtrl-C: stopping after this step and writing a checkpoint (Ctrl-C again to stop at once)",
              file=sys.stderr, flush=True)

    def __enter__(self) -> None:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None
