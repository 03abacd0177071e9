"""The pipeline's threads: a source thread fills the ring, a processing thread feeds the monitor.

Everything the daemon concludes happens in the processing thread (the monitor and its event
store); the source thread only reads and copies, so a slow disk or a burst of windows never
makes the source miss frames, and a stalled source never blocks the processing of what arrived.
The watchdog asks `last_progress_monotonic`: it moves only when a block passed through, or while
the source rests on purpose (a duty cycle, daemon/duty.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.ringbuffer import BlockRing, RingClosed
from bogiemon.daemon.store import StoreError
from bogiemon.drivers.base import EndOfStream, Source
from bogiemon.drivers.recording import RecordingError

READ_TIMEOUT_S = 0.5
# A source at rest (a duty cycle) is asked less often: its thread wakes every 2 s instead of twice
# a second, a standing wagon's daemon being mostly such wake-ups; a stop waits for it at most that.
REST_READ_TIMEOUT_S = 2.0
PR_SET_NAME = 15  # linux/prctl.h


def name_os_thread(name: str) -> None:
    """Give the calling thread its name in the kernel too (15 bytes), where `top -H`, `ps -L` and
    /proc/PID/task/TID/comm show it: which of the daemon's threads spends the CPU. Linux only;
    elsewhere, or if the call fails, the thread keeps the process's name."""
    import ctypes

    try:
        ctypes.CDLL(None).prctl(PR_SET_NAME, name.encode()[:15], 0, 0, 0)
    except (OSError, AttributeError):
        pass


# A live source this far behind real time (Source.behind_s: samples received and not yet handed
# on, beyond the block being filled) is said in the journal at warning, and once it has caught up
# at info with how far behind it was at most and for how long: after a burst of errors or a stall
# the keeper sees that data came late, and how late.
BEHIND_S = 1.0


class BehindWatch:
    """Tells the journal when a live source falls behind real time, and when it has caught up."""

    def __init__(self, log: Any, clock: Callable[[], float] = time.monotonic) -> None:
        self._log = log
        self._clock = clock
        self._since_s: float | None = None  # behind since then (the clock's time); None: in time
        self._most_s = 0.0

    def observe(self, behind_s: float) -> None:
        if self._since_s is None:
            if behind_s >= BEHIND_S:
                self._since_s, self._most_s = self._clock(), behind_s
                self._log.warning("the source fell behind real time", behind_s=round(behind_s, 3))
            return
        self._most_s = max(self._most_s, behind_s)
        if behind_s == 0.0:
            self._log.info(
                "the source caught up with real time", behind_at_most_s=round(self._most_s, 3),
                behind_for_s=round(self._clock() - self._since_s, 3),
            )  # fmt: skip
            self._since_s = None


class Pipeline:
    def __init__(self, source: Source, monitor: Monitor, ring: BlockRing) -> None:
        self.source = source
        self.monitor = monitor
        self.ring = ring
        self.last_progress_monotonic = time.monotonic()
        self.first_block = threading.Event()
        self.finished = threading.Event()  # the processing thread has ended
        self.error: BaseException | None = None  # an internal error that stopped a thread
        self._stop = threading.Event()
        self._monitor_lock = threading.Lock()
        self._log = get_logger(component="pipeline")
        self._threads = [
            threading.Thread(target=self._read_loop, name="bogiemon-source", daemon=True),
            threading.Thread(target=self._process_loop, name="bogiemon-core", daemon=True),
        ]

    def start(self) -> None:
        for thread in self._threads:
            thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop reading, process what the ring holds, and wait for both threads."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout_s)

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until a finite source is exhausted and processed; True if it was."""
        return self.finished.wait(timeout_s)

    def with_monitor(self, fn: Callable[[Monitor], object]) -> object:
        """Run fn on the monitor between two blocks (e.g. a reload from the main thread)."""
        with self._monitor_lock:
            return fn(self.monitor)

    def _read_loop(self) -> None:
        name_os_thread("bogiemon-source")
        behind = None if self.source.finite else BehindWatch(self._log)
        try:
            while not self._stop.is_set():
                try:
                    block = self.source.read(REST_READ_TIMEOUT_S if self.source.resting else READ_TIMEOUT_S)
                except EndOfStream:
                    break
                except RecordingError as exc:
                    # A recording that turns out bad further in (a streaming read finds a bad row
                    # late): the file's fault, not a bug. The windows before it were judged;
                    # whoever runs the pipeline names the file (replay: one line, exit 2).
                    self.error = exc
                    break
                if behind is not None:
                    behind.observe(self.source.behind_s())
                if block is None:
                    if self.source.resting:  # a duty cycle's rest: no data, on purpose, and no stall
                        self.last_progress_monotonic = time.monotonic()
                    continue
                stored = self.ring.put(block, timeout_s=READ_TIMEOUT_S)
                while not stored and self.ring.backpressure and not self._stop.is_set():
                    stored = self.ring.put(block, timeout_s=READ_TIMEOUT_S)
        except BaseException as exc:  # a bug in a driver: stop cleanly and let the service exit non-zero
            self.error = exc
            self._log.error("source thread failed", error=repr(exc))
        finally:
            self.ring.close()

    def _process_loop(self) -> None:
        name_os_thread("bogiemon-core")
        try:
            while True:
                try:
                    # No timeout: a block or the ring's closing wakes it, nothing else needs it.
                    block = self.ring.get(timeout_s=None)
                except RingClosed:
                    break
                if block is None:
                    continue
                with self._monitor_lock:
                    self.monitor.feed(block)
                self.last_progress_monotonic = time.monotonic()
                self.first_block.set()
        except StoreError as exc:
            # The event store refused what the monitor could not hold: a fault of the storage, not
            # a bug. Whoever runs the pipeline reports it: replay as one line, the service at crit.
            self.error = exc
            self._stop.set()
        except BaseException as exc:
            self.error = exc
            self._log.error("processing thread failed", error=repr(exc))
            self._stop.set()
        finally:
            self.finished.set()
