"""A JUDGED folder (docs/fleet-formats.md section 3) from a few synthetic wagons, for the report's tests.

Until `fleet judge` writes real ones, this writes wagons.json, events.jsonl and the series Parquet
files exactly as the contract says, from seeded random scores run through a small stand-in of the
daemon's decision (warning -> SUSPECTED, a few windows over the alarm -> CONFIRMED, clean windows
-> CLEARED). It is a fixture, not the daemon's rule: the report only draws what it is given.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any, TypedDict

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bogiemon.daemon.messages import encode_event
from bogiemon.detection import Corner
from bogiemon.judgement.diagnosis import Diagnosis
from bogiemon.judgement.events import (
    DEFAULT_BOGIE,
    DEFAULT_SEVERITY,
    ClearedDetails,
    ConfirmedDetails,
    Event,
    EventDetails,
    KOfN,
    SensorFaultDetails,
    SuspectedDetails,
    SuspensionHint,
    Trigger,
)
from bogiemon.judgement.rules import Threshold
from bogiemon.judgement.vocabulary import LoadState, Method, Mode

HOP_S = 10.0  # the daemon's default hop between windows
FIRST_DAY = "2026-11-30"
# The shipped fused model's levels per load state (config/fused_model.toml, rounded).
LEVELS = {
    "full": {"warning": 31.3, "alarm": 67.0, "trend_warning": 3.07, "trend_alarm": 7.35},
    "tare": {"warning": 25.4, "alarm": 49.5, "trend_warning": 1.45, "trend_alarm": 2.49},
}
ATTENTION = {"CONFIRMED": 100.0, "SENSOR_FAULT": 50.0, "SUSPECTED": 30.0, "NO_DATA": 10.0, "NORMAL": 0.0}
SAFE_ID = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,63}$")
CONFIRM_AFTER = 3  # consecutive windows over the alarm level
CLEAR_AFTER = 30  # consecutive clean windows

# The kinds of synthetic wagon: what each does is in _scores and _simulate.
KINDS = ("confirmed", "suspected", "sensor_fault", "normal", "blip", "no_data")


@dataclass(frozen=True)
class WagonSpec:
    wagon: str
    kind: str  # one of KINDS
    type: str = "Sgns-Y25"
    commissioned: tuple[str, ...] = ("full", "tare")
    notes: tuple[str, ...] = ()
    bogie: str | None = None  # the bogie its events name (None: they name none, as a one-bogie gateway's)
    days_behind: int = 0  # its data end this many days before the others' (a gateway that stopped)
    # The corners its SENSOR_FAULT says the couplings point at (a spring at the sensor's corner).
    sensor_suspension: tuple[str, ...] = ()


@dataclass(frozen=True)
class FleetShape:
    days: int = 2
    recordings_per_day: int = 2
    windows_per_recording: int = 360  # an hour at a 10 s hop


@dataclass
class _Wagon:
    spec: WagonSpec
    columns: dict[str, list[Any]] = field(default_factory=dict)
    events: list[Event] = field(default_factory=list)
    reported_fault: bool = False


DEFAULT_FLEET = (
    WagonSpec("31-80-4557-003", "normal"),
    WagonSpec("31-80-4557-001", "confirmed"),
    WagonSpec("31-80-4557-004", "blip", commissioned=("full",), notes=("not commissioned for tare: judged with the shipped prior",)),
    WagonSpec("31-80-4557-002", "sensor_fault"),
    WagonSpec("31-80-4557-006", "suspected", type="Sgns-Y25-light"),
    WagonSpec("31-80-4557-005", "no_data", commissioned=(), notes=("no recordings",)),
)
DIAGNOSIS = Diagnosis(
    corners=(Corner.LEADING_LEFT, Corner.TRAILING_RIGHT), kind="unknown", corner_confidence=0.84, kind_confidence=0.0,
    best_match="pitch-roll +4.1, bounce-roll +3.2 sd at 4-8 Hz: leading-left or trailing-right", cosine=1.0, windows=3,
)  # fmt: skip
# The diagnosis as wagons.json holds it (the CONFIRMED event's, as JSON).
DIAGNOSIS_BODY = {
    "corner": DIAGNOSIS.corner, "corners": [c.value for c in DIAGNOSIS.corners], "kind": DIAGNOSIS.kind,
    "corner_confidence": DIAGNOSIS.corner_confidence, "kind_confidence": DIAGNOSIS.kind_confidence,
}  # fmt: skip
CORNERS = {"a1": "leading-left", "a2": "leading-right", "a3": "trailing-left"}


def _scores(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    base = rng.lognormal(mean=np.log(6.0), sigma=0.35, size=n)
    if kind == "confirmed":  # the fault grows over the last third: the score climbs past the alarm
        ramp = np.clip((np.arange(n) - 2 * n / 3) / (n / 3), 0.0, 1.0)
        return base * (1.0 + 25.0 * ramp**2)
    if kind == "suspected":  # the last windows sit between warning and alarm
        out = base.copy()
        out[-40:] = 40.0 * rng.lognormal(0.0, 0.05, size=min(40, n))
        return out
    if kind == "blip":  # a short suspicion in the middle that clears
        out = base.copy()
        out[n // 2 : n // 2 + 2] = 35.0
        return out
    return base


def _simulate(spec: WagonSpec, shape: FleetShape, rng: np.random.Generator) -> _Wagon:
    wagon = _Wagon(spec)
    cols: dict[str, list[Any]] = {
        name: []
        for name in ("time_s", "judged", "load", "score", "trend", "warning", "alarm", "trend_warning", "trend_alarm", "mode", "gate", "sensor_problems")
    }
    wagon.columns = cols
    if spec.kind == "no_data":
        return wagon
    day0 = datetime.fromisoformat(FIRST_DAY).replace(tzinfo=UTC) - timedelta(days=spec.days_behind)
    bogie = DEFAULT_BOGIE if spec.bogie is None else spec.bogie
    pointed = SuspensionHint(spec.sensor_suspension, 80.0, 67.0, "") if spec.sensor_suspension else None
    n_total = shape.days * shape.recordings_per_day * shape.windows_per_recording
    scores = _scores(spec.kind, n_total, rng)
    mode, over_alarm, clean, trend, i = "NORMAL", 0, 0, 0.0, 0
    fault_from = int(n_total * 0.8) if spec.kind == "sensor_fault" else n_total
    for day in range(shape.days):
        load = "full" if day % 2 == 0 else "tare"
        lv = LEVELS[load]
        for rec in range(shape.recordings_per_day):
            start_s = (day0 + timedelta(days=day, hours=6 + 5 * rec)).timestamp()
            for w in range(shape.windows_per_recording):
                time_s = start_s + 120.0 + w * HOP_S  # a window's end: 120 s window, 10 s hop
                gate = "standstill" if w < 12 else ""  # each recording starts at a standstill
                faulty = i >= fault_from
                judged = not gate and not faulty
                if faulty and not wagon.reported_fault:
                    wagon.reported_fault = True
                    noisy = {"a3": ("noisy",)}
                    found = SensorFaultDetails(
                        window_start_s=time_s - 120.0, window_end_s=time_s, rms_mps2=(0.9, 1.1, 1.4), problems=noisy, reported=noisy, suspension=pointed,
                    )  # fmt: skip
                    wagon.events.append(_event(time_s, found, rng, bogie=bogie))
                score = float(scores[i])
                if judged:
                    trend = 0.98 * trend + 0.02 * score / 8.0
                    if score > lv["alarm"]:
                        over_alarm += 1
                    else:
                        over_alarm = 0
                    clean = clean + 1 if score <= lv["warning"] else 0
                    if mode != "CONFIRMED" and over_alarm >= CONFIRM_AFTER:
                        mode = "CONFIRMED"
                        confirmed = ConfirmedDetails(**_decided(time_s, load), alarm_windows=KOfN(CONFIRM_AFTER, CONFIRM_AFTER), trigger=Trigger.WINDOWS,
                                                     diagnosis=DIAGNOSIS)  # fmt: skip
                        wagon.events.append(_event(time_s, confirmed, rng, {"fused_score": score}, bogie=bogie))
                    elif mode == "NORMAL" and score > lv["warning"]:
                        mode = "SUSPECTED"
                        wagon.events.append(_event(time_s, SuspectedDetails(**_decided(time_s, load)), rng, {"fused_score": score}, bogie=bogie))
                    elif mode == "SUSPECTED" and clean >= CLEAR_AFTER:
                        mode = "NORMAL"
                        wagon.events.append(_event(time_s, ClearedDetails(**_decided(time_s, load), cleared=Mode.SUSPECTED), rng, bogie=bogie))
                nan = float("nan")
                cols["time_s"].append(time_s)
                cols["judged"].append(judged)
                cols["load"].append(load if judged else "")
                cols["score"].append(score if judged else nan)
                cols["trend"].append(trend if judged else nan)
                for name in ("warning", "alarm", "trend_warning", "trend_alarm"):
                    cols[name].append(lv[name] if judged else nan)
                cols["mode"].append(mode.lower())  # the series holds the daemon's words
                cols["gate"].append(gate)
                cols["sensor_problems"].append("a3 noisy" if faulty else "")
                i += 1
    return wagon


class _Decided(TypedDict):
    window_start_s: float
    window_end_s: float
    load: LoadState
    thresholds: dict[str, Threshold]
    method: Method


def _decided(time_s: float, load: str) -> _Decided:
    """What a suspension event states of its window: the fused method's limits in the load state."""
    lv = LEVELS[load]
    limits = {"fused_score": Threshold(lv["warning"], lv["alarm"]), "fused_trend": Threshold(lv["trend_warning"], lv["trend_alarm"])}
    return _Decided(window_start_s=time_s - 120.0, window_end_s=time_s, load=LoadState(load), thresholds=limits, method=Method.FUSED)


def _event(time_s: float, details: EventDetails, rng: np.random.Generator, indicators: dict[str, float] | None = None, bogie: str = DEFAULT_BOGIE) -> Event:
    return Event(
        time_s=time_s,
        kind=details.KIND,
        severity=DEFAULT_SEVERITY[details.KIND],
        config_hash="fixture",
        indicators=indicators or {},
        details=details,
        event_id=f"{int(rng.integers(2**62)):016x}{int(rng.integers(2**62)):016x}",
        bogie=bogie,
    )


def _summary(w: _Wagon, seqs: list[int]) -> dict[str, Any]:
    cols, spec = w.columns, w.spec
    n = len(cols["time_s"])
    judged = cols["judged"]
    if n == 0:
        state = "NO_DATA"
    elif w.reported_fault:
        state = "SENSOR_FAULT"
    else:
        state = cols["mode"][-1].upper()
    last_judged = max((k for k in range(n) if judged[k]), default=None)
    trend = None if last_judged is None else round(cols["trend"][last_judged], 4)
    trend_alarm = None if last_judged is None else cols["trend_alarm"][last_judged]
    last_event = None
    if w.events:
        ev, seq = w.events[-1], seqs[-1]
        last_event = {"kind": ev.kind.value, "time_s": ev.time_s, "time_utc": _utc(ev.time_s), "seq": seq}
    days = sorted({datetime.fromtimestamp(t, UTC).date().isoformat() for t in cols["time_s"]})
    stands_out = spec.kind == "confirmed"
    return {
        "wagon": spec.wagon,
        "type": spec.type,
        "state": state,
        "attention": ATTENTION[state] + (0.0 if trend is None or not trend_alarm else round(trend / trend_alarm, 4)),
        "last_event": last_event,
        "diagnosis": dict(DIAGNOSIS_BODY) if spec.kind == "confirmed" else None,
        "diagnosis_now": {},
        "sensor_problems": {"a3": ["noisy"]} if w.reported_fault else {},
        "trend": trend,
        "trend_alarm": trend_alarm,
        "commissioned": list(spec.commissioned),
        "days": len(days),
        "first_day": days[0] if days else None,
        "last_day": days[-1] if days else None,
        "windows": n,
        "judged": int(sum(judged)),
        "gated": sum(1 for g in cols["gate"] if g),
        "sensor_fault_windows": sum(1 for p in cols["sensor_problems"] if p),
        "last_data_s": cols["time_s"][-1] if n else None,
        "sensor_corners": dict(CORNERS),
        "fleet_relative": None
        if n == 0
        else {
            "baseline_distance": 4.2 if stands_out else 0.8,
            "trend_rank": 1.0 if stands_out else 0.4,
            "stands_out": stands_out,
            "why": "trend 3.1x its sisters' median" if stands_out else "within its sisters' spread",
        },
        "notes": list(spec.notes),
    }


def _utc(time_s: float) -> str:
    return datetime.fromtimestamp(time_s, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


SERIES_SCHEMA = pa.schema(
    [
        ("time_s", pa.float64()),
        ("judged", pa.bool_()),
        ("load", pa.string()),
        ("score", pa.float64()),
        ("trend", pa.float64()),
        ("warning", pa.float64()),
        ("alarm", pa.float64()),
        ("trend_warning", pa.float64()),
        ("trend_alarm", pa.float64()),
        ("mode", pa.string()),
        ("gate", pa.string()),
        ("sensor_problems", pa.string()),
    ]
)


def write_judged(
    root: Path,
    wagons: tuple[WagonSpec, ...] = DEFAULT_FLEET,
    shape: FleetShape = FleetShape(),
    *,
    seed: int = 15,
    fleet: str = "Keeper X, Sgns Y25 fleet",
    skipped: tuple[tuple[str, str], ...] = (("31-80-4557-003/2026-11-31", "day folder name is no date"),),
    sort: bool = False,
) -> Path:
    """Write a JUDGED folder at root (created) and return it.

    The wagons list is written in the order given unless sort: the report must sort by attention
    itself. A wagon id that is no folder name gets no series file (its kind should be no_data).
    """
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    entries, lines = [], []
    for spec in wagons:
        w = _simulate(spec, shape, rng)
        seqs = list(range(1, len(w.events) + 1))
        lines += [encode_event(spec.wagon, seq, ev) for seq, ev in zip(seqs, w.events, strict=True)]
        entries.append(_summary(w, seqs))
        if SAFE_ID.match(spec.wagon):
            folder = root / "series" / f"wagon={spec.wagon}"
            folder.mkdir(parents=True, exist_ok=True)
            pq.write_table(pa.table(w.columns, schema=SERIES_SCHEMA), folder / "part-0.parquet")
    if sort:
        entries.sort(key=lambda e: -e["attention"])
    doc = {
        "format": 3,
        "generated_utc": "2026-12-02T10:00:00Z",
        "fleet": fleet,
        "wagons": entries,
        "inputs": {
            "wagons": len(wagons),
            "recordings": sum(shape.days * shape.recordings_per_day for s in wagons if s.kind != "no_data"),
            "skipped": [{"path": p, "reason": r} for p, r in skipped],
        },
    }
    write_wagons_json(root, doc)
    # Events in time order across the fleet; seq counts per wagon (what `fleet judge` writes).
    lines.sort(key=lambda line: json.loads(line)["time_s"])
    (root / "events.jsonl").write_text("".join(line + "\n" for line in lines), encoding="utf-8")
    return root


def read_wagons_json(root: Path) -> dict[str, Any]:
    return json.loads((root / "wagons.json").read_text(encoding="utf-8"))


def write_wagons_json(root: Path, doc: dict[str, Any]) -> None:
    (root / "wagons.json").write_text(json.dumps(doc, indent=2), encoding="utf-8")


def many_wagons(n: int) -> tuple[WagonSpec, ...]:
    """A fleet of n synthetic wagons of three types: mostly normal, one in 97 confirmed, one in 20
    suspected, blipping or with a sensor fault, one in 211 without data, one in 150 whose data
    stopped five days early; commissioned for both loads, full only or not at all."""
    kinds = ["normal"] * 17 + ["suspected", "blip", "sensor_fault"]
    types = ("Sgns-Y25", "Sgns-Y25-light", "Habbiins")
    commissioned: tuple[tuple[str, ...], ...] = (("full", "tare"), ("full",), ())
    return tuple(
        WagonSpec(
            f"31-80-{4000 + i:04d}-{i % 10}", "confirmed" if i % 97 == 0 else "no_data" if i % 211 == 0 else kinds[i % len(kinds)],
            type=types[i % 3], commissioned=commissioned[i % 7 % 3], days_behind=5 if i % 150 == 0 else 0,
        )  # fmt: skip
        for i in range(n)
    )


# A small shape for a large fleet: two days of one 10-minute recording each.
SMALL_SHAPE = FleetShape(days=2, recordings_per_day=1, windows_per_recording=60)
