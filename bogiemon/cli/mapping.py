"""--unit and --columns, shared by the commands that read recordings written by others (replay,
analyze, convert): the config's [source] as a replay of them, read with this unit and mapping."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bogiemon.daemon.config import BogiemonConfig

UNITS = ("m/s^2", "g", "mm/s^2")


def _columns(text: str) -> str:
    from bogiemon.drivers.columns import parse_columns

    try:
        parse_columns(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_mapping_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--unit", choices=UNITS, help="the unit of a recording's accelerations (default: the config's [source] unit, else m/s^2)")
    p.add_argument("--columns", type=_columns, metavar="time=NAME,a1=NAME,...",
                   help="which columns of a recording are the time and a1, a2, a3 (default: the config's [source] columns, else "
                        "time_s,a1,a2,a3; the time also as time, timestamp, ... in s, or ms/us/ns as its name says)")  # fmt: skip


def with_mapping(config: BogiemonConfig, args: argparse.Namespace) -> BogiemonConfig:
    """config whose replays read recordings with --unit and --columns (those not given: the
    config's): its [source] as a replay source of the same layout, DBC and block length."""
    if args.unit is None and args.columns is None:
        return config
    from bogiemon.daemon.config_sources import ReplaySourceConfig
    from bogiemon.daemon.sources import replay_source_config

    src = replay_source_config(getattr(config.source, "path", "-"), config)
    updates = {"unit": args.unit, "columns": args.columns}
    src = ReplaySourceConfig.model_validate({**src.model_dump(), **{k: v for k, v in updates.items() if v is not None}})
    return config.model_copy(update={"source": src})
