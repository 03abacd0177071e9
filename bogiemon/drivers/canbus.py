"""The one place that opens a python-can bus: an interface kind and a channel in, a bus out.

The kinds are a table (python-can's interface registry, `can.interfaces.BACKENDS`, is the
model): each names its interface class, imported when first used, and every setting it is given.
The class is instantiated directly, never through `can.Bus(...)`, so python-can reads no
~/.canrc, can.ini or CAN_* environment variable: what a gateway does must not depend on the files
or the environment of whoever starts it. The CAN source (receiver) and the player and the alarm
sender (senders) open their buses here; where their settings differ, the table says so and why.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # python-can itself loads with the interface class: the CLI lists KINDS cheaply
    import can


class BusRole(Enum):
    """What the bus is opened for; the few settings that depend on it are in BusKind."""

    RECEIVER = "receiver"  # the CAN source: reads every frame, sends nothing
    SENDER = "sender"  # the player, the alarm sender: sends, never reads
    # The simulated sensor hub: sends frames stamped with the hub's own clock. On the in-process
    # virtual bus those stamps are the receive times, so a sending thread the machine stalls does
    # not look like a silence of the bus; a real interface stamps at reception whatever is sent.
    STAMPED_SENDER = "stamped sender"


class UnknownBusKind(ValueError):
    """An interface kind the table has no entry for (the config and the CLI only offer known ones)."""


@dataclass(frozen=True)
class BusKind:
    """One python-can interface: its class, how messages name a channel, its settings."""

    module: str
    class_name: str
    description: str  # "{channel}" is replaced by the channel
    shared: Mapping[str, Any]  # the same for a receiver and a sender
    receiver: Mapping[str, Any]
    sender: Mapping[str, Any]
    stamped: Mapping[str, Any] = field(default_factory=dict)  # over sender's, for STAMPED_SENDER

    def interface_class(self) -> type[can.BusABC]:
        # Imported on first use: the SocketCAN module imports anywhere, but nothing needs it on
        # a process that only ever opens virtual buses.
        cls: type[can.BusABC] = getattr(importlib.import_module(self.module), self.class_name)
        return cls

    def settings(self, role: BusRole) -> dict[str, Any]:
        if role is BusRole.RECEIVER:
            return {**self.shared, **self.receiver}
        return {**self.shared, **self.sender, **(self.stamped if role is BusRole.STAMPED_SENDER else {})}


# Shared by both roles, on purpose:
# - receive_own_messages=False: the receiver sends nothing, and a sender never reads, so its own
#   frames would only pile up unread (on the virtual bus in an unbounded queue).
# - virtual rx_queue_size=0: an unbounded queue, as lossless as the tests need;
#   preserve_timestamps=False: a frame is stamped at sending, its receive time as on SocketCAN.
# - SocketCAN local_loopback=True: other sockets on this host (the daemon reading what the
#   player sends on vcan0, candump) see the frames sent here; fd=False: classical CAN, the
#   DBC's frames are at most 8 bytes; can_filters=None: every frame (the receiver counts the
#   foreign ones, a sender receives nothing it looks at).
# Different, on purpose:
# - ignore_rx_error_frames: the receiver asks for error frames (bus-off and controller overflows
#   end a segment, drivers/can_decode.py); a sender never reads, so the kernel need not queue
#   them for it.
# - The receive buffer (SO_RCVBUFFORCE) is the receiver's alone, and is set on the socket by its
#   port (drivers/can_source.py: CanBusPort), not here: it sizes how long the reader may be busy.
KINDS: Mapping[str, BusKind] = {
    "virtual": BusKind(
        module="can.interfaces.virtual",
        class_name="VirtualBus",
        description="virtual CAN channel '{channel}'",
        shared={"receive_own_messages": False, "rx_queue_size": 0, "preserve_timestamps": False},
        receiver={},
        sender={},
        stamped={"preserve_timestamps": True},
    ),
    "socketcan": BusKind(
        module="can.interfaces.socketcan",
        class_name="SocketcanBus",
        description="SocketCAN interface '{channel}'",
        shared={"receive_own_messages": False, "local_loopback": True, "fd": False, "can_filters": None},
        receiver={"ignore_rx_error_frames": False},
        sender={"ignore_rx_error_frames": True},
    ),
}


def bus_kind(kind: str) -> BusKind:
    """The table's entry for kind; UnknownBusKind (one line naming the known kinds) if none."""
    try:
        return KINDS[kind]
    except KeyError:
        known = " or ".join(f"'{name}'" for name in sorted(KINDS))
        raise UnknownBusKind(f"unknown CAN interface '{kind}': use {known}") from None


def bus_arguments(kind: str, channel: str, role: BusRole) -> dict[str, Any]:
    """Every keyword the interface class of kind is called with for channel and role."""
    return {"channel": channel, **bus_kind(kind).settings(role)}


def open_bus(kind: str, channel: str, role: BusRole) -> can.BusABC:
    """A new bus of kind on channel, set up for role.

    Raises what the interface raises when the channel is not there (OSError: ENODEV for a missing
    SocketCAN interface, EAFNOSUPPORT on a kernel without SocketCAN; can.CanError), and
    UnknownBusKind for a kind the table lacks.
    """
    return bus_kind(kind).interface_class()(**bus_arguments(kind, channel, role))
