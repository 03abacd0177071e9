"""The `bogiemon` command: parses the command line and hands over to one module per command.

Start-up is a feature on a gateway (and in a small VM on a test bench): this module and the
command modules import only argparse at the top; each command imports its library when it runs,
so `bogiemon run` never loads the offline lab, the simulator or a plotting library.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from bogiemon.cli import analyze, calibrate, check_config, convert, demo, evaluate, events, fleet, listen, play, replay, run, simulate, study

COMMANDS = (run, demo, replay, analyze, calibrate, events, check_config, simulate, study, evaluate, fleet, play, listen, convert)
# Errors a user can cause: one line on stderr and exit status 2, never a traceback. Named, not
# imported, so that the command line loads only the command it runs; a test resolves every name.
USER_ERRORS: frozenset[str] = frozenset(
    {
        "bogiemon.daemon.calibrate.CalibrationError",
        "bogiemon.daemon.config_sections.ConfigError",
        "bogiemon.daemon.delivery.connection.CredentialsError",
        "bogiemon.daemon.delivery.listener.ListenError",
        "bogiemon.judgement.models.ModelError",
        "bogiemon.daemon.store_file.StoreError",
        "bogiemon.fleet.layout.FleetError",
        "bogiemon.fleet.judge.JudgeError",
        "bogiemon.fleet.judged_files.ReportError",
        "bogiemon.drivers.candb.DbcError",
        "bogiemon.drivers.player.PlayError",
        "bogiemon.drivers.recording_format.RecordingError",
        "bogiemon.simulator.errors.SimulationError",
        "bogiemon.lab.robust.evaluate.EvaluateError",
        "bogiemon.lab.fleetsim.FleetSimError",
        "bogiemon.cli.events.TimeArgumentError",
        "bogiemon.cli.study.StudyError",
    }
)
EXIT_USER_ERROR = 2
# The packages of pyproject.toml's extras, which a gateway's install leaves out (docs/gateway.md):
# a command that needs one says which extra brings it, in one line.
EXTRA_OF_PACKAGE = {
    "pyarrow": "recordings",
    "numba": "sim",
    "scipy": "sim",
    "matplotlib": "report",
    "dask": "fleet",
    "distributed": "fleet",
}


def missing_extra(exc: ModuleNotFoundError) -> str | None:
    """The line saying which extra to install for a package an extra brings; None for any other."""
    package = (exc.name or "").split(".")[0]
    extra = EXTRA_OF_PACKAGE.get(package)
    if extra is None:
        return None
    return f"this command needs {package}, which this install leaves out: pip install 'bogiemon[{extra}]'"


def is_user_error(exc: BaseException) -> bool:
    """Whether exc is (a subclass of) one of USER_ERRORS."""
    return any(f"{cls.__module__}.{cls.__qualname__}" in USER_ERRORS for cls in type(exc).__mro__)


def build_parser() -> argparse.ArgumentParser:
    from bogiemon import __version__  # the package's __init__: nothing else is imported

    parser = argparse.ArgumentParser(
        prog="bogiemon",
        description="Condition monitoring of Y25 freight-wagon primary suspensions.",
    )
    parser.add_argument("--version", action="version", version=f"bogiemon {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except BrokenPipeError:  # e.g. `bogiemon analyze ... | head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        return 130
    except ModuleNotFoundError as exc:
        line = missing_extra(exc)
        if line is None:
            raise
        print(f"bogiemon: error: {line}", file=sys.stderr)
        return EXIT_USER_ERROR
    except Exception as exc:
        if not is_user_error(exc):
            raise
        from bogiemon.drivers.quoting import printable  # a message may quote a file: nothing in it for the terminal to act on

        print(f"bogiemon: error: {printable(str(exc))}", file=sys.stderr)
        return EXIT_USER_ERROR


if __name__ == "__main__":
    sys.exit(main())
