"""kill -9 at random moments of `bogiemon replay` and `bogiemon run` (issue 17), by the hundred; and
of `bogiemon run` with its recorder on a small disk, then filled to its last page (issue 37).

Each trial starts the real command on a recording with twelve alarm cycles (36 events), kills it
with SIGKILL at a seeded random moment (one in five at a random time into the start-up, where
the store is created and opened; the others up to 0.1 s after a random number of printed
events), and judges what it left with the checks of tests/daemon/test_kill9.py: the store
opens; every event the process printed (it prints only what is committed) is in the store; no
event twice; the store holds a prefix of the uninterrupted run's events; the stored state is the
one committed with the last stored event; a restarted monitor, and for `run` a restarted
`bogiemon run`, starts from it. The disk trials (tests/daemon/test_kill9_disk.py, root only: a
tmpfs each) kill `run` with its recorder at a random moment, fill the disk to its last page with
what it left (the temporary of a recording killed in its write, else a recording), and start it
again: it must give back its own files, commit the run's events and exit 0.

    .venv/bin/python bench/kill9.py                 # 60 trials of each command and 20 disk trials, seed 17 (make kill9)
    .venv/bin/python bench/kill9.py --trials 5 --disk-trials 2 --seed 3

Prints one line per command and exits 1 if any trial failed a check (naming the trial).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.daemon.test_kill9 import KINDS, TrialResult, Workload, draw_moment, make_workload, run_trial  # noqa: E402
from tests.daemon.test_kill9_disk import DiskTrialResult, as_line, mount_tmpfs, run_disk_trial, unmount  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=60, help="trials per command (default 60: 120 in all)")
    parser.add_argument("--disk-trials", type=int, default=20, help="trials of run with its recorder on a disk it fills (default 20; root only)")
    parser.add_argument("--seed", type=int, default=17)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    failed: list[tuple[int, TrialResult]] = []
    with tempfile.TemporaryDirectory(prefix="bogiemon-kill9-") as scratch:
        work = Path(scratch)
        workload = make_workload(work / "workload")
        print(f"kill -9: {args.trials} trials per command, seed {args.seed}, {len(workload.events)} events in an uninterrupted run")
        print(f"{'command':8} {'trials':>6} {'ended':>5} {'printed':>7} {'open-fail':>9} {'lost':>4} {'dup':>3} {'unlike':>6} {'state':>5} {'restart':>7} {'time':>6}")
        for kind in KINDS:
            started = time.monotonic()
            results = []
            for i in range(args.trials):
                result = run_trial(workload, kind, *draw_moment(rng, workload), work / f"{kind}-{i}")
                results.append(result)
                if not result.ok:
                    failed.append((i, result))
            print(
                f"{kind:8} {len(results):>6} {sum(r.completed for r in results):>5} {sum(r.reported for r in results):>7} "
                f"{sum(not r.store_opened for r in results):>9} {sum(r.lost for r in results):>4} {sum(r.duplicated for r in results):>3} "
                f"{sum(r.unlike_reference for r in results):>6} {sum(r.state_mismatch for r in results):>5} "
                f"{sum(r.restart_mismatch for r in results):>7} {time.monotonic() - started:>5.0f}s"
            )
        disk_failed = _disk_trials(args.disk_trials, rng, workload, work)
    print("ended: the process finished before its kill; printed: events it printed (committed) before the kill")
    for i, result in failed:
        print(f"FAILED {result.kind} trial {i}: {result}", file=sys.stderr)
    for i, disk_result in disk_failed:
        print(f"FAILED disk trial {i}: {as_line(disk_result)}", file=sys.stderr)
    return 1 if failed or disk_failed else 0


def _disk_trials(n: int, rng: np.random.Generator, workload: Workload, work: Path) -> list[tuple[int, DiskTrialResult]]:
    """The disk trials, one line of figures; those that failed."""
    why = mount_tmpfs(work / "probe")
    if why is None:
        unmount(work / "probe")
    if n == 0 or why is not None:
        print(f"{'disk':8} not run: {why or 'no trials asked for'}")
        return []
    started = time.monotonic()
    results = [run_disk_trial(workload, *draw_moment(rng, workload), work / f"disk-{i}") for i in range(n)]
    print(
        f"{'disk':8} {n:>6} {sum(r.completed for r in results):>5} killed in a write: {sum(r.left == 'recording temporary' for r in results)}, "
        f"restart not 0: {sum(r.restart_status != 0 for r in results)}, temporaries left: {sum(r.temporaries_left for r in results)}, "
        f"reserve not free: {sum(not r.reserve_free for r in results)}, events fewer: {sum(r.stored_after < r.stored_before for r in results)} "
        f"{time.monotonic() - started:>5.0f}s"
    )
    return [(i, r) for i, r in enumerate(results) if not r.ok]


if __name__ == "__main__":
    sys.exit(main())
