"""Benchmark of the drivers: the batch CAN decoder against cantools, and CPU per hour of 500 Hz data.

Figures (median of several runs, min and max): frames/s of the compiled numpy decoder and of
per-frame cantools decoding on the same frames, with their ratio from the same run; then the CPU
seconds each source spends per hour of 500 Hz data: CAN over python-can's virtual bus with a
player thread (reader and player measured separately with time.thread_time() inside each
thread; the reader also as it was before it coalesced its wake-ups, coalesce_s = 0, as the
baseline), serial through a real pseudo-terminal, and replay of a CSV and a candump log.
Run with `make bench-drivers` or `.venv/bin/python bench/bench_drivers.py [--runs R] [--seconds S]`.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

import can
import cantools
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from timing import Figure, table, time_interleaved  # noqa: E402

from bogiemon.drivers.base import EndOfStream, HealthCounters, Source  # noqa: E402
from bogiemon.drivers.can_decode import CanFrameDecoder  # noqa: E402
from bogiemon.drivers.can_source import CanBusPort, CanSource  # noqa: E402
from bogiemon.drivers.candb import load_layout, shipped_dbc_text  # noqa: E402
from bogiemon.drivers.player import encode_instants, open_player_bus, play, write_can_log  # noqa: E402
from bogiemon.drivers.recording import write_csv_recording  # noqa: E402
from bogiemon.drivers.replay import open_replay  # noqa: E402
from bogiemon.drivers.segments import SampleQueue  # noqa: E402
from bogiemon.drivers.serial_protocol import encode_packets  # noqa: E402
from bogiemon.drivers.serial_source import SerialSource  # noqa: E402

FS_HZ = 500.0
COMMAND = "make bench-drivers"


def accel(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((n, 3)) * 3 + 9.81


def hub_messages(n: int) -> list[can.Message]:
    layout = load_layout(None, "hub")
    return [
        can.Message(timestamp=i / FS_HZ, arbitration_id=fid, is_extended_id=ext, data=payload)
        for i, frames in enumerate(encode_instants(layout, accel(n)))
        for fid, ext, payload in frames
    ]


def decoder_figures(runs: int, n: int) -> list[Figure]:
    """Frames/s of the batch codec and decoder, each against per-frame cantools in the same run."""
    layout = load_layout(None, "hub")
    messages = hub_messages(n)
    payloads = np.frombuffer(b"".join(m.data for m in messages), np.uint8).reshape(n, 8)
    db = cantools.database.load_string(shipped_dbc_text(), database_format="dbc")

    def batch_payloads() -> None:  # the compiled codec alone, on an (n, 8) array
        layout.hub.decode(payloads)

    def batch_messages() -> None:  # the whole CAN path from python-can Messages to samples
        queue = SampleQueue(FS_HZ)
        CanFrameDecoder(layout, FS_HZ, HealthCounters(), queue).feed(messages)

    def per_frame_cantools() -> None:
        for m in messages:
            db.decode_message(m.arbitration_id, m.data, decode_choices=False)

    codec_s, decoder_s, cantools_s = time_interleaved([batch_payloads, batch_messages, per_frame_cantools], runs)
    baseline = Figure.of("cantools_frames_per_s", "per-frame cantools decode_message", "frames/s",
                         [n / s for s in cantools_s], COMMAND)  # fmt: skip
    codec = Figure.of("codec_frames_per_s", f"CAN batch codec on payload arrays ({n} hub frames)", "frames/s",
                      [n / s for s in codec_s], COMMAND)  # fmt: skip
    decoder = Figure.of("decoder_frames_per_s", "CAN batch decoder from python-can Messages", "frames/s",
                        [n / s for s in decoder_s], COMMAND)  # fmt: skip
    return [codec.compare(baseline), decoder.compare(baseline), baseline]


def drain_live(source: Source, n: int, timeout_s: float) -> tuple[int, float]:
    """Read n samples in this thread; (samples, this thread's CPU seconds)."""
    cpu0, got, end = time.thread_time(), 0, time.monotonic() + timeout_s
    while got < n and time.monotonic() < end:
        block = source.read(0.5)
        if block is not None:
            got += block.n_samples
    return got, time.thread_time() - cpu0


def cpu_can(seconds: float, layout_name: str, coalesce_s: float | None = None) -> tuple[float, float]:
    """(reader, player) CPU seconds per second of data, CAN over the virtual bus at real time."""
    layout = load_layout(None, layout_name)
    channel = f"bench-{layout_name}-{time.monotonic_ns()}"
    data = accel(int(seconds * FS_HZ))
    player_cpu: list[float] = []
    with CanSource(CanBusPort("virtual", channel), layout, FS_HZ, coalesce_s=coalesce_s) as source:
        bus = open_player_bus("virtual", channel)

        def player() -> None:
            cpu0 = time.thread_time()
            play(bus, layout, data, FS_HZ, rate=1.0)
            player_cpu.append(time.thread_time() - cpu0)

        thread = threading.Thread(target=player)
        thread.start()
        got, reader_cpu = drain_live(source, data.shape[0], seconds + 5)
        thread.join()
        bus.shutdown()
    assert got == data.shape[0], f"the CAN reader got {got} of {data.shape[0]} samples"
    return reader_cpu / seconds, player_cpu[0] / seconds


def cpu_serial(seconds: float) -> float:
    data = encode_packets(accel(int(seconds * FS_HZ)))
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        with SerialSource(os.ttyname(slave), 115200, FS_HZ) as source:

            def board() -> None:  # a 500 Hz board: 10 packets every 20 ms
                chunk, t0 = 13 * 10, time.monotonic()
                for i in range(0, len(data), chunk):
                    time.sleep(max(0.0, t0 + (i / 13) / FS_HZ - time.monotonic()))
                    view = memoryview(data[i : i + chunk])
                    while view:
                        view = view[os.write(master, view) :]

            thread = threading.Thread(target=board)
            thread.start()
            got, cpu_s = drain_live(source, len(data) // 13, seconds + 5)
            thread.join()
    finally:
        os.close(master)
        os.close(slave)
    assert got == len(data) // 13, f"the serial reader got {got} samples"
    return cpu_s / seconds


def cpu_replay(path: Path, data_s: float) -> float:
    layout = load_layout(None, "hub")
    cpu0 = time.thread_time()  # opening included: a CSV is parsed whole when opened
    source = open_replay(path, rate=0, layout=layout, fs_hz=FS_HZ)
    try:
        while True:
            source.read(1.0)
    except EndOfStream:
        pass
    return (time.thread_time() - cpu0) / data_s


def source_figures(runs: int, seconds: float) -> list[Figure]:
    """CPU seconds per hour of 500 Hz data of each source, live ones paced at real time."""
    hour = 3600.0
    out = []
    for layout_name in ("hub", "per-node"):
        # In turn, so that the reader and its baseline see the same machine.
        pairs = [(cpu_can(seconds, layout_name, coalesce_s=0.0), cpu_can(seconds, layout_name)) for _ in range(runs)]
        per_frame = [woken[0] for woken, _ in pairs]
        readers, players = [now[0] for _, now in pairs], [now[1] for _, now in pairs]
        woken = Figure.of(f"can_{layout_name}_reader_per_frame_cpu_s_per_h",
                          f"CAN {layout_name} reader woken per frame (coalesce_s = 0, as before)",
                          "CPU s/h", [c * hour for c in per_frame], COMMAND, higher_is_better=False)  # fmt: skip
        reader = Figure.of(f"can_{layout_name}_reader_cpu_s_per_h", f"CAN {layout_name} reader, virtual bus, 500 Hz",
                           "CPU s/h", [c * hour for c in readers], COMMAND, higher_is_better=False)  # fmt: skip
        player = Figure.of(f"can_{layout_name}_player_cpu_s_per_h", f"CAN {layout_name} player thread (not the daemon's)",
                           "CPU s/h", [c * hour for c in players], COMMAND, higher_is_better=False)  # fmt: skip
        out += [reader.compare(woken), woken, player]
    out.append(Figure.of("serial_cpu_s_per_h", "serial source through a pty, 500 Hz, 13-byte packets", "CPU s/h",
                         [cpu_serial(seconds) * hour for _ in range(runs)], COMMAND, higher_is_better=False))  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        data_s = 60.0
        data = accel(int(data_s * FS_HZ))
        write_csv_recording(Path(tmp) / "run.csv", np.arange(data.shape[0]) / FS_HZ, data)
        write_can_log(Path(tmp) / "run.log", load_layout(None, "hub"), data, FS_HZ, start_s=0.0)
        for suffix, what in (("csv", "CSV"), ("log", "candump .log, hub")):
            values = [cpu_replay(Path(tmp) / f"run.{suffix}", data_s) * hour for _ in range(runs)]
            out.append(Figure.of(f"replay_{suffix}_cpu_s_per_h", f"replay of a {what} file, unpaced (60 s file)", "CPU s/h",
                                 values, COMMAND, higher_is_better=False))  # fmt: skip
    return out


def figures(runs: int = 5, seconds: float = 10.0, frames: int = 20000) -> list[Figure]:
    return decoder_figures(runs, frames) + source_figures(max(3, runs // 2), seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs per figure (default 5)")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of live data per run (default 10)")
    parser.add_argument("--frames", type=int, default=20000, help="frames for the decoder figures (default 20000)")
    args = parser.parse_args()
    print(table(figures(args.runs, args.seconds, args.frames)))


if __name__ == "__main__":
    main()
