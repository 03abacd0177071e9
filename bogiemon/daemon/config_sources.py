"""The [source] section: one model per kind of source (CAN, serial ADC, a replayed recording, the
bundled simulator), chosen by its `kind` field (docs/drivers.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, Discriminator, Field, Tag, model_validator

from bogiemon.daemon.config_sections import Section

if TYPE_CHECKING:
    from bogiemon.drivers.columns import ColumnMap

_LAYOUT = "The frame layout: \"hub\" (one SensorHub frame per instant) or \"per-node\" (SensorNode1..3 answering Sync)."
_DBC = "The DBC file describing the layouts; empty: the shipped config/bogiemon.dbc."
_INTERFACE = (
    "The python-can interface: \"socketcan\" on the gateway (can0, or vcan0 on a bench), \"virtual\" for "
    "python-can's in-process bus (tests, demos). Every setting is passed explicitly: python-can reads no "
    "~/.canrc and no CAN_* environment variable."
)


class _SourceSection(Section):
    """Settings every source kind has."""

    max_block_s: float = Field(1.0, gt=0, le=10.0, description="Seconds of samples one read hands downstream at most (blocks also end at gaps and timeouts).")


class _LiveSourceSection(_SourceSection):
    # Waits are bounded: a thread's wait() takes at most about 49 days, and a retry storm of
    # microsecond backoffs helps no one.
    reconnect_backoff_min_s: float = Field(0.5, ge=0.01, le=3600, description=(
        "After the bus or device is lost, the first reopen attempt waits this many seconds; each failed "
        "attempt doubles the wait, up to reconnect_backoff_max_s."
    ))  # fmt: skip
    reconnect_backoff_max_s: float = Field(30.0, ge=0.01, le=3600, description="The longest wait between reopen attempts, in seconds (at least reconnect_backoff_min_s).")

    @model_validator(mode="after")
    def _backoff_order(self) -> _LiveSourceSection:
        if self.reconnect_backoff_min_s > self.reconnect_backoff_max_s:
            raise ValueError(
                f"reconnect_backoff_min_s ({self.reconnect_backoff_min_s}) must not exceed "
                f"reconnect_backoff_max_s ({self.reconnect_backoff_max_s})"
            )
        return self


class CanSourceConfig(_LiveSourceSection):
    """The sensor hub or nodes on a CAN bus."""

    kind: Literal["can"] = Field("can", description=(
        "Where the samples come from: \"can\" (the sensor hub or nodes on a CAN bus), \"serial\" (the "
        "serial ADC board), \"replay\" (a recording or a CAN log) or \"simulated\" (the bundled simulator "
        "on an in-process CAN bus: demos and tests). Each kind has its own fields."
    ))  # fmt: skip
    interface: Literal["socketcan", "virtual"] = Field("socketcan", description=_INTERFACE)
    channel: str = Field("can0", min_length=1, description="The network interface (socketcan) or channel name (virtual).")
    layout: Literal["hub", "per-node"] = Field("hub", description=_LAYOUT)
    dbc_path: str = Field("", description=_DBC)
    receive_buffer_bytes: int = Field(1_048_576, ge=4096, le=2**31 - 1, description=(  # SO_RCVBUF is a C int
        "Bytes of kernel receive buffer asked for the CAN socket: what absorbs a stalled reader (each "
        "frame costs several hundred bytes of it). Above net.core.rmem_max it needs CAP_NET_ADMIN."
    ))  # fmt: skip


class SerialSourceConfig(_LiveSourceSection):
    """A serial ADC board (sync word, sequence number, status, three int16 samples, CRC-16)."""

    kind: Literal["serial"] = Field(description="\"serial\".")
    port: str = Field("/dev/ttyUSB0", min_length=1, description="The serial device; prefer a stable /dev/serial/by-id/... name, which survives replugging.")
    baudrate: int = Field(115200, gt=0, le=12_000_000, description="Line speed in baud (8N1, no flow control); 500 Hz of 13-byte packets needs 65000.")


class ReplaySourceConfig(_SourceSection):
    """A recording replayed as if it came from the sensors."""

    kind: Literal["replay"] = Field(description="\"replay\".")
    path: str = Field(min_length=1, description=(
        "A recording (.csv, .csv.gz, .parquet) or a CAN log python-can reads (.log from candump -L, .asc, .blf)."
    ))  # fmt: skip
    realtime: bool = Field(True, description="true: at the recording's real-time pace; false: as fast as the daemon reads.")
    layout: Literal["hub", "per-node"] = Field("hub", description="For CAN logs: the frame layout, as for kind \"can\".")
    dbc_path: str = Field("", description="For CAN logs: the DBC file, as for kind \"can\".")
    unit: Literal["m/s^2", "g", "mm/s^2"] = Field("m/s^2", description=(
        "For recordings of samples: the unit of the accelerations. A file whose static levels say another unit (about 1: g; "
        "about 9810: mm/s^2) is refused, naming it."
    ))  # fmt: skip
    columns: str = Field("", description=(
        "For recordings of samples written by others: which columns are the time and the channels, as "
        "\"time=NAME,a1=NAME,a2=NAME,a3=NAME\" (pairs left out keep bogiemon's names; the time column by default the "
        "first of time_s, time, timestamp, ..., in s, or ms/us/ns as its name or Unix-time magnitude says)."
    ))  # fmt: skip

    @model_validator(mode="after")
    def _a_mapping(self) -> ReplaySourceConfig:
        from bogiemon.drivers.columns import parse_columns  # numpy and the standard library only

        parse_columns(self.columns)  # ValueError naming the pair that is wrong
        return self

    def column_map(self) -> ColumnMap:
        """The mapping and unit the recording is read with."""
        from bogiemon.drivers.columns import AccelUnit, ColumnMap, parse_columns

        return parse_columns(self.columns, ColumnMap(unit=AccelUnit(self.unit)))


class SimulatedSourceConfig(_SourceSection):
    """The bundled simulator on an in-process virtual CAN bus: the demo and the end-to-end tests.
    The samples go through the virtual bus and the real CAN decoder."""

    kind: Literal["simulated"] = Field(description="\"simulated\".")
    load: Literal["full", "tare"] = Field("full", description="The wagon's load state.")
    speed_kmh: float = Field(80.0, gt=0, le=200, description="Constant speed in km/h.")
    track: str = Field("erri-low", description="Track irregularity spectrum: perfect, erri-low, erri-high, fra-4, fra-5, fra-6.")
    # The whole run is simulated at open and held in memory (an hour at 500 Hz: 40 MiB).
    duration_s: float = Field(300.0, gt=0, le=3600, description="Seconds of running to simulate; the source ends after them.")
    seed: int = Field(0, ge=0, le=2**63 - 1, description="Seed of the track.")
    faults: list[str] = Field(default_factory=list, description="Faults, as `bogiemon simulate --fault`, e.g. [\"type_a:rear_outer:0.0@leading-left\"].")
    fault_at_s: float = Field(0.0, ge=0, description="The faults appear this many seconds into the run (0: from the start; before duration_s).")
    rate: float = Field(8.0, ge=0.01, le=10_000, description="Playback speed: 8 plays 8 simulated seconds per second.")
    channel: str = Field("bogiemon-sim", min_length=1, description="The in-process virtual CAN channel.")
    layout: Literal["hub", "per-node"] = Field("hub", description=_LAYOUT)
    dbc_path: str = Field("", description=_DBC)

    @model_validator(mode="after")
    def _a_scenario(self) -> SimulatedSourceConfig:
        # The simulator's own names and fault syntax (its two small modules, not the simulator).
        from bogiemon.simulator.errors import SimulationError
        from bogiemon.simulator.suspension import parse_fault
        from bogiemon.simulator.track import TRACKS

        if self.track not in TRACKS:
            raise ValueError(f"unknown track {self.track!r}: use one of {', '.join(TRACKS)}")
        for spec in self.faults:
            try:
                parse_fault(spec)
            except SimulationError as exc:
                raise ValueError(str(exc)) from None
        # As the simulator's Scenario checks them at open.
        if self.fault_at_s >= self.duration_s:
            raise ValueError(f"fault_at_s ({self.fault_at_s:g}) must lie before the end of the run, duration_s = {self.duration_s:g}")
        if self.fault_at_s > 0 and not self.faults:
            raise ValueError("fault_at_s needs a fault in faults")
        return self


def _source_kind(value: Any) -> str | None:
    """The [source] model's tag: its `kind`, "can" when a file leaves it out."""
    if isinstance(value, dict):
        return value.get("kind", "can")
    return getattr(value, "kind", None)


# [source] is one of four models, chosen by its `kind` field.
SourceConfig = Annotated[
    Annotated[CanSourceConfig, Tag("can")]
    | Annotated[SerialSourceConfig, Tag("serial")]
    | Annotated[ReplaySourceConfig, Tag("replay")]
    | Annotated[SimulatedSourceConfig, Tag("simulated")],
    Discriminator(
        _source_kind,
        custom_error_type="source_kind",
        custom_error_message="kind must be 'can', 'serial', 'replay' or 'simulated'",
    ),
]
SOURCE_KINDS: dict[str, type[BaseModel]] = {
    "can": CanSourceConfig,
    "serial": SerialSourceConfig,
    "replay": ReplaySourceConfig,
    "simulated": SimulatedSourceConfig,
}
