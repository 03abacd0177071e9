"""Benchmark of the drivers: the batch CAN decoder against cantools, and CPU per second of 500 Hz data.

Prints frames/s of the compiled numpy decoder and of per-frame cantools decoding on the same
frames (median of several runs, min and max, and their ratio from the same run), then the CPU
seconds each source spends per second of 500 Hz data: CAN over python-can's virtual bus with a
player thread (reader and player measured separately with time.thread_time() inside each
thread), serial through a real pseudo-terminal, and replay of a CSV and a candump log.
Run with `make bench-drivers` or `.venv/bin/python bench/bench_drivers.py [--runs R] [--seconds S]`.
"""

from __future__ import annotations

import argparse
import os
import statistics
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

from timing import time_runs  # noqa: E402

from bogiemon.drivers.base import EndOfStream, HealthCounters, Source  # noqa: E402
from bogiemon.drivers.can_decode import CanFrameDecoder  # noqa: E402
from bogiemon.drivers.can_source import CanSource, VirtualBusPort  # noqa: E402
from bogiemon.drivers.candb import load_layout, shipped_dbc_text  # noqa: E402
from bogiemon.drivers.player import encode_instants, open_player_bus, play, write_can_log  # noqa: E402
from bogiemon.drivers.recording import write_csv_recording  # noqa: E402
from bogiemon.drivers.replay import open_replay  # noqa: E402
from bogiemon.drivers.segments import SampleQueue  # noqa: E402
from bogiemon.drivers.serial_protocol import encode_packets  # noqa: E402
from bogiemon.drivers.serial_source import SerialSource  # noqa: E402

FS_HZ = 500.0


def accel(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((n, 3)) * 3 + 9.81


def hub_messages(n: int) -> list[can.Message]:
    layout = load_layout(None, "hub")
    return [
        can.Message(timestamp=i / FS_HZ, arbitration_id=fid, is_extended_id=ext, data=payload)
        for i, frames in enumerate(encode_instants(layout, accel(n)))
        for fid, ext, payload in frames
    ]


def bench_decoder(runs: int, n: int) -> None:
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

    print(f"CAN decoding, {n} hub frames, {runs} runs (frames/s: median, min..max)")
    baseline = time_runs(per_frame_cantools, max(3, runs // 2))
    for label, fn in (("batch codec on payload arrays", batch_payloads), ("batch decoder from Messages", batch_messages)):
        t = time_runs(fn, runs)
        print(
            f"  {label:<38} {n / t.median_s:12.0f}  ({n / t.max_s:.0f}..{n / t.min_s:.0f})"
            f"  {baseline.median_s / t.median_s:6.1f}x cantools"
        )
    print(f"  {'per-frame cantools decode_message':<38} {n / baseline.median_s:12.0f}  ({n / baseline.max_s:.0f}..{n / baseline.min_s:.0f})")


def drain_live(source: Source, n: int, timeout_s: float) -> tuple[int, float]:
    """Read n samples in this thread; (samples, this thread's CPU seconds)."""
    cpu0, got, end = time.thread_time(), 0, time.monotonic() + timeout_s
    while got < n and time.monotonic() < end:
        block = source.read(0.5)
        if block is not None:
            got += block.n_samples
    return got, time.thread_time() - cpu0


def cpu_can(seconds: float, layout_name: str) -> tuple[float, float]:
    layout = load_layout(None, layout_name)
    channel = f"bench-{layout_name}-{time.monotonic_ns()}"
    data = accel(int(seconds * FS_HZ))
    player_cpu: list[float] = []
    with CanSource(VirtualBusPort(channel), layout, FS_HZ) as source:
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


def spread(values: list[float]) -> str:
    return f"{statistics.median(values) * 1e3:7.2f} ms/s  ({min(values) * 1e3:.2f}..{max(values) * 1e3:.2f}, {len(values)} runs)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs per figure (default 5)")
    parser.add_argument("--seconds", type=float, default=4.0, help="seconds of live data per run (default 4)")
    parser.add_argument("--frames", type=int, default=20000, help="frames for the decoder figures (default 20000)")
    args = parser.parse_args()
    bench_decoder(args.runs, args.frames)

    live_runs = max(3, args.runs // 2)
    print(f"\nCPU seconds per second of 500 Hz data (median, min..max), live sources paced at real time, {args.seconds:g} s each")
    for layout_name in ("hub", "per-node"):
        readers, players = zip(*(cpu_can(args.seconds, layout_name) for _ in range(live_runs)), strict=True)
        print(f"  CAN {layout_name:<8} reader (virtual bus)        {spread(list(readers))}")
        print(f"  CAN {layout_name:<8} player thread               {spread(list(players))}")
    print(f"  serial reader (pty, 13-byte packets)      {spread([cpu_serial(args.seconds) for _ in range(live_runs)])}")
    with tempfile.TemporaryDirectory() as tmp:
        data_s = 60.0
        data = accel(int(data_s * FS_HZ))
        write_csv_recording(Path(tmp) / "run.csv", np.arange(data.shape[0]) / FS_HZ, data)
        write_can_log(Path(tmp) / "run.log", load_layout(None, "hub"), data, FS_HZ, start_s=0.0)
        print(f"  replay CSV, unpaced ({data_s:g} s file)        {spread([cpu_replay(Path(tmp) / 'run.csv', data_s) for _ in range(live_runs)])}")
        print(f"  replay candump .log, unpaced, hub         {spread([cpu_replay(Path(tmp) / 'run.log', data_s) for _ in range(live_runs)])}")


if __name__ == "__main__":
    main()
