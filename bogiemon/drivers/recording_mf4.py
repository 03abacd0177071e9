"""MF4 files of signals (a logger's or a test bench's channels with their time master) read as a
recording: the channels of the mapping (a1, a2, a3 by default) from the one group holding them,
through asammdf a chunk of records at a time; times absolute from the file's start where it has
one. Bus-logging MF4 (CAN frames) is a CAN log instead (drivers/mf4.py, drivers/replay_can.py)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.columns import MAPPING_HINT, ColumnMap
from bogiemon.drivers.files import UntrustedFile
from bogiemon.drivers.mf4 import CHUNK_RECORDS, Mf4File, SignalGroup, open_mf4
from bogiemon.drivers.recording_check import RecordingReader
from bogiemon.drivers.recording_format import RecordingError


class Mf4RecordingReader(RecordingReader):
    """An MF4 of signals: its group found and its first and last times read at the open."""

    format = "mf4"

    def __init__(self, file: UntrustedFile, columns: ColumnMap | None = None) -> None:
        super().__init__(file, columns)
        self._mf4: Mf4File | None = None
        self._group: SignalGroup | None = None
        self._offset_s = 0.0

    def open(self, min_samples: int) -> None:
        mf4 = self._mf4 = open_mf4(self.file)
        if any(mf4.bus_groups().values()):
            self.error("an MF4 bus log (CAN frames), not a recording of signals: replay it, or convert it with bogiemon convert")
        names = tuple(c.column for c in self.columns.channels)
        try:
            group = self._group = mf4.signal_group(names)
        except RecordingError as exc:
            raise RecordingError(f"{exc}; {MAPPING_HINT}") from None
        # The file's start (its header's absolute time) makes the times absolute, else they are relative.
        self._offset_s = mf4.start_s or 0.0
        self.n_samples = group.records
        first_s = last_s = None
        if group.records:
            first_s = float(mf4.read_signals(group, 0, 1)[0][0]) + self._offset_s
            last_s = float(mf4.read_signals(group, group.records - 1, 1)[0][0]) + self._offset_s
        self._check_whole(min_samples, first_s, last_s)

    def where(self, row: int) -> str:
        return f"record {row + 1}"

    def close(self) -> None:
        if self._mf4 is not None:
            self._mf4.close()
        super().close()

    def _raw_chunks(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        mf4, group = self._mf4, self._group
        assert mf4 is not None and group is not None, "opened by open_recording_reader"
        for first in range(0, group.records, CHUNK_RECORDS):
            time_s, values = mf4.read_signals(group, first, min(CHUNK_RECORDS, group.records - first))
            yield time_s + self._offset_s, np.column_stack([np.asarray(v, dtype=np.float64) for v in values])
