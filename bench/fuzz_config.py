"""Fuzz target of the config loader: load_config on files with include lists, and what it accepts.

Configs start from the shipped config (with its comments), the demo's, small hand-written ones
and `bogiemon calibrate`'s fragment, and are damaged as trees (a value replaced by a huge, NaN,
infinite or boundary number, a wrong type, a strange string; a key dropped, renamed or added), as
lines or as bytes. Include lists name good fragments and bad ones: 5, [5], "\\u0000", /dev/zero, a
FIFO, a directory, the file itself, a missing file, one too big, a file outside the config's
folder by "..", by an absolute path or by a symlink. A config load_config accepts must be one
`run` can start with (its monitor settings, its detection core at the configured rate, its DBC),
and an include outside the folder must not be followed unless the config allows it.
"""

from __future__ import annotations

import datetime
import functools
import math
import os
import random
import re
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import fuzz_core
from bogiemon.daemon.config import load_config
from bogiemon.detection import IndicatorStream
from bogiemon.drivers.candb import load_layout

MAIN = "conf/bogiemon.toml"
ROOT_MARK = "{ROOT}"  # replaced by the input's directory when it runs: absolute paths that replay anywhere


@functools.cache
def shipped(name: str) -> str:
    return resources.files("bogiemon.config").joinpath(name).read_text(encoding="utf-8")


# ---- a TOML writer for mutated trees (tomllib only reads) ---------------------------------------


def _string(text: str) -> str:
    out = []
    for ch in text:
        code = ord(ch)
        if ch in '"\\':
            out.append("\\" + ch)
        elif code < 0x20 or code == 0x7F or 0xD800 <= code <= 0xDFFF:  # a surrogate escape is bad TOML: on purpose
            out.append(f"\\u{code:04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _string(key)


def toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, datetime.date):
        return value.isoformat()
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value if v is not None) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {toml_value(v)}" for k, v in value.items() if v is not None) + "}"
    return '""'


def toml_dumps(tree: Any) -> str:
    if not isinstance(tree, dict):
        return f"include = {toml_value(tree)}\n"
    lines: list[str] = []

    def table(node: dict[str, Any], path: list[str]) -> None:
        scalars = {k: v for k, v in node.items() if not isinstance(v, dict) and v is not None}
        tables = {k: v for k, v in node.items() if isinstance(v, dict)}
        if path:
            lines.append("[" + ".".join(_key(p) for p in path) + "]")
        for k, v in scalars.items():
            lines.append(f"{_key(k)} = {toml_value(v)}")
        for k, v in tables.items():
            table(v, [*path, k])

    table(tree, [])
    return "\n".join(lines) + "\n"


# ---- the inputs -----------------------------------------------------------------------------------

MINIMAL: tuple[dict[str, Any], ...] = (
    {},
    {"source": {"kind": "replay", "path": "run.csv", "realtime": False}},
    {"source": {"kind": "serial", "port": "/dev/ttyUSB0", "baudrate": 115200}},
    {"source": {"kind": "can", "layout": "per-node", "channel": "can0"}, "decision": {"method": "thresholds", "load": "tare"}},
    {"processing": {"fs_hz": 1000.0, "window_s": 60.0, "hop_s": 5.0}, "decision": {"method": "thresholds"}},
    {"wagon": {"id": "318045331234"}, "mqtt": {"enabled": True, "host": "broker.example", "tls_ca_file": "ca.pem"}},
    {"decision": {"thresholds": {"full": {"i4_norm": {"center": 0.0, "warning": 0.05, "alarm": 0.1}}}}},
)
FRAGMENT = {"decision": {"thresholds": {"full": {"i4_norm": {"center": 0.0003, "warning": 0.037, "alarm": 0.056}}}}}
# An include entry, and whether it reaches outside the config's folder (such a config allows it now and then).
INCLUDES: tuple[tuple[Any, bool], ...] = (
    ("cal.toml", False), ("frag.toml", False), ("sub/inner.toml", False), ("./frag.toml", False),
    ("../elsewhere/outside.toml", True), (ROOT_MARK + "/elsewhere/outside.toml", True), ("link.toml", True),
    ("/dev/zero", True), ("/dev/null", True), ("/etc/hostname", True), ("/proc/self/status", True),
    ("pipe.toml", False), ("sub", False), ("bogiemon.toml", False), ("missing.toml", False), ("big.toml", False),
    ("binary.toml", False), ("\u0000", False), ("", False), (".", False), ("x" * 5000, False), ("nested.toml", False),
    (5, False), (None, False), (True, False), (["frag.toml"], False),
)  # fmt: skip


def _main_tree(rng: random.Random) -> tuple[dict[str, Any] | None, str | None]:
    """A main config as a tree (to mutate as one) or as text (the shipped file, comments and all)."""
    choice = rng.random()
    if choice < 0.35:
        return None, shipped("bogiemon.toml")
    if choice < 0.45:
        return None, shipped("demo.toml")
    if choice < 0.75:
        return dict(rng.choice(MINIMAL)), None
    return tomllib.loads(shipped(rng.choice(("bogiemon.toml", "demo.toml")))), None


def generate(rng: random.Random) -> fuzz_core.Input:
    m = fuzz_core.Mutator(rng)
    tree, text = _main_tree(rng)
    includes: list[Any] | Any = []
    escapes = False
    if rng.random() < 0.5:
        picks = [rng.choice(INCLUDES) for _ in range(rng.choice((1, 1, 2, 3)))]
        includes = [p[0] for p in picks]
        escapes = any(p[1] for p in picks)
        if rng.random() < 0.01:
            includes = ["cal.toml"] * 1000
        elif rng.random() < 0.1:
            includes = picks[0][0]  # not a list at all: include = 5
    allow = escapes and rng.random() < 0.3
    if tree is not None:
        if includes != [] or rng.random() < 0.5:
            tree["include"] = includes
        if allow:
            tree["allow_absolute_includes"] = True
        if rng.random() < 0.8:
            tree = m.tree(tree)
        text = toml_dumps(tree)
    else:
        assert text is not None
        include_line = f"include = {toml_value(includes)}" + ("\nallow_absolute_includes = true" if allow else "")
        text = re.sub(r"^include = \[\]$", lambda _: include_line, text, count=1, flags=re.M) if "include = []" in text else include_line + "\n" + text
        if allow:
            text = re.sub(r"^allow_absolute_includes = false$", "", text, count=1, flags=re.M)
        if rng.random() < 0.7:
            text = m.lines(text, tokens=lambda line: _mutate_assignment(m, line))
    raw = text.encode("utf-8", "surrogatepass")
    if rng.random() < 0.1:
        raw = m.bytes(raw)
    fragment = FRAGMENT if rng.random() < 0.7 else m.tree(FRAGMENT)
    files = {
        MAIN: raw,
        "conf/cal.toml": shipped("demo_calibration.toml").encode(),
        "conf/frag.toml": toml_dumps(fragment).encode("utf-8", "surrogatepass"),
        "conf/sub/inner.toml": b'[decision]\nconfirm_k = 2\n',
        "conf/nested.toml": b'include = ["frag.toml"]\n',
        "elsewhere/outside.toml": b'[state]\ndirectory = "/tmp/bogiemon-fuzz-outside"\n',
        "conf/binary.toml": bytes(range(256)),
    }
    specials = {"conf/pipe.toml": "fifo", "conf/link.toml": "symlink:../elsewhere/outside.toml"}
    if "big.toml" in str(includes):
        specials["conf/big.toml"] = "big"  # made when the input runs: a saved input stays small
    return {"files": files, "specials": specials}


def _mutate_assignment(m: fuzz_core.Mutator, line: str) -> str:
    key, sep, _ = line.partition("=")
    if not sep:
        return m.garbage_line()
    value = m.strange_value()
    return f"{key}= {toml_value(value) if value is not None else m.number_text()}"


# ---- the run --------------------------------------------------------------------------------------


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    root = ctx.fresh_dir()
    for name, content in data["files"].items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(content.replace(ROOT_MARK.encode(), str(root).encode()))
    for name, kind in data["specials"].items():
        path = root / name
        if kind == "fifo":
            os.mkfifo(path)
        elif kind.startswith("symlink:"):
            path.symlink_to(kind.removeprefix("symlink:"))
        elif kind == "big":  # valid TOML, over the 1 MiB an include may have
            path.write_bytes(b"# " + b"x" * (2 << 20) + b"\n")
    config = load_config(root / MAIN)
    escaping = _escaping_includes(root / MAIN)
    if escaping:
        return f"an include outside the config's folder was followed, not allowed by the config: {escaping[0][:80]!r}"
    return run_can_start(config, ctx)


def _escaping_includes(main: Path) -> list[str]:
    """The include entries of the main file that resolve outside its folder, unless it allows them (the reference)."""
    try:
        tree = tomllib.loads(main.read_bytes().decode("utf-8-sig"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        return []
    includes = tree.get("include", [])
    if not isinstance(includes, list) or tree.get("allow_absolute_includes") is True:
        return []
    folder = main.parent.resolve()
    out = []
    for entry in includes:
        try:
            if isinstance(entry, str) and not (folder / entry).resolve().is_relative_to(folder):
                out.append(entry)
        except (OSError, ValueError):
            continue
    return out


def run_can_start(config: Any, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    """What `bogiemon run` builds at start from an accepted config, none of it opening a device."""
    try:
        settings = config.monitor_settings(None)
    except Exception as exc:  # noqa: BLE001 - any failure here is a config check-config should have refused
        return _cannot_start(exc)
    key = repr((settings.processing, settings.geometry, config.health.clip_level_mps2))
    cores: dict[str, str | None] = ctx.cache.setdefault("cores", {})
    if key not in cores:
        try:
            IndicatorStream(settings.processing, settings.geometry, 0.0, config.health.clip_level_mps2)
            cores[key] = None
        except Exception as exc:  # noqa: BLE001
            cores[key] = _cannot_start(exc)
        if len(cores) > 256:
            cores.pop(next(iter(cores)))
    if cores[key] is not None:
        return cores[key]
    source = config.source
    if source.kind in ("can", "simulated") or (source.kind == "replay" and not source.path.lower().endswith(".csv")):
        try:
            load_layout(source.dbc_path or None, source.layout)
        except Exception as exc:  # noqa: BLE001
            return _cannot_start(exc)
    if "\x00" in os.fspath(config.state.directory):
        return "check-config accepts, run cannot start (state.directory): a NUL byte in the path"
    return None


def _cannot_start(exc: BaseException) -> str:
    return f"check-config accepts, run cannot start ({type(exc).__name__}): {exc}"


TARGETS = [fuzz_core.Target("config", generate, run)]
