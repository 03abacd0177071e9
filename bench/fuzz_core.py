"""What every fuzz target shares: the target record, the per-input scratch space, saved inputs, the
checks of plausible values, and the mutations (bit flips, truncations, splices, extreme numbers,
wrong types, garbage lines, random bytes), all drawn from one seeded random.Random per input.

An input is a plain dict (JSON-able, bytes allowed) made by a target's generate(rng) from that rng
alone, so (seed, target, index) names it for good and a saved input replays without the seed.
"""

from __future__ import annotations

import base64
import json
import math
import os
import random
import shutil
import stat
import string
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

Input = dict[str, Any]
# A target's verdict on one input: None when the result is right (or a clear error was raised),
# else "kind: detail", the kind grouping the wrong results in the report.
Verdict = str | None

# A time a datetime can represent (years 1 to 9999): outside it an event cannot even be printed.
# Every time the sources deliver or the stores hold must be finite and inside it.
PLAUSIBLE_TIME_S = (-62_135_596_800.0, 253_402_300_799.0)
# A block may start this much before the previous one ended (clock jitter); more is time going back.
BACKWARD_TOLERANCE_S = 1.0
SQLITE_INT_RANGE = (-(2**63), 2**63 - 1)


class InputTimeout(BaseException):
    """One input ran past its time limit (a BaseException, so that no target's `except Exception` hides it)."""


@dataclass(frozen=True)
class Target:
    """One fuzz target: a generator of inputs and the run that feeds one input to the code under test.

    run returns None when the outcome is right, or "kind: detail" for a silently wrong result;
    an exception it lets through is a clear error or a crash, as fuzz.CLEAR_ERRORS says.
    """

    name: str
    generate: Callable[[random.Random], Input]
    run: Callable[[Input, Context], Verdict]


class Context:
    """Scratch space of one worker process: a fresh empty directory per input, on tmpfs if there is one."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.cache: dict[str, Any] = {}  # per-worker memo of a target's deterministic set-up

    def fresh_dir(self) -> Path:
        path = self.root / "input"
        if os.path.lexists(path):
            remove_tree(path)
        path.mkdir(parents=True)
        return path


def scratch_root(prefix: str) -> Path:
    """A new private directory under /dev/shm (files cost no disk I/O there), else the temp dir."""
    base = "/dev/shm" if os.access("/dev/shm", os.W_OK) else None
    return Path(tempfile.mkdtemp(prefix=prefix, dir=base))


def remove_scratch(pid: int) -> None:
    """Every scratch directory process pid made (scratch_root with a prefix naming it)."""
    for base in {Path("/dev/shm"), Path(tempfile.gettempdir())}:
        for leftover in base.glob(f"bogiemon-fuzz-{pid}-*"):
            remove_tree(leftover)


def remove_tree(path: Path) -> None:
    """rm -rf that also gets through what an input made unwritable or unreadable."""

    def fix(func: Callable[..., Any], name: str, _exc: Any) -> None:
        parent = os.path.dirname(name)
        for p in (parent, name):
            try:
                os.chmod(p, stat.S_IRWXU)
            except OSError:
                pass
        try:
            func(name)
        except OSError:
            pass

    if path.is_symlink() or path.is_file():
        path.unlink()
    else:
        shutil.rmtree(path, onerror=fix)  # onexc from Python 3.12 on


# ---- saved inputs: JSON with bytes as {"$b64": ...} ---------------------------------------------


def _encode(value: Any) -> Any:
    if isinstance(value, bytes | bytearray):
        return {"$b64": base64.b64encode(bytes(value)).decode("ascii")}
    if isinstance(value, dict):
        return {str(k): _encode(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_encode(v) for v in value]
    return value


def _decode(value: Any) -> Any:
    if isinstance(value, dict):
        if set(value) == {"$b64"}:
            return base64.b64decode(value["$b64"])
        return {k: _decode(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_decode(v) for v in value]
    return value


def dump_input(data: Input) -> str:
    # allow_nan: an input may hold NaN or infinity on purpose (Python's json reads them back).
    return json.dumps(_encode(data), allow_nan=True, separators=(",", ":"))


def load_input(text: str) -> Input:
    return _decode(json.loads(text))


def input_rng(seed: int, target: str, index: int) -> random.Random:
    """The one source of randomness of an input (a str seed is hashed with SHA-512: stable everywhere)."""
    return random.Random(f"bogiemon-fuzz/{seed}/{target}/{index}")


# ---- checks ---------------------------------------------------------------------------------


def implausible_time(time_s: float) -> bool:
    return not (isinstance(time_s, int | float) and math.isfinite(time_s) and PLAUSIBLE_TIME_S[0] <= time_s <= PLAUSIBLE_TIME_S[1])


def strict_json(text: str | bytes) -> Any:
    """json.loads that refuses NaN and Infinity, as strict JSON readers do; ValueError if not strict JSON."""

    def refuse(token: str) -> Any:
        raise ValueError(f"{token} is not JSON")

    return json.loads(text, parse_constant=refuse)


# ---- the mutations ----------------------------------------------------------------------------

INTERESTING_INTS = (0, 1, -1, 2, 7, 8, 9, 127, 128, 255, 256, 32767, 32768, 65535, 65536, 2**31 - 1, 2**31, 2**32,
                    2**53 + 1, 2**63 - 1, 2**63, 2**64, 2**70, -(2**31), -(2**63), -(2**63) - 1, 10**30)  # fmt: skip
INTERESTING_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 5e-324, 2.2250738585072014e-308, 1e-300, 1e-6, 0.01, 0.5,
                      1.0, 10.0, 333.33, 1e16, 1e300, -1e300, 1.7976931348623157e308, -1.0, 1.7e9)  # fmt: skip
# Numbers as text, each something a parser may read differently from its neighbour.
NUMBER_TEXTS = ("nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e309", "-1e309", "1e308", "1.7976931348623157e308",
                "4.9e-324", "5e-324", "1e-320", "0", "-0", "0.0", "-0.0", "1e16", "9007199254740993",
                "18446744073709551616", "1e300", "-1e300", "0x10", "1_000", "\u0661\u0662\u0663", "1.5 ", " 1.5", "+1.5",
                "1.", ".5", "1e", "e1", "--1", "", " ", "1,5", "1.0.0", "\x00", "0" * 400, "9" * 400, "1e-7", "12345678.9")  # fmt: skip
STRANGE_STRINGS = ("", " ", "\x00", "a\x00b", "\ud800", "\u202e", "é", "../../etc/passwd", "/dev/zero", "x" * 10_000,
                   "\n", "\t", "%s%n", "{}", "null", "NaN", "1e300", "\\", '"', "'")  # fmt: skip


class Mutator:
    """Mutations of bytes, text lines and JSON-like trees, drawn from one rng."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    # Bytes.

    def random_bytes(self, max_n: int = 64) -> bytes:
        return self.rng.randbytes(self.rng.randint(0, max_n))

    def bytes(self, data: bytes, n_mutations: int | None = None, donors: Sequence[bytes] = ()) -> bytes:
        """1-4 stacked byte-level mutations (a splice takes a piece of a donor)."""
        rng = self.rng
        out = bytearray(data)
        for _ in range(n_mutations or rng.randint(1, 4)):
            kind = rng.choice(("flip", "flip", "set", "insert", "delete", "duplicate", "truncate", "splice", "interesting", "zero_run"))
            n = len(out)
            at = rng.randint(0, n) if n else 0
            if kind == "flip" and n:
                i = rng.randrange(n)
                out[i] ^= 1 << rng.randrange(8)
            elif kind == "set" and n:
                out[rng.randrange(n)] = rng.choice((0x00, 0xFF, 0x7F, 0x80, 0x0A, 0x0D, 0x22, 0x2C, 0xC3, 0xA5, rng.randrange(256)))
            elif kind == "insert":
                out[at:at] = self.random_bytes(32)
            elif kind == "delete" and n:
                del out[at : at + rng.randint(1, 32)]
            elif kind == "duplicate" and n:
                start = rng.randrange(n)
                piece = out[start : start + rng.randint(1, 64)]
                out[at:at] = piece * rng.randint(1, 4)
            elif kind == "truncate" and n:
                del out[rng.randint(0, n - 1) :]
            elif kind == "splice" and donors:
                donor = rng.choice(donors)
                if donor:
                    start = rng.randrange(len(donor))
                    out[at:] = donor[start : start + rng.randint(1, 512)] + out[at:]
            elif kind == "interesting":
                out[at:at] = rng.choice((b"\x00" * 8, b"\xff" * 8, b"\xa5\x5a", b"\xef\xbb\xbf", b"\xc3", b"\xe2\x82", b"\r", b"\n\n", b"\x80"))
            elif kind == "zero_run" and n:
                start = rng.randrange(n)
                length = rng.randint(1, 128)
                out[start : start + length] = bytes(len(out[start : start + length]))
        return bytes(out)

    # Text.

    def garbage_line(self) -> str:
        rng = self.rng
        kind = rng.randrange(6)
        if kind == 0:
            return "".join(rng.choice(string.printable) for _ in range(rng.randint(0, 80)))
        if kind == 1:
            return self.random_bytes(40).decode("latin-1")
        if kind == 2:
            return "x" * rng.choice((1000, 100_000))
        if kind == 3:
            return rng.choice(("", " ", "\t", "\x00", "#", ";", "\ufeff", "\u2028"))
        if kind == 4:
            return ",".join(rng.choice(NUMBER_TEXTS) for _ in range(rng.randint(1, 8)))
        return rng.choice(NUMBER_TEXTS)

    def number_text(self) -> str:
        rng = self.rng
        if rng.random() < 0.7:
            return rng.choice(NUMBER_TEXTS)
        return repr(rng.choice(INTERESTING_FLOATS)) if rng.random() < 0.5 else str(rng.choice(INTERESTING_INTS))

    def lines(self, text: str, n_mutations: int | None = None, tokens: Callable[[str], str] | None = None) -> str:
        """1-3 stacked line-level mutations; tokens(line) rewrites one field of a line, if given."""
        rng = self.rng
        lines = text.split("\n")
        for _ in range(n_mutations or rng.randint(1, 3)):
            n = len(lines)
            i = rng.randrange(n)
            kind = rng.choice(("garbage", "delete", "duplicate", "swap", "token", "token", "token", "cut", "move", "blank"))
            if kind == "garbage":
                lines.insert(i, self.garbage_line())
            elif kind == "delete" and n > 1:
                del lines[i]
            elif kind == "duplicate":
                lines[i:i] = [lines[i]] * rng.randint(1, 3)
            elif kind == "swap" and i + 1 < n:
                lines[i], lines[i + 1] = lines[i + 1], lines[i]
            elif kind == "token" and tokens is not None:
                lines[i] = tokens(lines[i])
            elif kind == "cut":
                lines[i] = lines[i][: rng.randint(0, len(lines[i]))]
            elif kind == "move" and n > 2:
                lines.insert(rng.randrange(n), lines.pop(i))
            elif kind == "blank":
                lines.insert(i, "")
        end = rng.choice(("\n", "\n", "\n", "\r\n", "\r"))
        return end.join(lines)

    def replace_field(self, line: str, separators: str = ", ") -> str:
        """One whitespace- or comma-separated field of a line replaced by a strange number."""
        rng = self.rng
        sep = next((s for s in separators if s in line), None)
        if sep is None:
            return self.number_text()
        fields = line.split(sep)
        fields[rng.randrange(len(fields))] = self.number_text()
        return sep.join(fields)

    # Trees (JSON or TOML values).

    def strange_value(self) -> Any:
        rng = self.rng
        kind = rng.randrange(9)
        if kind == 0:
            return rng.choice(INTERESTING_INTS)
        if kind == 1:
            return rng.choice(INTERESTING_FLOATS)
        if kind == 2:
            return rng.choice(STRANGE_STRINGS)
        if kind == 3:
            return rng.choice((True, False))
        if kind == 4:
            return None
        if kind == 5:
            return rng.choice(([], [True, False], [None], [1, "a"], [[[]]], [1e300] * 3))
        if kind == 6:
            return rng.choice(({}, {"a": 1}, {"": None}))
        if kind == 7:
            return self.number_text()
        return [rng.choice(INTERESTING_INTS) for _ in range(rng.randint(0, 12))]

    def tree(self, value: Any, n_mutations: int | None = None, allow_none: bool = True) -> Any:
        """1-3 stacked mutations of a nested dict/list: a value replaced, a key deleted, renamed or added."""
        rng = self.rng
        root = json.loads(json.dumps(value))  # a deep copy made of dicts and lists
        for _ in range(n_mutations or rng.randint(1, 3)):
            paths = list(_paths(root))
            if not paths:
                return self.strange_value()
            path = rng.choice(paths)
            parent, key = _parent(root, path)
            kind = rng.choice(("replace", "replace", "replace", "delete", "rename", "add", "wrap"))
            if parent is None:
                root = self.strange_value()
                continue
            if kind == "replace":
                new = self.strange_value()
                if new is None and not allow_none:
                    new = ""
                parent[key] = new
            elif kind == "delete":
                del parent[key]
            elif kind == "rename" and isinstance(parent, dict):
                parent[rng.choice(("", key + "_", key.upper(), "schema", "seq", "x" * 300))] = parent.pop(key)
            elif kind == "add" and isinstance(parent, dict):
                parent[rng.choice(("extra", "include", "kind", "time_s", "\x00", "é"))] = self.strange_value()
            elif kind == "wrap":
                parent[key] = [parent[key]] if rng.random() < 0.5 else {"value": parent[key]}
        return root


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


def _parent(root: Any, path: tuple[Any, ...]) -> tuple[Any, Any]:
    if not path:
        return None, None
    node = root
    for part in path[:-1]:
        node = node[part]
    return node, path[-1]
