"""A fixed-rate wall-clock loop on a background thread.

Tick ``k`` is due at ``t0 + k * period``. The loop calls ``tick()`` at each due time whatever
else the process is doing; it never bursts to catch up: when a tick runs later than one period
past its due time (the callback was slower than the period, or the thread was starved), the
schedule restarts from now and the tick counts as late. ``period`` is the control period of the
simulated robot divided by the real-time factor.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

logger = logging.getLogger(__name__)


class FixedRateLoop:
    """Calls ``tick()`` every ``period`` seconds of wall clock on a daemon thread.

    ``setup()`` runs on that thread before the first tick and ``teardown()`` after the last one,
    so that resources bound to a thread (a GL context) live on it alone. An exception raised by
    ``setup`` or ``tick`` stops the loop; it is kept in :attr:`error` and logged, and
    :meth:`start` re-raises one from ``setup``.
    """

    def __init__(
        self,
        tick: Callable[[], None],
        period: float,
        name: str = "fixed-rate-loop",
        setup: Callable[[], None] | None = None,
        teardown: Callable[[], None] | None = None,
    ):
        if not period > 0:
            raise ValueError(f"period must be > 0 s, got {period}")
        self._tick = tick
        self._setup, self._teardown = setup, teardown
        self._ready = threading.Event()
        self.period = float(period)
        self._name = name
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.ticks = 0
        self.late_ticks = 0
        self.error: BaseException | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        """Start the thread and wait until ``setup`` has finished (re-raising its error)."""
        if self.running:
            raise RuntimeError(f"{self._name} is already running")
        self._stop.clear()
        self._ready.clear()
        self.error = None
        self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
        self._thread.start()
        self._ready.wait()
        if self.error is not None:
            self._thread.join()
            self._thread = None
            raise RuntimeError(f"{self._name}: setup failed: {self.error}") from self.error

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        self._thread = None

    def _run(self) -> None:
        try:
            if self._setup is not None:
                self._setup()
        except BaseException as e:
            self.error = e
            logger.exception("%s: setup raised", self._name)
            return
        finally:
            self._ready.set()
        try:
            self._loop()
        finally:
            if self._teardown is not None:
                self._teardown()

    def _loop(self) -> None:
        due = time.perf_counter()
        while not self._stop.is_set():
            now = time.perf_counter()
            if now < due:
                if self._stop.wait(due - now):
                    break
            elif now - due > self.period:
                self.late_ticks += 1
                due = now
            try:
                self._tick()
            except BaseException as e:  # surfaced through `error` and the log
                self.error = e
                logger.exception("%s stopped: tick raised", self._name)
                break
            self.ticks += 1
            due += self.period
