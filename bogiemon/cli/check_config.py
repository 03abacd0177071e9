"""`bogiemon check-config [FILE] [--reference]`: validate a config file as `run` starts it, and print it resolved.

Validation builds what `run` builds (the core's settings at the configured rate, the decision and
its models) and opens and parses every file the config names as `run` does at its start
(daemon/startup.py check_start: the includes, the models, the DBCs, the replayed recording, an
existing event store): a file it accepts, the service starts and a reload applies. Warnings
(credential files others can read or that cannot be used now, a password in clear) come first,
as comment lines; the digest covers the config and the files it names, as a reload compares them.
--reference prints the reference of every field (bogiemon/daemon/config_reference.py) instead.
"""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("check-config", help="validate a config file as run starts it and print the resolved config")
    p.add_argument("file", nargs="?", help="the config file (default: the shipped default config)")
    p.add_argument("--reference", action="store_true", help="print the reference of every section and field instead (docs/configuration.md)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.reference:
        from bogiemon.daemon.config_reference import reference_text

        print(reference_text(), end="")
        return 0
    from bogiemon.daemon import tomlout
    from bogiemon.daemon.config import load_config_and_files
    from bogiemon.daemon.startup import Snapshot, check_start

    config, files = load_config_and_files(args.file, log_warnings=False)  # warnings printed here, where the reader looks
    problems = check_start(config)
    snapshot = Snapshot.of(config, files)
    print(f"# {args.file or 'default config'}: valid (digest {config.digest()}; with the files it names {snapshot.digest})")
    for warning in [*config.credential_warnings(), *problems]:
        print(f"# warning: {warning}")
    print(tomlout.dumps(config.model_dump(mode="json", exclude_none=True)), end="")
    return 0
