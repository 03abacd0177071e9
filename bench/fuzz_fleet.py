"""Fuzz target of the back office: `fleet analyze`, `judge` and `report` on damaged trees.

An input is a small fleet (FLEET) of one to three wagons, each with its config and days of tiny
recordings, made hostile: names that are not UTF-8, days no clock reads, recordings that are
random bytes, cut, bit-flipped, FIFOs, folders, huge sparse files or symlinks out of FLEET (to a
file, to /dev/zero); fleet.toml, configs and calibrations that are FIFOs, junk or lead out. The
run analyses it (in this process: fleet/cluster.py InProcess), damages the windows dataset it
wrote (a partition's bytes, its metadata JSON with or without its digest made to match, a column,
a FIFO, a folder or a symlink in its place, _analysis.json), judges the damaged dataset, analyses
again, judges again (sometimes through the command line, to odd outputs: a file, a FIFO, a
character device, FLEET itself, a name that is not UTF-8), damages JUDGED and writes the report.

A clear error is a FleetError, JudgeError or ReportError (or the command line's exit status 2).
Silently wrong: a second analysis that refuses or trusts a damaged partition (every partition it
leaves must read whole and sound), a judge that stops for a damaged day instead of naming it, a
file outside the outputs changed, an output that is not strict UTF-8 JSON, a page that is not
UTF-8. Recordings are generated when the input runs, from seeds in the input, so that a saved
input stays small.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import io
import json
import os
import random
import re
import stat
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

import fuzz_core
from bogiemon.cli.main import main
from bogiemon.drivers.recording import write_csv_recording, write_parquet_recording
from bogiemon.fleet.analyze import analyze_fleet
from bogiemon.fleet.cluster import InProcess
from bogiemon.fleet.judge import judge_fleet
from bogiemon.fleet.layout import FleetError, day_start_s, scan_fleet
from bogiemon.fleet.report import write_report
from bogiemon.fleet.windows_files import DIGEST_KEY, METADATA_KEY, PartitionError, partition_path, read_partition

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.fleet import tiny  # noqa: E402

CONFIG = tiny.CONFIG.encode()  # a wagon judged by thresholds on 20-s windows: seconds of noise analyse in milliseconds
FS_HZ = tiny.FS_HZ
DATES = ("2026-11-02", "2026-11-03", "2026-11-04")
ODD_DATES = ("0001-01-01", "9999-12-31", "1999-12-31", "2100-01-01", "2026-02-30", "2026-1-1", "1970-01-01", "+2 days", "-1 days")
WAGON_IDS = ("W1", "W2", "318045331234", "w.3", "-x", "a" * 70, "\udcff", "W 1", "..", "wagon=W1")
RECORDING_NAMES = ("060000_run.csv.gz", "070000_run.csv", "080000_run.parquet", "090000_run.CSV.GZ", "100000_can.log")
RELATIVE_DAY = re.compile(r"^([+-]\d+) days$")
DAY_S = 86_400.0
NOT_UTF8 = "\udcff\udcfe"  # what Python lists for the bytes 0xff 0xfe in a name
SPECIALS = ("fifo", "folder", "sparse", "link-outside", "link-zero", "link-root", "link-loop")
OUTPUTS = ("fresh",) * 27 + ("file", "fifo", "device", "inside-input", "same", "link-outside", "not-utf8", "nested", "under-file")  # three in four fresh: most inputs reach the report


# ---- the inputs -----------------------------------------------------------------------------------


def _recording(rng: random.Random, m: fuzz_core.Mutator) -> dict[str, Any]:
    """A recording as the input holds it: made at run time from its seed, then perhaps damaged."""
    name = rng.choice(RECORDING_NAMES)
    if rng.random() < 0.05:
        name = NOT_UTF8 + name
    spec: dict[str, Any] = {"name": name, "seed": rng.randrange(1 << 30), "duration_s": rng.choice((25.0, 45.0, 45.0, 0.01, 120.0)),
                            "hhmm": rng.choice(("06:00", "06:00", "23:59", "00:00")), "origin": rng.choice(("unix", "unix", "zero", "other-day"))}  # fmt: skip
    kind = rng.random()
    if kind < 0.55:
        return spec
    if kind < 0.75:
        spec["mutate"] = rng.randrange(1 << 30)  # the made bytes through Mutator.bytes, seeded
    elif kind < 0.82:
        spec["bytes"] = m.random_bytes(rng.choice((0, 10, 500)))
    elif kind < 0.88:
        spec["cut"] = rng.random()
    else:
        spec["special"] = rng.choice(SPECIALS)
    return spec


def _wagon(rng: random.Random, m: fuzz_core.Mutator, index: int) -> dict[str, Any]:
    wagon_id = f"W{index + 1}" if rng.random() < 0.9 else rng.choice(WAGON_IDS)
    config: dict[str, Any] = {"bytes": CONFIG}
    if rng.random() < 0.1:
        config = {"bytes": m.bytes(CONFIG)} if rng.random() < 0.6 else {"special": rng.choice(SPECIALS)}
    calibration = None
    if rng.random() < 0.1:
        calibration = {"bytes": m.random_bytes(40)} if rng.random() < 0.3 else {"special": rng.choice(SPECIALS)}
    days = []
    for date in rng.sample(DATES, rng.randint(1, len(DATES))):
        if rng.random() < 0.08:
            date = rng.choice(ODD_DATES) if rng.random() < 0.8 else NOT_UTF8 + date
        days.append({"date": date, "recordings": [_recording(rng, m) for _ in range(rng.choice((1, 1, 2, 3)))],
                     "special": rng.choice(SPECIALS) if rng.random() < 0.03 else None})  # fmt: skip
    return {"id": wagon_id, "config": config, "calibration": calibration, "days": days}


def _fleet_toml(rng: random.Random, m: fuzz_core.Mutator, wagon_ids: list[str]) -> dict[str, Any] | None:
    kind = rng.random()
    if kind < 0.7:
        return None
    entries = {w: {"type": "Sgns"} for w in wagon_ids if w.isprintable()}
    if kind < 0.88 and entries and rng.random() < 0.5:  # a config outside FLEET, or nowhere
        target = rng.choice(("../outside.toml", "/etc/hostname", "W1/bogiemon.toml", "", "W1/../../outside.toml", "\u0000", "W1"))
        entries[next(iter(entries))]["config"] = target
    text = '[fleet]\nname = "fuzz"\n' + "".join(
        f"[wagons.{json.dumps(w)}]\n" + "".join(f"{k} = {json.dumps(v)}\n" for k, v in entry.items()) for w, entry in entries.items()
    )
    if kind < 0.88:
        return {"bytes": text.encode("utf-8", "surrogatepass")}
    if kind < 0.95:
        return {"bytes": m.bytes(text.encode())}
    return {"special": rng.choice(SPECIALS)}


WINDOWS_DAMAGES = ("bytes", "cut", "random", "empty", "fifo", "folder", "link-outside", "link-zero", "metadata", "metadata-digest",
                   "null-column", "nan-column", "segment", "remove", "stray", "temporary", "summary", "summary-special", "wagon-file")  # fmt: skip
JUDGED_DAMAGES = ("wagons-tree", "wagons-bytes", "events-lines", "series-bytes", "special", "none", "none", "none")


def generate(rng: random.Random) -> fuzz_core.Input:
    m = fuzz_core.Mutator(rng)
    wagons = [_wagon(rng, m, i) for i in range(rng.choice((1, 2, 2, 3)))]
    return {
        "wagons": wagons,
        "fleet_toml": _fleet_toml(rng, m, [w["id"] for w in wagons]),
        "windows_damages": [{"kind": rng.choice(WINDOWS_DAMAGES), "seed": rng.randrange(1 << 30)} for _ in range(rng.choice((0, 1, 1, 2, 3)))],
        "judged_damage": {"kind": rng.choice(JUDGED_DAMAGES), "seed": rng.randrange(1 << 30)},
        "judge_output": rng.choice(OUTPUTS),
        "report_output": rng.choice(OUTPUTS),
        "cli": rng.random() < 0.3,  # the judge and the report through `bogiemon fleet ...` (analyze never: no Dask here)
    }


# ---- making the tree -------------------------------------------------------------------------------


def _special(path: Path, kind: str, outside: Path) -> None:
    """A thing that is no regular file of its own at path."""
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    elif kind == "sparse":  # a TiB that costs nothing on disk (a sparse file)
        with path.open("wb") as f:
            f.truncate(1 << 40)
    elif kind == "link-outside":
        path.symlink_to(outside / "secret.csv")
    elif kind == "link-zero":
        path.symlink_to("/dev/zero")
    elif kind == "link-root":
        path.symlink_to(outside)
    elif kind == "link-loop":
        path.symlink_to(path.name)


def _recording_bytes(spec: dict[str, Any], date: str, scratch: Path) -> bytes:
    """The recording's bytes, made from its seed (written by the project's own writers)."""
    n = max(2, int(spec["duration_s"] * FS_HZ))
    rng = np.random.default_rng(spec["seed"])
    start_s = 0.0  # the recording's own origin (a simulator's), or a day no date names
    if spec["origin"] != "zero" and RELATIVE_DAY.match(date) is None:
        with contextlib.suppress(ValueError):
            hh, mm = spec["hhmm"].split(":")
            start_s = day_start_s(date) + 3600 * int(hh) + 60 * int(mm) + (3 * DAY_S if spec["origin"] == "other-day" else 0.0)
    name = spec["name"].encode("utf-8", "surrogateescape").decode("ascii", "replace").lower()
    path = scratch / ("made.parquet" if name.endswith(".parquet") else "made.csv.gz" if name.endswith(".gz") else "made.csv")
    time_s, accel = start_s + np.arange(n) / FS_HZ, rng.normal(0.0, 1.0, (n, 3))
    (write_parquet_recording if path.suffix == ".parquet" else write_csv_recording)(path, time_s, accel)
    data = path.read_bytes()
    path.unlink()
    return data


def build(data: fuzz_core.Input, root: Path) -> tuple[Path, Path]:
    """FLEET and a folder outside it (what no run may touch), from the input."""
    fleet, outside = root / "fleet", root / "outside"
    fleet.mkdir()
    outside.mkdir()
    (outside / "secret.csv").write_bytes(b"time_s,a1,a2,a3\n0,1,2,3\n0.005,1,2,3\n")
    (outside / "outside.toml").write_bytes(CONFIG)
    for wagon in data["wagons"]:
        folder = fleet / wagon["id"]
        try:
            folder.mkdir(exist_ok=True)
        except (OSError, ValueError):  # '..', a name the file system refuses
            continue
        _place(folder / "bogiemon.toml", wagon["config"], outside)
        if wagon["calibration"] is not None:
            _place(folder / "calibration.toml", wagon["calibration"], outside)
        for day in wagon["days"]:
            date = _date_text(day["date"])
            day_folder = folder / date
            if day["special"] is not None:
                with contextlib.suppress(OSError):
                    _special(day_folder, day["special"], outside)
                continue
            day_folder.mkdir(exist_ok=True)
            for spec in day["recordings"]:
                _place_recording(day_folder / spec["name"], spec, day["date"], root, outside)
    if data["fleet_toml"] is not None:
        _place(fleet / "fleet.toml", data["fleet_toml"], outside)
    return fleet, outside


def _date_text(date: str) -> str:
    """A day folder's name: '+2 days' is the day after tomorrow (UTC) when the input runs."""
    relative = RELATIVE_DAY.match(date)
    if relative is None:
        return date
    return (dt.datetime.now(dt.UTC).date() + dt.timedelta(days=int(relative.group(1)))).isoformat()


def _place(path: Path, spec: dict[str, Any], outside: Path) -> None:
    with contextlib.suppress(OSError):
        if "special" in spec:
            _special(path, spec["special"], outside)
        else:
            path.write_bytes(spec["bytes"])


def _place_recording(path: Path, spec: dict[str, Any], date: str, root: Path, outside: Path) -> None:
    if os.path.lexists(path):
        return
    if "special" in spec:
        _special(path, spec["special"], outside)
        return
    if "bytes" in spec:
        path.write_bytes(spec["bytes"])
        return
    raw = _recording_bytes(spec, date, root)
    if "mutate" in spec:
        raw = fuzz_core.Mutator(random.Random(spec["mutate"])).bytes(raw)
    elif "cut" in spec:
        raw = raw[: int(len(raw) * spec["cut"])]
    path.write_bytes(raw)


# ---- damaging what the back office wrote ----------------------------------------------------------


def _partitions(windows: Path) -> list[Path]:
    return sorted(p for p in windows.glob("wagon=*/date=*/part-0.parquet") if os.path.lexists(p))


def damage_windows(windows: Path, damage: dict[str, Any], outside: Path) -> None:
    rng = random.Random(damage["seed"])
    m = fuzz_core.Mutator(rng)
    kind = damage["kind"]
    parts = [p for p in _partitions(windows) if stat.S_ISREG(os.lstat(p).st_mode)]  # analyze's own, or a damage's
    summary = windows / "_analysis.json"
    if kind == "summary":
        if summary.is_file():
            raw = summary.read_bytes()
            summary.write_bytes(m.bytes(raw) if rng.random() < 0.5 else json.dumps(m.tree(json.loads(raw))).encode("utf-8", "surrogatepass"))
        return
    if kind == "summary-special":
        with contextlib.suppress(OSError):
            summary.unlink()
            _special(summary, rng.choice(SPECIALS), outside)
        return
    if kind == "stray":  # a partition of a wagon and day that are not in FLEET
        stray = windows / "wagon=ZZ" / "date=2026-11-09" / "part-0.parquet"
        stray.parent.mkdir(parents=True, exist_ok=True)
        stray.write_bytes(m.random_bytes(64))
        return
    if not parts:
        return
    path = rng.choice(parts)
    if kind == "temporary":  # what a run killed while writing leaves, in odd shapes
        _special(path.parent / f".{rng.randrange(1 << 32):08x}.part-0.parquet", rng.choice(("fifo", "folder", "link-outside")), outside)
    elif kind == "wagon-file":  # the wagon's folder of partitions replaced by a file
        folder = path.parents[1]
        for p in sorted(folder.rglob("*"), reverse=True):
            p.rmdir() if p.is_dir() and not p.is_symlink() else p.unlink()
        folder.rmdir()
        folder.write_bytes(b"x")
    elif kind in ("bytes", "cut", "random", "empty"):
        raw = path.read_bytes()
        path.write_bytes({"bytes": lambda: m.bytes(raw), "cut": lambda: raw[: rng.randrange(max(1, len(raw)))],
                          "random": lambda: m.random_bytes(4096), "empty": lambda: b""}[kind]())  # fmt: skip
    elif kind == "remove":
        path.unlink()
    elif kind in ("fifo", "folder", "link-outside", "link-zero"):
        path.unlink()
        _special(path, kind, outside)
    elif kind in ("metadata", "metadata-digest"):
        table = pq.read_table(path)
        meta = dict(table.schema.metadata or {})
        text = json.dumps(m.tree(json.loads(meta[METADATA_KEY])), allow_nan=True).encode("utf-8", "surrogatepass")
        meta[METADATA_KEY] = text
        if kind == "metadata-digest":  # a careful hand: the digest made to match
            meta[DIGEST_KEY] = hashlib.sha256(text).hexdigest().encode()
        pq.write_table(table.replace_schema_metadata(meta), path)
    else:
        table = pq.read_table(path)
        if table.num_rows == 0:
            return
        names = table.column_names
        name = "segment" if kind == "segment" else rng.choice(names)
        column = table.column(name)
        if kind == "null-column":
            values = pa.nulls(table.num_rows, type=column.type)
        else:
            strange = rng.choice((float("nan"), float("inf"), -1.0, 1e300, 0.0, 2.0**40)) if kind != "segment" else rng.choice((-1, 10**6, 1))
            values = column.to_pylist()
            values[rng.randrange(len(values))] = strange if not pa.types.is_string(column.type) else "\x00"
            try:
                values = pa.array(values, type=column.type)
            except (pa.ArrowException, OverflowError, TypeError, ValueError):
                return
        pq.write_table(table.set_column(names.index(name), name, values), path)


def damage_judged(judged: Path, damage: dict[str, Any], outside: Path) -> None:
    rng = random.Random(damage["seed"])
    m = fuzz_core.Mutator(rng)
    kind = damage["kind"]
    wagons, events = judged / "wagons.json", judged / "events.jsonl"
    series = sorted(judged.glob("series/wagon=*/part-0.parquet"))
    if kind == "wagons-tree" and wagons.is_file():
        wagons.write_bytes(json.dumps(m.tree(json.loads(wagons.read_bytes())), allow_nan=True).encode("utf-8", "surrogatepass"))
    elif kind == "wagons-bytes" and wagons.is_file():
        wagons.write_bytes(m.bytes(wagons.read_bytes()))
    elif kind == "events-lines" and events.is_file():
        events.write_bytes(m.lines(events.read_text(encoding="utf-8")).encode("utf-8", "surrogatepass"))
    elif kind == "series-bytes" and series:
        path = rng.choice(series)
        path.write_bytes(m.bytes(path.read_bytes()))
    elif kind == "special":
        path = rng.choice([wagons, events, *series])
        with contextlib.suppress(OSError):
            path.unlink()
            _special(path, rng.choice(SPECIALS), outside)


# ---- outputs -------------------------------------------------------------------------------------


def output(kind: str, root: Path, name: str, inputs: dict[str, Path]) -> Path:
    """An output path of the kind asked for (the place made as it says)."""
    path = root / name
    if kind == "file":
        path.write_bytes(b"not yours\n")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "device":  # a /dev/null of the scratch space's own: a rename over it harms nothing
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
        except OSError:
            os.mkfifo(path)
    elif kind == "inside-input":
        path = next(iter(inputs.values())) / name
    elif kind == "same":
        path = next(iter(inputs.values()))
    elif kind == "link-outside":  # a symlink to a folder elsewhere: where the user asked the output to go
        (root / "elsewhere" / name).mkdir(parents=True)
        path.symlink_to(root / "elsewhere" / name)
    elif kind == "not-utf8":
        path = root / (name + NOT_UTF8)
    elif kind == "nested":
        path = root / "a" / "b" / name
    elif kind == "under-file":
        (root / "plain").write_bytes(b"")
        path = root / "plain" / name
    return path


# ---- the run --------------------------------------------------------------------------------------


def _digest_tree(folder: Path) -> dict[str, str]:
    """What a folder holds (names, kinds, the bytes of its small regular files, the size and time
    of a large one), its symlinks not followed: to tell it untouched."""
    out = {}
    for parent, dirs, files in os.walk(folder):
        for name in (*dirs, *files):
            path = os.path.join(parent, name)
            st = os.lstat(path)
            if stat.S_ISREG(st.st_mode) and st.st_size <= 1 << 20:
                out[path] = hashlib.sha256(Path(path).read_bytes()).hexdigest()
            else:
                out[path] = f"{stat.S_IFMT(st.st_mode):o} {st.st_size} {st.st_mtime_ns}"
    return out


def _run_cli(argv: list[str]) -> int:
    """A `bogiemon` command in this process: its exit status (argparse's own errors are 2 too)."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        try:
            return main(argv)
        except SystemExit as exc:
            return int(exc.code or 0)


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    root = ctx.fresh_dir()
    fleet, outside = build(data, root)
    untouched = {"FLEET": _digest_tree(fleet), "outside": _digest_tree(outside)}
    windows = root / "windows"
    analyze_fleet(fleet, windows, runner=InProcess())  # FLEET's own problems: a clear error, or counted and skipped
    verdict = _strict_json(windows / "_analysis.json")
    if verdict is not None:
        return verdict
    for damage in data["windows_damages"]:
        with contextlib.suppress(OSError, ValueError, pa.ArrowException):  # a damage that does not apply (an earlier one's file)
            damage_windows(windows, damage, outside)

    # The damaged dataset: every day that does not read is named, the rest judged.
    try:
        judge_fleet(windows, root / "judged-damaged", fleet_root=fleet)
    except ValueError as exc:  # FleetError, JudgeError: none is right here
        return f"judge stopped for a damaged windows dataset: {type(exc).__name__}: {exc}"
    try:
        again = analyze_fleet(fleet, windows, runner=InProcess())
    except FleetError as exc:
        return f"a second analyze refused a damaged windows dataset instead of analysing it again: {exc}"
    verdict = _strict_json(windows / "_analysis.json") or _sound(windows, fleet)
    if verdict is None and again.analysed == 0 and again.repaired:
        verdict = "repaired partitions counted, none analysed"
    if verdict is not None:
        return verdict

    judged = output(data["judge_output"], root, "judged", {"WINDOWS": windows, "FLEET": fleet})
    if data["cli"]:
        code = _run_cli(["fleet", "judge", str(windows), "-o", str(judged), "--fleet", str(fleet)])
        if code not in (0, 2):
            return f"fleet judge exit status {code}"
        if code == 2:
            return _untouched(untouched, fleet, outside)
    else:
        judge_fleet(windows, judged, fleet_root=fleet)
    verdict = _strict_json(judged / "wagons.json")
    if verdict is not None:
        return verdict
    with contextlib.suppress(OSError, ValueError, pa.ArrowException):
        damage_judged(judged, data["judged_damage"], outside)
    report = output(data["report_output"], root, "report", {"JUDGED": judged})
    if data["cli"]:
        code = _run_cli(["fleet", "report", str(judged), "-o", str(report)])
        if code not in (0, 2):
            return f"fleet report exit status {code}"
    else:
        try:
            write_report(judged, report)
        except ValueError:  # ReportError: a clear error, once nothing outside was touched
            return _untouched(untouched, fleet, outside)
        for page in (report / "index.html", report / "worklist.csv", report / "worklist.json", *sorted((report / "wagons").glob("*.html"))):
            try:
                page.read_bytes().decode("utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                return f"the report's {page.name} is not UTF-8 text: {exc}"
    return _untouched(untouched, fleet, outside)


def _strict_json(path: Path) -> fuzz_core.Verdict:
    if not os.path.lexists(path):
        return None
    try:
        fuzz_core.strict_json(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        return f"{path.name} is not strict UTF-8 JSON: {exc}"
    return None


def _sound(windows: Path, fleet: Path) -> fuzz_core.Verdict:
    """After a second analyze, every partition of the fleet's days reads whole and sound."""
    scanned = scan_fleet(fleet)
    for wagon in scanned.wagons:
        for day in wagon.days:
            path = partition_path(windows, wagon.wagon_id, day.date)
            try:
                read_partition(path, day.midnight_s)
            except PartitionError as exc:
                return f"a damaged partition left after analyze: {exc}"
    return None


def _untouched(before: dict[str, dict[str, str]], fleet: Path, outside: Path) -> fuzz_core.Verdict:
    if _digest_tree(outside) != before["outside"]:
        return "a file outside the outputs changed (outside the fleet)"
    if _digest_tree(fleet) != before["FLEET"]:
        return "a file in FLEET changed (analyze, judge and report only read it)"
    return None


TARGETS = [fuzz_core.Target("fleet", generate, run)]


if __name__ == "__main__":
    # Until bench/fuzz.py lists this target (SPECS and CLEAR_ERRORS): the harness run with it
    # added, e.g. `.venv/bin/python bench/fuzz_fleet.py --target fleet --inputs 300 --jobs 2`.
    import fuzz

    if "fleet" not in fuzz.BY_NAME:
        spec = fuzz.Spec("fleet", "fuzz_fleet", 2000, 100, 30.0, 5, "fleet analyze/judge/report on damaged trees, partitions and JUDGED")
        fuzz.SPECS = (*fuzz.SPECS, spec)
        fuzz.BY_NAME["fleet"] = spec
        fuzz.CLEAR_ERRORS["fleet"] = ("bogiemon.fleet.layout.FleetError", "bogiemon.fleet.judge.JudgeError", "bogiemon.fleet.judged_files.ReportError")
    sys.exit(fuzz.main())
