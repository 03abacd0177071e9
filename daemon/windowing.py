"""The monitor's windowing rules, shared with the back office's re-analysis (fleet/).

Which block starts a new segment of the detection core and which counts as a gap for the
dropouts check, the gaps of the last hour, and the sensors' status bits over a window: the
onboard monitor and `bogiemon fleet` apply the same rules, so a fleet re-analysis judges what
the gateway judged.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings, WindowIndicators
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


@dataclass(frozen=True)
class Windowed:
    """One window of BlockWindows: the sensors' status bits over it and the gaps of the hour before it."""

    window: WindowIndicators
    status: tuple[SensorStatus, SensorStatus, SensorStatus]
    gaps_last_hour: int
    segment: int  # the number of the segment it lies in, from 0


class BlockWindows:
    """Blocks in, windows out, by the rules above: the detection core restarted at every new
    segment (a new one at a new rate, from processing_at(fs_hz)), the gaps and the status bits
    tracked. The monitor's and the back office's windowing, one copy."""

    def __init__(
        self, processing_at: Callable[[float], ProcessingSettings], geometry: BogieGeometry, clip_level_mps2: float, keep_starts: bool = False
    ) -> None:
        self.processing_at = processing_at
        self.geometry = geometry
        self.clip_level_mps2 = clip_level_mps2
        self.core: IndicatorStream | None = None
        self.spans = StatusSpans()
        self.gaps = GapMemory()
        self.segments = 0
        # (start_s, fs_hz) of every segment, with keep_starts (a day's analysis; a service running
        # for months keeps only the count).
        self.segment_starts: list[tuple[float, float]] = []
        self.keep_starts = keep_starts

    def feed(self, block: Block) -> list[Windowed]:
        new_segment, gap = segment_start(self.core.settings.fs_hz if self.core is not None else None, block)
        if new_segment:
            if self.core is None or self.core.settings.fs_hz != block.fs_hz:
                self.core = IndicatorStream(self.processing_at(block.fs_hz), self.geometry, block.start_s, self.clip_level_mps2)
            else:
                self.core.restart(block.start_s)
            self.segments += 1
            if self.keep_starts:
                self.segment_starts.append((block.start_s, block.fs_hz))
        if gap:
            self.gaps.add(block.start_s)
        self.spans.add(block)
        assert self.core is not None
        return [
            Windowed(w, self.spans.over(w.start_s, w.end_s), self.gaps.count_before(w.end_s), self.segments - 1)
            for w in self.core.process(block.accel_mps2)
        ]
