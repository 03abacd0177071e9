"""The detection study (issue 4): the paper's experiment matrix on the simulator, its Table 4, and
evidence for the daemon's defaults (window length, normalisation, thresholds).

    plan = StudyPlan.default()                           # or StudyPlan.quick()       (plan.py)
    result = run_study(plan, settings, geometry)         # simulate, then the core    (run.py)
    table = identify(result)                             # Table 4 under the rule     (rules.py)
    evidence = defaults_evidence(result)                 # the defaults rules         (defaults.py)
    write_report(result, "docs/study", command="bogiemon study -o docs/study")   (report.py, text.py)

THE MATRIX. For each load (full, tare): the healthy wagon and every fault case of the paper's
tables (Type A by spring position and severity, Type B by severity; the shipped verbatim copy of
../shared/paper/y25_fault_cases.toml), the fault on one corner of the monitored bogie
(leading-left, the corner of sensor a1, by default), at each speed and track quality of the plan,
several runs each (independent track realisations). Each run's seed is the CRC-32 of its name
(load, case, severity, speed, track, run number), so the quick plan's runs are the same runs as the
default plan's at its condition and every run is reproducible alone. Each signal is simulated
once and analysed for every window length (analysis is cheap, simulation is not).

THE IDENTIFICATION RULE, fixed before any result was looked at (not to be tuned to the paper):
for one load, speed, track and window length, the healthy reference is every window of the
healthy runs, with, per indicator, its median m and the 99th percentile h of the deviation
|x - m|. A window is flagged when |x - m| > h. A severity's detection share is the share of its
windows that are flagged, pooled over the plan's speeds and tracks (each window judged against the
reference of its own speed and track). A fault case (a row of Table 4) is IDENTIFIED by an
indicator when the detection share is at least RULE_MIN_SHARE = 0.5 for EVERY severity of the
case: the median faulty window lies beyond the healthy 1 % tail. The rule's per-window
false-alarm rate is 1 % in-sample by construction; out of sample (two-fold over the healthy runs:
the reference from the even-numbered runs judges the odd-numbered ones, and back) it must stay at
or below RULE_MAX_FALSE_ALARM = 3 %.

THE DEFAULTS RULES. Thresholds: the daemon's own rule (judgement/rules.py fit_threshold, which
`bogiemon calibrate` runs: warning and alarm at per-window false-alarm targets 1e-2 and 1e-4,
robust sigma and empirical terms), applied per load to
all healthy windows pooled over speeds and tracks (the daemon knows the load, not the speed or
the track): the matrix's, and the envelope's (healthy runs at 40 and 120 km/h, the rest of the
speeds the daemon judges). The envelope was added after the first full run, in which thresholds
from the matrix's speeds alone confirmed alarms on healthy runs at 40 km/h; the report shows
that comparison on every run. Indicators per load: forward selection on the per-window alarm-level
detection share over all fault windows of the load: start with the best indicator, add the next
best while it raises the share of windows in which any selected indicator reaches its alarm
level by at least SELECTION_MIN_GAIN (2 points), at most SELECTION_MAX_INDICATORS (3). Window
length: the one with the highest combined share, averaged over the loads; a shorter window
within WINDOW_TIE (2 points) of the best wins (quicker confirmation, less speed change inside a
window); a window length is eligible only if no healthy run of the study (matrix or envelope)
confirms an alarm (confirm_k of confirm_n windows at alarm level) and every full-load
broken-outer-spring run of the matrix does.
"""


from bogiemon.lab.study.defaults import (
    DecisionEvidence,
    DefaultsEvidence,
    ThresholdCheck,
    calibrate_thresholds,
    check_thresholds,
    decision_evidence,
    defaults_evidence,
)
from bogiemon.lab.study.plan import INDICATORS, Condition, FaultCase, StudyPlan, StudyRun, paper_table4, table4_cases
from bogiemon.lab.study.report import write_report
from bogiemon.lab.study.rules import (
    RULE_MAX_FALSE_ALARM,
    RULE_MIN_SHARE,
    CaseEvidence,
    Reference,
    identify,
    roc_auc,
    rule_detection_rate,
    rule_false_alarm,
)
from bogiemon.lab.study.run import StudyResult, run_study, window_settings

__all__ = [
    "INDICATORS",
    "RULE_MAX_FALSE_ALARM",
    "RULE_MIN_SHARE",
    "CaseEvidence",
    "Condition",
    "DecisionEvidence",
    "DefaultsEvidence",
    "FaultCase",
    "Reference",
    "StudyPlan",
    "StudyResult",
    "StudyRun",
    "ThresholdCheck",
    "calibrate_thresholds",
    "check_thresholds",
    "decision_evidence",
    "defaults_evidence",
    "identify",
    "paper_table4",
    "roc_auc",
    "rule_detection_rate",
    "rule_false_alarm",
    "run_study",
    "table4_cases",
    "window_settings",
    "write_report",
]
