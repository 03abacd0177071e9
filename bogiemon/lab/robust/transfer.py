"""`bogiemon evaluate --transfer`: every prior fitted on one wagon model, judged on the other (issue 16).

    plans = transfer_plans("default")                   # the same plan on wagon models A and B
    doc = run_transfer(config, "docs/robust/transfer", command="bogiemon evaluate --transfer ...")

bogiemon ships priors fitted on its own simulator (config/load_model.toml and fused_model.toml).
Here they are fitted, by the rule `make evaluate` uses (lab/modelfit.py),
on the training fleet of each wagon model in turn (model A: simulator/vehicle.py; model B:
simulator/model_b, formulated independently), written into a temporary folder and given to the
daemon as decision.models_dir. The daemon's default method (fused, calibrated: each wagon
commissioned per load on its own calibration runs) then judges the evaluation fleets of both
models: A's priors on A and on B, B's on B and on A. The targets are issue 16's, stated here
before any result; they are about the model the priors were NOT fitted on, and the same-model
judgements beside them give the transfer gap (cross-model minus same-model, on one evaluation
fleet). Every figure is a count of runs, windows or events; TARGETS says how each is counted.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Any

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.lab.robust.evaluate import EvaluateError, fit_and_write_models
from bogiemon.lab.robust.transfer_plan import Progress, judge_transfer, load_or_simulate_models, transfer_plans
from bogiemon.lab.robust.transfer_report import write_transfer_report

# --------------------------------------------------------------------------------------------
# The command


def run_transfer(
    config: BogiemonConfig,
    out_dir: str | Path,
    command: str,
    size: str = "default",
    data_file: str | Path | None = None,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Simulate (or load) the plan on both models, fit each model's priors into a temporary
    folder, judge the four combinations and write README.md and results.json into out_dir."""
    started = time.perf_counter()
    plans = transfer_plans(size)

    def part(base: float, share: float) -> Progress | None:
        return None if progress is None else (lambda f: progress(base + share * f))

    data = load_or_simulate_models(plans, config, data_file, part(0.0, 0.85))
    with tempfile.TemporaryDirectory(prefix="bogiemon-priors-") as folder:
        dirs = {}
        for model, fleet in data.items():
            dirs[model] = Path(folder) / model
            dirs[model].mkdir()
            fit_and_write_models(fleet, config, dirs[model])
        judgements = judge_transfer(data, config, dirs, part(0.85, 0.15))
    try:
        return write_transfer_report(data, judgements, out_dir, command, time.perf_counter() - started)
    except OSError as exc:
        raise EvaluateError(f"{out_dir}: cannot write the report: {exc.strerror or exc}") from None
