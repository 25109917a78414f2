"""One browser's render loop: a preview at an adaptive resolution while the camera moves, the full
resolution once it has rested for ``settle_s``.

:class:`AdaptiveResolution` is the policy (pure, tested on its own): the preview height is scaled
by ``sqrt(target_s / last render time)`` after every preview, so previews take about ``target_s``
whatever the model and the machine; the full-resolution frame is the browser canvas's height,
capped at ``max_height``. :class:`Session` runs it in a thread per client.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["AdaptiveResolution", "Session"]


@dataclass
class AdaptiveResolution:
    """Preview heights between ``min_height`` and the full height, aiming at ``target_s`` a frame."""

    target_s: float = 0.15
    min_height: int = 48
    max_height: int = 1024
    preview: int = 160

    def full(self, canvas_height: int) -> int:
        """The resting frame's height: the canvas's, at most ``max_height``."""
        return max(self.min_height, min(int(canvas_height), self.max_height))

    def moving(self, canvas_height: int) -> int:
        """The next preview's height."""
        return max(self.min_height, min(self.preview, self.full(canvas_height)))

    def record(self, height: int, seconds: float) -> None:
        """Adapt the preview height to the time a preview of ``height`` pixels took."""
        scale = math.sqrt(self.target_s / max(seconds, 1e-4))
        self.preview = int(max(self.min_height, min(height * min(scale, 2.0), self.max_height)))


class Session:
    """Renders for one client: ``state()`` reads its camera and settings, ``render(state, height)``
    makes a uint8 image, ``show(image)`` sends it. Call :meth:`changed` on every camera/GUI update."""

    def __init__(self, state: Callable[[], tuple], render: Callable[[tuple, int], np.ndarray],
                 show: Callable[[np.ndarray], None], canvas_height: Callable[[], int],
                 policy: AdaptiveResolution | None = None, settle_s: float = 0.3):
        self.state, self.render, self.show, self.canvas_height = state, render, show, canvas_height
        self.policy = policy or AdaptiveResolution()
        self.settle_s = settle_s
        self._event = threading.Event()
        self._stop = threading.Event()
        self._last_change = time.monotonic()
        self._full_done = False
        self.frames: list[tuple[int, bool]] = []  # (height, full?) of every frame sent, for tests and logs
        self.thread = threading.Thread(target=self._loop, daemon=True)

    def start(self) -> Session:
        self.thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._event.set()

    def changed(self) -> None:
        self._last_change = time.monotonic()
        self._full_done = False
        self._event.set()

    def step(self) -> bool:
        """Render one frame if one is due (a preview after a change, else the full frame once the
        camera has rested); returns whether a frame was sent."""
        moving = self._event.is_set()
        self._event.clear()
        canvas = self.canvas_height()
        if moving:
            height, full = self.policy.moving(canvas), False
        elif not self._full_done and time.monotonic() - self._last_change >= self.settle_s:
            height, full = self.policy.full(canvas), True
        else:
            return False
        t0 = time.perf_counter()
        image = self.render(self.state(), height)
        if not full:
            self.policy.record(height, time.perf_counter() - t0)
        self.show(image)
        self.frames.append((height, full))
        self._full_done = self._full_done or full
        return True

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._event.wait(timeout=self.settle_s / 3)
            if self._stop.is_set():
                break
            try:
                self.step()
            except Exception as exc:  # noqa: BLE001  (a client that went away must not kill the server)
                print(f"viewer: frame not rendered: {exc}", flush=True)
                time.sleep(0.5)
