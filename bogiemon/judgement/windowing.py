"""The monitor's windowing rules, shared with the back office's analysis (fleet/).

Which block starts a new segment of the detection core and which start is a gap (samples lost:
the dropouts check counts it), the gaps of the last hour, and the sensors' status bits over a
window: the onboard monitor and `bogiemon fleet` apply the same rules, so a fleet re-analysis
judges what the gateway judged. A new stream (another recording, replayed or analysed after the
one before) starts a new segment and is never a gap: nothing was lost, the recordings are simply
apart.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings, WindowIndicators
from bogiemon.drivers.base import ALL_OK, Block, SensorStatus

GAP_MEMORY_S = 3600.0  # dropouts are judged over the last hour
Status = tuple[SensorStatus, SensorStatus, SensorStatus]


@dataclass(frozen=True)
class SegmentStart:
    """Where the detection core started afresh: at start_s, at fs_hz; gap: samples of the same
    stream were lost before it (a dropout of the source), not a new stream or a new rate."""

    start_s: float
    fs_hz: float
    gap: bool


class GapMemory:
    """The gaps of the last GAP_MEMORY_S seconds, counted before a time: the one gap count the
    sensor check reads (the monitor adds them as blocks arrive, `fleet judge` from a day's stored
    segment starts)."""

    def __init__(self, memory_s: float = GAP_MEMORY_S, maxlen: int = 10_000) -> None:
        self.memory_s = memory_s
        self._times: deque[float] = deque(maxlen=maxlen)

    def add(self, starts: Iterable[SegmentStart]) -> None:
        self._times.extend(s.start_s for s in starts if s.gap)

    def count_before(self, time_s: float) -> int:
        while self._times and self._times[0] < time_s - self.memory_s:  # windows only move on
            self._times.popleft()
        return sum(1 for t in self._times if t <= time_s)


class StatusSpans:
    """The sensors' status bits per block, OR-ed over the blocks a window overlaps."""

    def __init__(self, maxlen: int = 10_000) -> None:
        self._spans: deque[tuple[float, float, Status]] = deque(maxlen=maxlen)

    def add(self, block: Block) -> None:
        if any(block.status):
            self._spans.append((block.start_s, block.end_s, block.status))

    def over(self, start_s: float, end_s: float) -> Status:
        while self._spans and self._spans[0][1] <= start_s:  # windows only move on
            self._spans.popleft()
        seen = list(ALL_OK)
        for span_start_s, span_end_s, status in self._spans:
            if span_start_s < end_s and span_end_s > start_s:
                seen = [a | b for a, b in zip(seen, status, strict=True)]
        return (seen[0], seen[1], seen[2])


@dataclass(frozen=True)
class Windowed:
    """One window of BlockWindows: the sensors' status bits over it and the gaps of the hour before it."""

    window: WindowIndicators
    status: Status
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
        # Every segment's start, with keep_starts (a day's analysis; a service running for months
        # keeps only the count).
        self.segment_starts: list[SegmentStart] = []
        self.keep_starts = keep_starts
        self._new_stream = True

    def new_stream(self) -> None:
        """The next block begins another stream (the next recording): a new segment, not a gap."""
        self._new_stream = True

    def feed(self, block: Block) -> list[Windowed]:
        core = self.core
        new_stream = self._new_stream or block.new_stream
        if core is None or core.settings.fs_hz != block.fs_hz or new_stream or block.gap_before:
            # A gap is a loss within one stream at one rate; a new stream or a new rate is not.
            start = SegmentStart(block.start_s, block.fs_hz, gap=not new_stream and core is not None and core.settings.fs_hz == block.fs_hz)
            if core is None or core.settings.fs_hz != block.fs_hz:
                self.core = IndicatorStream(self.processing_at(block.fs_hz), self.geometry, block.start_s, self.clip_level_mps2)
            else:
                core.restart(block.start_s)
            self._new_stream = False
            self.segments += 1
            self.gaps.add((start,))
            if self.keep_starts:
                self.segment_starts.append(start)
        self.spans.add(block)
        assert self.core is not None
        return [
            Windowed(w, self.spans.over(w.start_s, w.end_s), self.gaps.count_before(w.end_s), self.segments - 1)
            for w in self.core.process(block.accel_mps2)
        ]
