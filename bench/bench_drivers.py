"""Benchmark of the drivers: the batch CAN decoder against cantools, and CPU per hour of 500 Hz data.

Figures (median of several runs, min and max): frames/s of the compiled numpy decoder and of
per-frame cantools decoding on the same frames, with their ratio from the same run; the per-node
aligner's numpy join against its frame-by-frame rules; then the CPU seconds each source spends per
hour of 500 Hz data, live ones paced at real time by a player thread (reader and player measured
separately with time.thread_time() inside each thread):

- CAN on the socketcan kind, the gateway's path: the source reads its bus's socket in batches
  (recvmmsg), against the same source reading the same socket through python-can's recv, a
  select, a recvmsg and a Message per frame (how it read SocketCAN before). This kernel has no
  AF_CAN: the socket is a UDP one carrying the kernel's struct can_frame datagrams with
  SO_TIMESTAMPNS stamps (tests/drivers/frames.py: DatagramCanBus, whose python-can receive code
  is SocketcanBus's own), the rest is the source as a gateway runs it.
- CAN on python-can's virtual bus (the tests', the demo's and bench_daemon's bus): python-can's
  recv, a Message per frame, from an in-process queue.
- serial through a real pseudo-terminal, and replay of a CSV and a candump log.

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
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import can
import can.interfaces.socketcan
import cantools
import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))
sys.path.insert(0, str(BENCH.parent))

from timing import Figure, table, time_interleaved  # noqa: E402

from bogiemon.drivers.base import EndOfStream, HealthCounters, Source  # noqa: E402
from bogiemon.drivers.can_decode import CanFrameDecoder, NodeAligner, max_silence_s  # noqa: E402
from bogiemon.drivers.can_frames import BusFrameReader, FrameReader  # noqa: E402
from bogiemon.drivers.can_source import CanBusPort, CanSource  # noqa: E402
from bogiemon.drivers.candb import load_layout, shipped_dbc_text  # noqa: E402
from bogiemon.drivers.player import encode_instants, open_player_bus, play, write_can_log  # noqa: E402
from bogiemon.drivers.recording import write_csv_recording  # noqa: E402
from bogiemon.drivers.replay import open_replay  # noqa: E402
from bogiemon.drivers.segments import SampleQueue  # noqa: E402
from bogiemon.drivers.serial_protocol import encode_packets  # noqa: E402
from bogiemon.drivers.serial_source import SerialSource  # noqa: E402
from tests.drivers.frames import DatagramCanBus, DatagramSender  # noqa: E402
from tests.drivers.test_node_aligner import FrameByFrame, as_arrays, instant_frames  # noqa: E402

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


def aligner_figures(runs: int, n: int) -> list[Figure]:
    """Node frames/s of the per-node aligner: its numpy join against its frame-by-frame rules (before)."""
    rng = np.random.default_rng(0)
    frames = [f for j in range(n) for f in instant_frames(j, j % 256, j / FS_HZ, rng.permutation(3).tolist())]
    batches = [as_arrays(frames[i : i + 750]) for i in range(0, len(frames), 750)]  # 0.5 s reads at 500 Hz

    def join(aligner_class: type[NodeAligner]) -> None:
        aligner = aligner_class(256, max_silence_s(256, FS_HZ))
        for batch in batches:
            aligner.push(*batch)

    numpy_s, per_frame_s = time_interleaved([lambda: join(NodeAligner), lambda: join(FrameByFrame)], runs)
    per_frame = Figure.of("aligner_per_frame_frames_per_s", "per-node aligner frame by frame (before)", "frames/s",
                          [len(frames) / t for t in per_frame_s], COMMAND)  # fmt: skip
    joined = Figure.of("aligner_frames_per_s", "per-node aligner, numpy join of 0.5 s batches", "frames/s",
                       [len(frames) / t for t in numpy_s], COMMAND)  # fmt: skip
    return [joined.compare(per_frame), per_frame]


def drain_live(source: Source, n: int, timeout_s: float) -> tuple[int, float]:
    """Read n samples in this thread; (samples, this thread's CPU seconds)."""
    cpu0, got, end = time.thread_time(), 0, time.monotonic() + timeout_s
    while got < n and time.monotonic() < end:
        block = source.read(0.5)
        if block is not None:
            got += block.n_samples
    return got, time.thread_time() - cpu0


class PythonCanRecvPort(CanBusPort):
    """The socketcan kind read as before: through python-can's recv, a Message per frame."""

    def frame_reader(self, bus: can.BusABC, capacity: int) -> FrameReader:
        return BusFrameReader(bus)


@contextmanager
def datagram_socketcan() -> Iterator[None]:
    """The socketcan kind opens a DatagramCanBus (this kernel has no AF_CAN)."""
    real = can.interfaces.socketcan.SocketcanBus
    can.interfaces.socketcan.SocketcanBus = DatagramCanBus  # type: ignore[misc]
    try:
        yield
    finally:
        can.interfaces.socketcan.SocketcanBus = real  # type: ignore[misc]
        DatagramCanBus.made.clear()


def cpu_can(seconds: float, layout_name: str, path: str) -> tuple[float, float]:
    """(reader, player) CPU seconds per second of data at real time; path: 'batched', 'python-can' or 'virtual'."""
    layout = load_layout(None, layout_name)
    data = accel(int(seconds * FS_HZ))
    player_cpu: list[float] = []
    with datagram_socketcan():  # the source opens its bus here
        if path == "virtual":
            channel = f"bench-{layout_name}-{time.monotonic_ns()}"
            source = CanSource(CanBusPort("virtual", channel), layout, FS_HZ)
            bus = open_player_bus("virtual", channel)
        else:
            port_class = CanBusPort if path == "batched" else PythonCanRecvPort
            # 4 MiB of socket buffer asked for (the kernel caps it at net.core.rmem_max), so that a
            # reader stalled on a shared machine does not lose frames.
            source = CanSource(port_class("socketcan", "bench", receive_buffer_bytes=1 << 22), layout, FS_HZ)
            bus = DatagramSender(DatagramCanBus.made[-1].address)
    with source:

        def player() -> None:
            cpu0 = time.thread_time()
            play(bus, layout, data, FS_HZ, rate=1.0)
            player_cpu.append(time.thread_time() - cpu0)

        thread = threading.Thread(target=player)
        thread.start()
        got, reader_cpu = drain_live(source, data.shape[0], seconds + 5)
        thread.join()
        bus.shutdown()
    assert got == data.shape[0], f"the CAN reader ({path}) got {got} of {data.shape[0]} samples: {source.counters.as_dict()}"
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
    paths = {  # key suffix (the virtual bus keeps the key it had, for comparing runs), what
        "batched": ("_socketcan_batched", "reader, socketcan kind, socket read in batches (recvmmsg)"),
        "python-can": ("_socketcan_python_can_recv", "reader, socketcan kind, python-can's recv per frame (before)"),
        "virtual": ("", "reader, virtual bus (python-can's recv)"),
    }
    for layout_name in ("hub", "per-node"):
        # In turn, so that the readers see the same machine.
        measured: dict[str, list[float]] = {path: [] for path in paths}
        players: list[float] = []
        for _ in range(runs):
            for path in paths:
                reader_s, player_s = cpu_can(seconds, layout_name, path)
                measured[path].append(reader_s * hour)
                if path == "virtual":
                    players.append(player_s * hour)
        figures = {
            path: Figure.of(f"can_{layout_name}_reader{suffix}_cpu_s_per_h", f"CAN {layout_name} {what}, 500 Hz",
                            "CPU s/h", measured[path], COMMAND, higher_is_better=False)  # fmt: skip
            for path, (suffix, what) in paths.items()
        }
        player = Figure.of(f"can_{layout_name}_player_cpu_s_per_h", f"CAN {layout_name} player thread, virtual bus (not the daemon's)",
                           "CPU s/h", players, COMMAND, higher_is_better=False)  # fmt: skip
        out += [figures["batched"].compare(figures["python-can"]), figures["python-can"], figures["virtual"], player]
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
    return decoder_figures(runs, frames) + aligner_figures(runs, frames // 3) + source_figures(max(3, runs // 2), seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs per figure (default 5)")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of live data per run (default 10)")
    parser.add_argument("--frames", type=int, default=20000, help="frames for the decoder figures (default 20000)")
    args = parser.parse_args()
    print(table(figures(args.runs, args.seconds, args.frames)))


if __name__ == "__main__":
    main()
