"""What is asked of the service, by a signal or by another thread: stop (SIGTERM, SIGINT) or reload
(SIGHUP), by the book.

A handler only sets a flag and writes a byte to a pipe (a self-pipe): no lock, no Event.set(). A
Python signal handler runs in the main thread between two bytecodes, also inside
threading.Event.wait() while that holds the event's lock, and an Event.set() there waits for the
same lock forever: a burst of SIGHUPs once deadlocked the main thread (no reload, SIGTERM ignored,
the watchdog no longer pinged). The main thread sleeps on the pipe (wait), then reads the flags.

The stages: the handlers go in first thing in `bogiemon run` (before the config is read), so that a
signal during the start is the service's, never the default action's (SIGHUP's ends the process);
once the service stops, quiet() ignores them: Python's finalisation puts back the default action of
every signal with a handler of its own, and SIGHUPs arriving then killed the stopped daemon with
signal 1.
"""

from __future__ import annotations

import os
import select
import signal
from types import FrameType

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)
RELOAD_SIGNALS = (signal.SIGHUP,)
HANDLED = (*STOP_SIGNALS, *RELOAD_SIGNALS)


class Requests:
    """The service's stop and reload flags and the pipe that wakes its main thread."""

    def __init__(self) -> None:
        # Non-blocking both ends: a handler never blocks on a full pipe (a wake-up is pending then),
        # and the reader drains it without waiting.
        self._read_fd, self._write_fd = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._poll = select.poll()
        self._poll.register(self._read_fd, select.POLLIN)
        self.stop = False
        self.reload = False  # a reload asked for and not yet taken (take_reload)
        self.signals_received = 0
        self.installed = False  # the handlers are these flags' (install), or ignore the signals (quiet)

    # --- what a handler or another thread may call: plain stores and a write, nothing else --------

    def request_stop(self) -> None:
        self.stop = True
        self._wake()

    def request_reload(self) -> None:
        self.reload = True
        self._wake()

    def _wake(self) -> None:
        try:
            os.write(self._write_fd, b"\0")
        except OSError:  # full: a wake-up is already pending; closed: nobody waits any more
            pass

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self.signals_received += 1
        if signum in RELOAD_SIGNALS:
            self.request_reload()
        else:
            self.request_stop()

    # --- the main thread -----------------------------------------------------------------------

    def install(self) -> None:
        """Handle SIGTERM, SIGINT and SIGHUP here from now on (the main thread only, as Python requires)."""
        for signum in HANDLED:
            signal.signal(signum, self._on_signal)
        self.installed = True

    def quiet(self) -> None:
        """Once installed, ignore the three from now on: the service is stopping, and the
        interpreter's exit must not fall back to their default actions."""
        if self.installed:
            for signum in HANDLED:
                signal.signal(signum, signal.SIG_IGN)

    def wait(self, timeout_s: float) -> None:
        """Sleep until a request comes or timeout_s passes; what the pipe holds is read away."""
        if not (self.stop or self.reload):
            self._poll.poll(max(0, round(timeout_s * 1000)))  # a handler run meanwhile retries it (PEP 475)
        while True:
            try:
                if not os.read(self._read_fd, 4096):
                    return
            except (BlockingIOError, InterruptedError):
                return

    def take_reload(self) -> bool:
        """Whether a reload was asked for since the last take; a SIGHUP coming while the reload runs
        asks for the next one (a burst of them is one or two reloads, each of the newest file)."""
        if not self.reload:
            return False
        self.reload = False
        return True

    def close(self) -> None:
        for fd in (self._read_fd, self._write_fd):
            try:
                os.close(fd)
            except OSError:
                pass
