"""`bogiemon run [--config F] [--load auto|full|tare] [--state-dir D]`: the service (systemd Type=notify, or by hand)."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("run", help="run the monitoring service")
    p.add_argument("--config", help="config file (default: the shipped default config)")
    p.add_argument("--load", choices=("auto", "full", "tare"), help="load state, overriding decision.load (auto: estimated from the signals)")
    p.add_argument("--state-dir", help="the state directory (the event store), overriding the config's [state] directory")
    p.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.signals import Requests

    # First: a SIGHUP or SIGTERM from here on is the service's, also while it imports and starts
    # (SIGHUP's default action ends the process); from its stop to the exit they are ignored.
    requests = Requests()
    requests.install()
    try:
        from bogiemon.daemon.logs import configure_logging
        from bogiemon.daemon.service import Service
        from bogiemon.daemon.sources import open_service_source

        configure_logging(level=args.log_level)
        service = Service(args.config, open_service_source, load=args.load, state_dir=args.state_dir, requests=requests)
        return service.run()
    finally:
        requests.quiet()
