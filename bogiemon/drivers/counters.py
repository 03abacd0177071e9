"""Every counter a driver keeps beyond HealthCounters' own (drivers/base.py), in one table: its
name as the daemon's log, `systemctl status` and the MQTT status carry it (HealthCounters.extra),
and what it counts. Each driver names the ones it keeps with `counters(...)`."""

from __future__ import annotations

COUNTERS: dict[str, str] = {
    # Live sources (drivers/live.py): the device's cycle.
    "disconnects": "the device failed under the source (the bus or interface went away, the adapter was unplugged)",
    "open_failures": "attempts to (re)open the device that failed",
    # Sequence numbers (CAN frame counters, serial packet numbers).
    "duplicates": "a frame or packet with the sequence number of the one just accepted: dropped",
    "out_of_order": "a frame or packet whose sequence number is behind the last accepted one: dropped",
    "lost_samples": "sampling instants missing inside sequence jumps (a lower bound)",
    # The serial packet stream.
    "crc_errors": "sync words followed by a packet whose CRC fails (also bad_frames)",
    "garbage_bytes": "bytes skipped while resynchronising",
    # CAN frames.
    "unknown_ids": "frames whose identifier is in no message of the DBC, or no CAN identifier (also bad_frames)",
    "other_dbc_frames": "frames of the DBC's other messages (alarms, heartbeats): expected, ignored",
    "wrong_length": "a layout identifier with the wrong data length (also bad_frames)",
    "remote_frames": "remote-request frames (also bad_frames)",
    "error_frames": "error frames the controller reported",
    "bus_off": "of the error frames, bus-off: the controller stopped sending and receiving",
    "rx_overflow": "of the error frames, the controller's own receive FIFO overflowed",
    "dropped_by_kernel": "frames the socket's receive buffer had no room for (socketcan)",
    # Time stamps (drivers/segments.py).
    "bad_timestamps": "frames whose time stamp is not finite, beyond MAX_TIME_S or behind (also bad_frames)",
    "clock_steps": "times the receive clock stepped back and the guard followed it",
    # Replays and recordings.
    "unreadable_entries": "log entries python-can could not parse (also bad_frames)",
    "clipped_samples": "samples beyond the converter's range, clipped to its full scale",
    "resampled_samples": "samples of a recording with jittered time stamps, interpolated onto its nominal grid",
    "recording_gaps": "gaps in a recording's time stamps (samples missing): a new segment starts after each",
}


def counters(*names: str) -> tuple[str, ...]:
    """The names a driver keeps, each one of COUNTERS (a KeyError names a counter missing from it)."""
    for name in names:
        if name not in COUNTERS:
            raise KeyError(f"counter '{name}' is not in drivers/counters.py's table")
    return names
