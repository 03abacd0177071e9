"""`bogiemon check-config [FILE] [--reference]`: validate a config file and print it resolved, defaults filled in.

Validation builds what `run` builds (the core's settings at the configured rate, the decision
and its models): a file it accepts, the service starts and a reload applies. Warnings (credential
files others can read, a password in clear) come first, as comment lines. --reference prints the
reference of every field (bogiemon/daemon/config_reference.py) instead.
"""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("check-config", help="validate a config file and print the resolved config")
    p.add_argument("file", nargs="?", help="the config file (default: the shipped default config)")
    p.add_argument("--reference", action="store_true", help="print the reference of every section and field instead (docs/configuration.md)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.reference:
        from bogiemon.daemon.config_reference import reference_text

        print(reference_text(), end="")
        return 0
    from bogiemon.daemon import tomlout
    from bogiemon.daemon.config import load_config

    config = load_config(args.file, log_warnings=False)  # printed here, where the reader looks
    print(f"# {args.file or 'default config'}: valid (digest {config.digest()})")
    for warning in config.credential_warnings():
        print(f"# warning: {warning}")
    print(tomlout.dumps(config.model_dump(mode="json", exclude_none=True)), end="")
    return 0
