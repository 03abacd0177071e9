"""The bench's regression guard: the daemon's figures against the last ones recorded on this machine class.

The daemon's absolute budget (2 % of a core) sits far above what it costs, so a regression that
doubles its CPU can pass it unnoticed (it did: 28 -> 69 CPU s/h in issue 16). The guard keeps
the last figure measured per machine class in bench/results/records.json (committed) and gives
each guarded figure a target just above it: at most TOLERANCE (25 %) more, and never above the
absolute budget. A figure past its target is MISSED, and bench_daemon.py and suite.py exit 1.

A machine class is the architecture, the CPU model and the number of cores: what sets a CPU
figure on an otherwise idle machine (the developers' 2-core EPYC and a gateway's ARM board are two
classes; two gateways of one model are one). A class without a record is judged against the
absolute budget alone, and the table says so.

Recording is an explicit step, `--record`, never automatic: it appends the figures measured (the
file is a history, the last entry of a class and figure is the one in force); a figure that
missed its target is recorded only with `--accept-worse` as well (a cost accepted in review),
and figures of a --quick run never.
"""

from __future__ import annotations

import json
import os
import platform
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from timing import Figure, format_value, table

REPO = Path(__file__).resolve().parents[1]
RECORDS_PATH = REPO / "bench" / "results" / "records.json"
FORMAT = 1
TOLERANCE = 0.25  # a figure more than this above the last recorded one is a regression
# The figures under guard: the daemon's CPU per feed and its peak memory (bench_daemon.py), the
# gateway's install, the peak memory of its `bogiemon run` on CAN, its standing hours and its day
# (bench_gateway.py), on a real kernel's vcan0 the CAN source's CPU against candump's and the peak
# memory of `bogiemon run` on CAN (bench_vcan.py), the CPU of `bogiemon analyze` of an hour as CSV
# and as Parquet (bench_core.py) and of `fleet analyze` per wagon-hour on one worker (bench_fleet.py).
GUARDED = (
    "daemon_can_cpu_s_per_h",
    "daemon_can_per_node_cpu_s_per_h",
    "daemon_replay_cpu_s_per_h",
    "daemon_replay_peak_rss_mb",
    "gateway_install_mb",
    "gateway_run_peak_rss_mib",
    "gateway_standing_cpu_s_per_h",
    "gateway_day_cpu_s",
    "gateway_day_cycled_cpu_s",
    "vcan_source_over_candump_cpu",
    "vcan_daemon_peak_rss_mib",
    "analyze_1h_cpu_s",
    "analyze_1h_parquet_cpu_s",
    "fleet_cpu_s_per_wagon_h",
)


class GuardError(RuntimeError):
    """The records file cannot be read or does not fit the figure (a message naming the file)."""


@dataclass(frozen=True)
class MachineClass:
    arch: str  # platform.machine(): x86_64, aarch64, armv7l
    cpu_model: str
    cores: int

    def label(self) -> str:
        return f"{self.arch}, {self.cpu_model}, {self.cores} cores"


def cpu_model_of(cpuinfo: str, device_model: str = "") -> str:
    """The CPU model from the text of /proc/cpuinfo: x86's "model name"; on ARM, where the kernel
    often gives none, the board's model (the device tree's), else the CPU's implementer and part."""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        name, sep, value = line.partition(":")
        if sep and name.strip().lower() not in fields:
            fields[name.strip().lower()] = value.strip()
    for key in ("model name", "hardware", "model"):
        if fields.get(key):
            return fields[key]
    if device_model.strip("\x00 \n"):
        return device_model.strip("\x00 \n")
    if "cpu implementer" in fields and "cpu part" in fields:
        return f"implementer {fields['cpu implementer']} part {fields['cpu part']}"
    return platform.processor() or "unknown"


def _read(path: str) -> str:
    try:
        return Path(path).read_text(errors="replace")
    except OSError:
        return ""


def machine_class() -> MachineClass:
    """This machine's class."""
    model = cpu_model_of(_read("/proc/cpuinfo"), _read("/proc/device-tree/model"))
    return MachineClass(platform.machine() or "unknown", model, os.cpu_count() or 1)


@dataclass(frozen=True)
class Record:
    """One recorded figure: where, what, how much, and from which run."""

    machine: MachineClass
    key: str
    unit: str
    median: float
    min: float
    max: float
    runs: int
    date: str  # ISO 8601, UTC
    commit: str
    command: str
    # The 1, 5 and 15 min load averages when it was recorded: a shared machine's figures are higher
    # and noisier (a record should come from a quiet one).
    load_average: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def as_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Record:
        machine = data["machine"]
        one, five, fifteen = (float(v) for v in data.get("load_average", (0.0, 0.0, 0.0))[:3])
        return cls(
            machine=MachineClass(str(machine["arch"]), str(machine["cpu_model"]), int(machine["cores"])),
            key=str(data["key"]), unit=str(data["unit"]), median=float(data["median"]), min=float(data["min"]),
            max=float(data["max"]), runs=int(data["runs"]), date=str(data["date"]), commit=str(data["commit"]),
            command=str(data["command"]), load_average=(one, five, fifteen),
        )  # fmt: skip


def load_records(path: Path = RECORDS_PATH) -> list[Record]:
    """The records in file order (oldest first); none when the file does not exist yet."""
    if not path.exists():
        return []
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if data.get("format") != FORMAT:
            raise GuardError(f"{path}: format {data.get('format')!r}, this bench reads format {FORMAT}")
        return [Record.from_json(r) for r in data["records"]]
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise GuardError(f"{path}: not a records file ({type(exc).__name__}: {exc}); restore it from git") from None


def save_records(records: list[Record], path: Path = RECORDS_PATH) -> None:
    """Write the records (whole file, then renamed into place: a crash leaves the old one)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps({"format": FORMAT, "tolerance": TOLERANCE, "records": [r.as_json() for r in records]}, indent=2) + "\n"
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(text, encoding="utf-8")
    partial.replace(path)


def last_record(records: list[Record], machine: MachineClass, key: str) -> Record | None:
    """The one in force for this class and figure: the last appended."""
    return next((r for r in reversed(records) if r.machine == machine and r.key == key), None)


def judge(figure: Figure, record: Record | None, machine: MachineClass, tolerance: float = TOLERANCE) -> Figure:
    """The figure with the guard's target: at most `tolerance` above the record (and within any
    absolute budget it has); without a record its own target stands and its note says so."""
    if figure.key not in GUARDED:
        return figure
    if record is None:
        note = f"no record for this machine class ({machine.label()}): `--record` keeps this figure as its baseline"
        return replace(figure, note="; ".join(p for p in (figure.note, note) if p))
    if record.unit != figure.unit:
        raise GuardError(f"{figure.key}: recorded in {record.unit}, measured in {figure.unit}")
    if figure.higher_is_better:
        raise GuardError(f"{figure.key}: the guard judges costs (lower is better)")
    limit = record.median * (1.0 + tolerance)
    budget = figure.target
    target = min(limit, budget) if budget is not None else limit
    parts = [f"+{tolerance:.0%} over the last record, {format_value(record.median, record.unit)} "
             f"({record.date[:10]}, {record.commit[:8] or 'no commit'})"]  # fmt: skip
    if budget is not None:
        parts.append(f"budget {format_value(budget, figure.unit)}")
    if figure.note:
        parts.append(figure.note)
    return replace(figure, target=target, note="; ".join(parts))


def judge_all(figures: list[Figure], records: list[Record], machine: MachineClass) -> list[Figure]:
    return [judge(f, last_record(records, machine, f.key), machine) for f in figures]


def missed(figures: list[Figure]) -> list[Figure]:
    """The guarded figures past their target (a regression, or over the absolute budget)."""
    return [f for f in figures if f.key in GUARDED and f.meets_target is False]


def to_record(
    records: list[Record], figures: list[Figure], machine: MachineClass, date: str, commit: str, command: str, accept_worse: bool = False
) -> tuple[list[Record], list[str]]:
    """The records with the guarded figures of this run appended, and what was refused (one line
    each): a figure that missed its target, unless accept_worse."""
    out, refused = list(records), []
    for f in figures:
        if f.key not in GUARDED:
            continue
        if f.meets_target is False and not accept_worse:
            refused.append(f"{f.key}: {format_value(f.median, f.unit)} missed its target "
                           f"{format_value(f.target or 0.0, f.unit)}; not recorded (--accept-worse records it)")  # fmt: skip
            continue
        load = tuple(round(v, 2) for v in os.getloadavg())
        out.append(Record(machine, f.key, f.unit, f.median, f.min, f.max, f.runs, date, commit, command, (load[0], load[1], load[2])))
    return out, refused


@dataclass(frozen=True)
class Outcome:
    figures: list[Figure]  # judged: the guarded ones with their targets
    messages: list[str]  # what was recorded or refused, what missed
    status: int  # 0, or 1 when a guarded figure missed its target

    def shown(self) -> int:
        """Print the figures' table, then what was recorded, refused or missed (on stderr); the
        status a benchmark exits with."""
        import sys

        print(table(self.figures))
        for line in self.messages:
            print(line, file=sys.stderr)
        return self.status


def git_commit(repo: Path) -> str:
    """HEAD's commit, with "+changes" when tracked files differ from it; "" outside git."""
    import subprocess

    def git(*args: str) -> str:
        done = subprocess.run(["git", "--no-optional-locks", *args], cwd=repo, capture_output=True, text=True)
        return done.stdout.strip() if done.returncode == 0 else ""

    commit = git("rev-parse", "HEAD")
    return commit + ("+changes" if commit and git("status", "--porcelain", "--untracked-files=no") else "")


def check(
    figures: list[Figure], command: str, record: bool = False, accept_worse: bool = False, quick: bool = False, path: Path = RECORDS_PATH
) -> Outcome:
    """Judge the figures against the records of this machine class; with record, append them."""
    from datetime import UTC, datetime

    machine = machine_class()
    records = load_records(path)
    judged = judge_all(figures, records, machine)
    messages = [f"guard: {f.key} {format_value(f.median, f.unit)} MISSED its target {format_value(f.target or 0.0, f.unit)} "
                f"({f.note})" for f in missed(judged)]  # fmt: skip
    if record and quick:
        messages.append("guard: figures of a --quick run are not recorded")
    elif record:
        date = datetime.now(UTC).isoformat(timespec="seconds")
        updated, refused = to_record(records, judged, machine, date, git_commit(REPO), command, accept_worse)
        messages += [f"guard: {line}" for line in refused]
        added = updated[len(records):]
        if added:
            save_records(updated, path)
            messages.append(f"guard: recorded {', '.join(r.key for r in added)} for {machine.label()} in {path}")
    return Outcome(judged, messages, 1 if missed(judged) else 0)
