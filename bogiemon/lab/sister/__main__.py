"""`python -m bogiemon.lab.sister`: the sister study from simulation to report (issue 33, docs/wagon.md).

    python -m bogiemon.lab.sister                       # simulate (cached under build/sister), study,
                                                        # fit config/sister_model.toml, evaluate, report
    python -m bogiemon.lab.sister --study-only          # the features' table alone (training fleets)
    python -m bogiemon.lab.sister --size quick --out /tmp/wagon --model-out /tmp/sister_model.toml

Steps: both models' fleets simulated (lab/sister/plan.py; a rerun reads the cache); the features
measured on the training fleets and the sister's chosen (lab/sister/study.py); the prior fitted on
both training fleets (lab/sister/fit.py) and written to --model-out; the evaluation wagons judged
with it (lab/sister/evaluate.py, lab/sister/score.py); the commissioning guard measured
(lab/sister/guard.py); tables.md, results.json and figures/ written into --out.
"""

from __future__ import annotations

import argparse
import sys
import time

from bogiemon.daemon.config import default_config_text, parse_config
from bogiemon.judgement.models import shipped_models
from bogiemon.judgement.sister import load_sister_model
from bogiemon.lab.sister.evaluate import evaluate_model
from bogiemon.lab.sister.features import table_of
from bogiemon.lab.sister.fit import SISTER_MODEL_PATH, fit_sister_model, write_sister_model
from bogiemon.lab.sister.guard import guard_study
from bogiemon.lab.sister.plan import SisterData, SisterPlan, simulate_sister
from bogiemon.lab.sister.report import write_report
from bogiemon.lab.sister.study import choose_features, measure

TRAINING = ("train-healthy", "train-fault")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bogiemon.lab.sister", description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=("default", "quick"), default="default", help="the plan (quick: a test's)")
    parser.add_argument("--models", nargs="+", choices=("a", "b"), default=["a", "b"])
    parser.add_argument("--cache", default="build/sister", help="folder of the simulated runs' windows (default: build/sister)")
    parser.add_argument("--out", default="docs/wagon", help="folder of tables.md, results.json, figures/ (default: docs/wagon)")
    parser.add_argument("--model-out", default=str(SISTER_MODEL_PATH), help="where the fitted prior is written (default: the shipped one)")
    parser.add_argument("--study-only", action="store_true", help="measure the features on the training fleets, nothing else")
    args = parser.parse_args(argv)
    command = "python -m bogiemon.lab.sister" + ("" if argv is None else " " + " ".join(argv))
    started = time.perf_counter()

    def say(text: str) -> None:
        print(f"[{time.perf_counter() - started:7.0f} s] {text}", file=sys.stderr, flush=True)

    config = parse_config(default_config_text(), "the default config")
    settings, geometry, health = config.processing_settings(), config.bogie_geometry(), config.health_settings()
    plans = {m: SisterPlan.default(m) if args.size == "default" else SisterPlan.quick(m) for m in args.models}
    datas: dict[str, SisterData] = {}
    for model, plan in plans.items():
        roles = TRAINING if args.study_only else None
        datas[model] = simulate_sister(plan, settings, geometry, args.cache, roles=roles)
        say(f"model {model.upper()}: {len(datas[model].runs)} runs, {datas[model].simulated_s / 3600:.1f} h ({datas[model].new_s / 3600:.1f} h simulated now)")
    rows = []
    tables = {}
    for model, data in datas.items():
        tables[model] = (table_of(data.select(role="train-healthy"), geometry), table_of(data.select(role="train-fault"), geometry))
        rows += measure(model, *tables[model])
    chosen, steps = choose_features(tables)
    say("the sister's features: " + "; ".join(f"{load}: {', '.join(names) or '(none)'}" for load, names in chosen.items()))
    configurations, stretches = [], []
    if not args.study_only and any(chosen.values()):
        fused = shipped_models().fused
        fitted = fit_sister_model(datas, chosen, health, {str(k): v for k, v in fused.items()}, config.decision.confirm_k, config.decision.confirm_n)
        description = "\n".join(
            [f"training fleets of the sister plan '{args.size}' (lab/sister/plan.py), held out from its evaluation fleets:"]
            + [f"model {m.upper()}: {p.n_training_wagons} wagons, {p.training_healthy_runs} healthy runs of {p.run_s:g} s per wagon and load, the first {p.commissioning_runs} its commissioning" for m, p in plans.items()]
            + [f"features chosen per load by lab/sister/study.py choose_features; windows of {settings.window_s:g} s every {settings.hop_s:g} s"]
        )
        path = write_sister_model(fitted, args.model_out, command, description)
        say(f"wrote {path}")
        prior = load_sister_model(path)
        for model, data in datas.items():
            configurations += evaluate_model(data, config, prior)
            say(f"model {model.upper()}: judged")
        stretches = guard_study(datas, prior, {str(k): v for k, v in fused.items()}, health)
        say("guard measured")
    header = [
        "# The whole wagon: the sister study's tables (generated)",
        "",
        f"Generated by `{command}` ({time.strftime('%Y-%m-%d')}); docs/wagon.md reads them.",
        "Runs per model: " + "; ".join(f"{m.upper()}: {len(d.runs)} runs, {d.simulated_s / 3600:.1f} h of running, both bogies" for m, d in datas.items()),
    ]
    written = write_report(args.out, rows, chosen, steps, configurations, stretches, header, {"command": command, "plans": {m: vars(p) for m, p in plans.items()}})
    say("wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
