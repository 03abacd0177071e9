"""The `bogiemon` command: parses the command line and hands over to one module per command."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from bogiemon.daemon.calibrate import CalibrationError
from bogiemon.daemon.cli import analyze, calibrate, check_config, demo, evaluate, events, listen, play, replay, run, simulate, study
from bogiemon.daemon.config import ConfigError
from bogiemon.daemon.delivery.connection import CredentialsError
from bogiemon.daemon.evaluate import EvaluateError
from bogiemon.daemon.models import ModelError
from bogiemon.daemon.delivery.listener import ListenError
from bogiemon.daemon.store import StoreError
from bogiemon.drivers.candb import DbcError
from bogiemon.drivers.player import PlayError
from bogiemon.drivers.recording import RecordingError
from bogiemon.simulator.errors import SimulationError

COMMANDS = (run, demo, replay, analyze, calibrate, events, check_config, simulate, study, evaluate, play, listen)
# Errors a user can cause: one line on stderr and exit status 2, never a traceback.
USER_ERRORS: tuple[type[Exception], ...] = (
    CalibrationError,
    ConfigError,
    CredentialsError,
    DbcError,
    ListenError,
    ModelError,
    PlayError,
    RecordingError,
    SimulationError,
    StoreError,
    EvaluateError,
    events.TimeArgumentError,
    study.StudyError,
)
EXIT_USER_ERROR = 2


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bogiemon",
        description="Condition monitoring of Y25 freight-wagon primary suspensions.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except USER_ERRORS as exc:
        print(f"bogiemon: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except BrokenPipeError:  # e.g. `bogiemon analyze ... | head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
