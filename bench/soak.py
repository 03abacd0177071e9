"""Soak test: the daemon fed 24 simulated hours of 500 Hz data, faster than real time, on a schedule.

The real Service (its pipeline threads, ring, monitor, SQLite event store, log sink, SIGHUP
reload) runs in this process's main thread, fed by a source that replays simulated runs of one
wagon (full load, 80 km/h, ERRI low-level track) as fast as the daemon takes them. A child
process simulates the data chunk by chunk (30 min scenarios, sent in 5 min pieces), so memory
stays bounded and this process never imports the simulator. On a schedule: a broken rear outer
coil at the leading-left corner for 30 to 60 min, then healthy again (three times); a channel
stuck, a dead channel with its sensor-fault bit, an hour of frequent dropouts, a standstill;
gaps; config reloads by SIGHUP (one rejected); restarts of the service on the same state dir,
one during an alarm and one during a sensor fault.

The decision is the daemon's default, decision.method "fused" with its trend, with the load
fixed at "full", on the wagon's own calibration, learned by bogiemon.daemon.calibrate from a
healthy calibration run of the same simulated wagon (2 h, other seeds), written beside the
config and included (the fragment holds the fused baseline and the thresholds alike).

It checks: RSS flat (the least-squares slope after the first WARMUP_H simulated hours below
RSS_SLOPE_BOUND_MB_PER_H, with a level of its own after each in-process restart or reload: see
rss_slope_mb_per_h), no exception escapes (every service exits 0, no error in the log
but the rejected reload), every expected event exactly once in the event store (one CONFIRMED
per fault phase and one CLEARED of it after the phase, none elsewhere; SENSOR_FAULT events only
in sensor phases, one SENSOR_CLEARED after each), events carry the config hash in force, and
the counters add up (per service: judged + gated + sensor-fault windows = windows = what the
segments fed allow, samples and blocks = those fed, nothing dropped by the ring).
Exit status 0 when every check passes, 1 otherwise; figures printed and written as JSON.
Run with `make soak` or `.venv/bin/python bench/soak.py [--short] [--json PATH]`.
"""

from __future__ import annotations

import argparse
import functools
import json
import multiprocessing
import sys
import tempfile
import threading
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from soak_checks import (  # noqa: E402
    RSS_SLOPE_BOUND_MB_PER_H,
    WARMUP_H,
    Checks,
    SoakRun,
    check_counters,
    check_events,
    check_health,
    data_s,
    rss_steps_mb,
)
from soak_feed import (  # noqa: E402
    Feed,
    Lifetime,
    Observer,
    RecordingNotifier,
    SoakError,
    SoakSource,
    calibration_fragment,
    generate,
)
from soak_schedule import FS_HZ, HOUR_S, Schedule, day_schedule, short_schedule  # noqa: E402

from bogiemon.daemon.config import BogiemonConfig, load_config  # noqa: E402
from bogiemon.drivers.atomic import write_text_atomically  # noqa: E402
from bogiemon.judgement.events import ClearedDetails  # noqa: E402
from bogiemon.daemon.logs import configure_logging  # noqa: E402
from bogiemon.daemon.service import Service  # noqa: E402
from bogiemon.daemon.store import EventStore  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results" / "soak-latest.json"


# ---- running it -------------------------------------------------------------------------------


def config_text(state_dir: Path, wagon_id: str) -> str:
    # The daemon's default decision (fused, with its trend) on the wagon's own calibration,
    # the load fixed (the simulated wagon runs loaded all day).
    return "\n".join([
        'include = ["thresholds.toml"]',
        "[wagon]", f'id = "{wagon_id}"',
        "[processing]", f"fs_hz = {FS_HZ}",
        "[decision]", 'method = "fused"', 'load = "full"',
        "[state]", f'directory = "{state_dir}"', "",
    ])  # fmt: skip


def bad_config_text(good: str) -> str:
    return good.replace('load = "full"', 'load = "full"\nconfirm_k = 9\nconfirm_n = 5')


def _given(source: SoakSource, _config: BogiemonConfig) -> SoakSource:
    return source


def run_soak(schedule: Schedule, workdir: Path) -> SoakRun:
    state_dir = workdir / "state"
    config_path = workdir / "bogiemon.toml"
    variants = {"a": config_text(state_dir, "soak-a"), "b": config_text(state_dir, "soak-b")}
    variants["bad"] = bad_config_text(variants["a"])
    (workdir / "thresholds.toml").write_text("")
    write_text_atomically(config_path, variants["a"])
    ctx = multiprocessing.get_context("spawn")
    pieces = ctx.Queue(maxsize=4)
    generator = ctx.Process(target=generate, args=(schedule, pieces, 1), name="soak-generator", daemon=True)
    generator.start()
    with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
        fragment_text, calibration = pool.submit(calibration_fragment, str(config_path)).result()
    (workdir / "thresholds.toml").write_text(fragment_text)
    config = load_config(config_path)
    settings = config.processing_settings(FS_HZ)
    feed = Feed(schedule, pieces, settings.hop_n, settings.window_n // settings.hop_n)
    feed.config_hashes.append((0.0, config.digest()))
    observer = Observer()
    log_path = workdir / "daemon.log"
    lifetimes: list[Lifetime] = []
    escaped: list[str] = []  # exceptions that ended a thread: the pipeline's own catch them and log
    threading.excepthook = lambda args: escaped.append(f"{args.thread.name if args.thread else '?'}: {args.exc_type.__name__}: {args.exc_value}")
    t0 = time.monotonic()
    with log_path.open("w") as log:
        configure_logging(stream=log)
        while not feed.exhausted:
            notifier = RecordingNotifier()
            source = SoakSource(feed, config_path, variants, observer, notifier)
            service = Service(config_path, functools.partial(_given, source), notifier=notifier, observers=[observer.observe])
            service.install_signal_handlers()
            source.lifetime.exit_status = service.run()
            lifetimes.append(source.lifetime)
            feed.epoch += 1
            if source.lifetime.exit_status != 0:
                break
    wall_s = time.monotonic() - t0
    threading.excepthook = threading.__excepthook__
    if not feed.exhausted:
        generator.terminate()  # a service failed: the checks say which
    generator.join(timeout=30)
    store = EventStore(state_dir, readonly=True)
    try:
        events, final_state = store.events(), store.get_state("monitor") or {}
    finally:
        store.close()
    records = [json.loads(line.split(">", 1)[1]) for line in log_path.read_text().splitlines() if line.startswith("<")]
    return SoakRun(schedule, calibration, lifetimes, feed, observer.windows, wall_s, events, records, final_state, escaped, observer.trend_below_warning)


# ---- the report -------------------------------------------------------------------------------


def summary(run: SoakRun, checks: Checks, slope: float, peak_mb: float, totals: dict[str, int]) -> dict[str, Any]:
    fed_h = run.feed.fed_samples / FS_HZ / HOUR_S
    rss = run.feed.rss_samples
    warm = [mb for h, mb, _ in rss if h >= WARMUP_H]
    cleared = Counter(str(e.details.cleared) for e in run.events if isinstance(e.details, ClearedDetails))
    return {
        "simulated_hours": run.schedule.duration_s / HOUR_S,
        "fed_hours": fed_h,
        "lost_s": run.feed.lost_samples / FS_HZ,
        "wall_s": run.wall_s,
        "x_real_time": fed_h * HOUR_S / run.wall_s,
        "rss_mb": {"first": rss[0][1], "after_warmup": warm[0] if warm else None, "end": rss[-1][1], "max": peak_mb,
                   "slope_mb_per_h": slope, "bound_mb_per_h": RSS_SLOPE_BOUND_MB_PER_H, "samples": len(rss),
                   "steps_at_restarts_and_reloads": rss_steps_mb(rss),
                   "by_hour": [[round(h, 3), round(mb, 2), e] for h, mb, e in rss]},
        "events": dict(Counter(e.kind.value for e in run.events)),
        "cleared": dict(cleared),
        "counters": totals,
        "services": len(run.lifetimes),
        "reloads": sum(life.reloads for life in run.lifetimes),
        "rejected_reloads": sum(life.bad_reloads for life in run.lifetimes),
        "gaps": sum(life.gap_blocks for life in run.lifetimes),
        "calibration": run.calibration,
        "checks_passed": len(checks.passed),
        "checks_failed": checks.failed,
        "passed": not checks.failed,
    }  # fmt: skip


def print_report(s: dict[str, Any], checks: Checks, run: SoakRun) -> None:
    rss, c = s["rss_mb"], s["counters"]
    print(f"soak: {s['simulated_hours']:.2f} simulated hours ({s['fed_hours']:.3f} h fed, {s['lost_s']:.0f} s lost to gaps and restarts)"
          f" in {s['wall_s']:.0f} s wall: {s['x_real_time']:.0f}x real time")
    print(f"calibration: {s['calibration']}")
    print(f"RSS: {rss['first']:.1f} MB at the first piece, {rss['after_warmup']:.1f} MB after {WARMUP_H:g} h, {rss['end']:.1f} MB at the end,"
          f" max {rss['max']:.1f} MB; slope {rss['slope_mb_per_h']:+.3f} MB per simulated hour (bound {rss['bound_mb_per_h']:g});"
          f" steps at in-process restarts and reloads {rss['steps_at_restarts_and_reloads']} MB")
    print("events: " + ", ".join(f"{k} {v}" for k, v in sorted(s["events"].items()))
          + " (CLEARED of " + ", ".join(f"{k} {v}" for k, v in sorted(s["cleared"].items())) + ")")
    print(f"counters: windows {c['windows']} = judged {c['judged']} + gated {c['gated']} + sensor-fault {c['sensor_fault_windows']};"
          f" samples {c['samples']} = fed {run.feed.fed_samples}; blocks {c['blocks']}; segments {c['segments']}; events {c['events']}")
    print(f"services: {s['services']} ({s['services'] - 1} restarts), reloads {s['reloads']} applied + {s['rejected_reloads']} rejected, {s['gaps']} gaps")
    for phase in run.schedule.phases:
        if phase.kind != "healthy":
            got = Counter(e.kind.value for e in run.events if phase.start_s <= data_s(e) < phase.end_s + 600.0)
            print(f"  {phase.label():<26} events within it (+10 min): " + (", ".join(f"{k} {v}" for k, v in sorted(got.items())) or "none"))
    for what in checks.failed:
        print(f"FAILED: {what}")
    print(f"checks: {len(checks.passed)} passed, {len(checks.failed)} failed: {'PASS' if s['passed'] else 'FAIL'}")  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--short", action="store_true", help="about 6 simulated hours with one of everything (trying it out)")
    parser.add_argument("--json", type=Path, default=RESULTS, help="where to write the figures (default bench/results/soak-latest.json)")
    parser.add_argument("--keep", type=Path, help="keep the state directory, config and daemon log in this folder")
    args = parser.parse_args()
    schedule = short_schedule() if args.short else day_schedule()
    with tempfile.TemporaryDirectory(prefix="bogiemon-soak-") as tmp:
        workdir = args.keep or Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        try:
            run = run_soak(schedule, workdir)
        except SoakError as exc:
            print(f"soak: error: {exc}", file=sys.stderr)
            return 2
        config: BogiemonConfig = load_config(workdir / "bogiemon.toml")
        settings = config.processing_settings(FS_HZ)
        checks = Checks()
        slope, peak_mb = check_health(run, checks)
        totals = check_counters(run, settings.hop_n, settings.window_n // settings.hop_n, checks)
        check_events(run, settings.window_s, settings.hop_s, config.decision.clear_after_windows, config.health.clear_after_windows, checks)
    s = summary(run, checks, slope, peak_mb, totals)
    print_report(s, checks, run)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({**s, "schedule": [asdict(p) for p in schedule.phases], "checks": checks.passed}, indent=2) + "\n")
    return 0 if s["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
