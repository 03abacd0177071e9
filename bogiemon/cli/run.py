"""`bogiemon run [--config F] [--load auto|full|tare]`: the service (systemd Type=notify, or by hand)."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("run", help="run the monitoring service")
    p.add_argument("--config", help="config file (default: the shipped default config)")
    p.add_argument("--load", choices=("auto", "full", "tare"), help="load state, overriding decision.load (auto: estimated from the signals)")
    p.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.logs import configure_logging
    from bogiemon.daemon.service import Service
    from bogiemon.daemon.sources import open_service_source

    configure_logging(level=args.log_level)
    service = Service(args.config, open_service_source, load=args.load)
    service.install_signal_handlers()
    return service.run()
