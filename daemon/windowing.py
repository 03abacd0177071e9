"""The monitor's windowing rules, shared with the back office's re-analysis (fleet/).

Which block starts a new segment of the detection core and which counts as a gap for the
dropouts check, the gaps of the last hour, and the sensors' status bits over a window: the
onboard monitor and `bogiemon fleet` apply the same rules, so a fleet re-analysis judges what
the gateway judged.
"""

from __future__ import annotations

from collections import deque

from bogiemon.drivers.base import Block, SensorStatus

GAP_MEMORY_S = 3600.0  # dropouts are judged over the last hour
ALL_OK = (SensorStatus.OK,) * 3


def segment_start(core_fs_hz: float | None, block: Block) -> tuple[bool, bool]:
    """(the block starts a new segment, it counts as a gap) for a core running at core_fs_hz
    (None: no core yet). A new rate starts a new core without counting a gap: it is another
    stream, not a lost stretch of this one."""
    if core_fs_hz is None or core_fs_hz != block.fs_hz:
        return True, False
    return block.gap_before, block.gap_before


class GapMemory:
    """The gaps of the last GAP_MEMORY_S seconds, counted before a time."""

    def __init__(self, memory_s: float = GAP_MEMORY_S, maxlen: int = 10_000) -> None:
        self.memory_s = memory_s
        self._times: deque[float] = deque(maxlen=maxlen)

    def add(self, time_s: float) -> None:
        self._times.append(time_s)

    def count_before(self, time_s: float) -> int:
        while self._times and self._times[0] < time_s - self.memory_s:  # windows only move on
            self._times.popleft()
        return sum(1 for t in self._times if t <= time_s)


class StatusSpans:
    """The sensors' status bits per block, OR-ed over the blocks a window overlaps."""

    def __init__(self, maxlen: int = 10_000) -> None:
        self._spans: deque[tuple[float, float, tuple[SensorStatus, ...]]] = deque(maxlen=maxlen)

    def add(self, block: Block) -> None:
        if any(block.status):
            self._spans.append((block.start_s, block.end_s, block.status))

    def over(self, start_s: float, end_s: float) -> tuple[SensorStatus, SensorStatus, SensorStatus]:
        while self._spans and self._spans[0][1] <= start_s:  # windows only move on
            self._spans.popleft()
        seen = [SensorStatus.OK] * 3
        for span_start_s, span_end_s, status in self._spans:
            if span_start_s < end_s and span_end_s > start_s:
                seen = [a | b for a, b in zip(seen, status, strict=True)]
        return (seen[0], seen[1], seen[2])
