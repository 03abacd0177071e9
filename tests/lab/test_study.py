"""The detection study: the quick plan's headline, the rule's parts against direct references, the report, the command.

The thresholds and the confirmation are the daemon's own rules (tests/daemon/test_rules.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import stats

from bogiemon.cli.main import main
from bogiemon.daemon.config import load_config
from bogiemon.judgement.vocabulary import LoadState
from bogiemon.lab.study import (
    INDICATORS,
    RULE_MAX_FALSE_ALARM,
    RULE_MIN_SHARE,
    Reference,
    StudyPlan,
    StudyResult,
    check_thresholds,
    decision_evidence,
    identify,
    paper_table4,
    roc_auc,
    rule_false_alarm,
    run_study,
    table4_cases,
    write_report,
)

I2, I4 = INDICATORS.index("i2"), INDICATORS.index("i4")


@pytest.fixture(scope="module")
def quick() -> StudyResult:
    """The quick plan with the shipped config's processing settings (about 30 s on two cores)."""
    config = load_config()
    return run_study(StudyPlan.quick(config.processing.window_s), config.processing_settings(), config.bogie_geometry())


def test_a_broken_rear_outer_coil_at_full_load_is_identified_by_i2_and_i4(quick: StudyResult) -> None:
    broken = {s.severity: s for s in identify(quick)["type_a.full.rear_outer"].severities}[0.0]
    assert broken.n_windows > 0
    assert broken.detection_share[I2] >= RULE_MIN_SHARE
    assert broken.detection_share[I4] >= RULE_MIN_SHARE


def test_healthy_windows_stay_under_the_rules_false_alarm_rate(quick: StudyResult) -> None:
    for load, rates in rule_false_alarm(quick).items():
        assert np.all(rates <= RULE_MAX_FALSE_ALARM), (load, dict(zip(INDICATORS, rates, strict=True)))


def test_the_shipped_thresholds_confirm_no_healthy_run_and_every_broken_rear_outer_coil(quick: StudyResult) -> None:
    thresholds = load_config().decision_settings().thresholds
    full = check_thresholds(quick, "full", quick.default_window_s, thresholds[LoadState.FULL])
    tare = check_thresholds(quick, "tare", quick.default_window_s, thresholds[LoadState.TARE])
    assert full.healthy_runs == tare.healthy_runs == 24
    assert full.healthy_confirmed_runs == tare.healthy_confirmed_runs == 0
    assert full.confirmed_share_per_case["type_a.full.rear_outer@0"] == 1.0


def test_the_derived_thresholds_never_alarm_on_the_healthy_windows_they_come_from(quick: StudyResult) -> None:
    evidence = decision_evidence(quick, "full", quick.default_window_s)
    assert evidence.check.healthy_alarm_windows == 0
    assert evidence.check.broken_outer_confirmed_runs == evidence.check.broken_outer_runs > 0


def test_the_quick_plan_runs_a_subset_of_the_default_plans_runs() -> None:
    quick = StudyPlan.quick()
    default = StudyPlan.default()
    assert quick.duration_s == default.duration_s
    names = {(r.name, r.seed) for r in default.runs() if r.group == ""}
    assert {(r.name, r.seed) for r in quick.runs()} <= names
    assert len({r.seed for r in default.runs() if r.group == ""}) == len(names)  # every main run its own track


def test_every_row_of_the_papers_table4_is_a_case_with_its_tables_severities() -> None:
    rows = table4_cases()
    assert set(rows) == set(paper_table4())
    assert rows["type_a.full.rear_outer"] == (0.0, 0.5, 1.5, 2.0)
    assert rows["type_b.full"] == (0.5, 0.75, 1.25, 1.5)
    assert len(rows) == 8


def test_the_reference_flags_deviations_beyond_the_healthy_99th_percentile() -> None:
    healthy = np.tile(np.linspace(-1.0, 1.0, 2001)[:, None], (1, len(INDICATORS)))
    ref = Reference.of(healthy)
    np.testing.assert_allclose(ref.center, 0.0, atol=1e-12)
    np.testing.assert_allclose(ref.limit, 0.99, rtol=1e-9)  # |d| spans 0..1 uniformly
    flags = ref.flags(np.array([[0.989] * 8, [-0.991] * 8]))
    assert not flags[0].any() and flags[1].all()


@given(st.lists(st.integers(0, 5), min_size=1, max_size=30), st.lists(st.integers(0, 5), min_size=1, max_size=30))
def test_roc_auc_is_the_mann_whitney_statistic(faulty: list[int], healthy: list[int]) -> None:
    f, h = np.array(faulty, dtype=float), np.array(healthy, dtype=float)
    u = stats.mannwhitneyu(f, h, alternative="two-sided").statistic
    assert roc_auc(f, h) == pytest.approx(u / (len(f) * len(h)), abs=1e-12)


def test_the_report_has_table4_for_every_case_the_figures_and_the_defaults(quick: StudyResult, tmp_path: Path) -> None:
    doc = write_report(quick, tmp_path, command="bogiemon study --quick -o X", configured=load_config().decision_settings().thresholds)
    saved = json.loads((tmp_path / "table4.json").read_text(encoding="utf-8"))
    assert saved == json.loads(json.dumps(doc))
    assert set(saved["cases"]) == set(paper_table4())
    for case in saved["cases"].values():
        assert len(case["ours"]) == len(case["paper"]) == len(case["agree"]) == 4
        assert [case["indicators"][f"I{j + 1}"]["identified"] for j in range(4)] == case["ours"]
    assert saved["agreement"]["cells"] == 32
    readme = (tmp_path / "README.md").read_text(encoding="utf-8")
    assert "bogiemon study --quick -o X" in readme and f"{saved['agreement']['agree']} of 32 cells agree" in readme
    for name in ("fig3_full_rear_outer.png", "fig4_tare_rear_outer.png", "fig5_full_type_b.png"):
        assert (tmp_path / "figures" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "## The defaults" in (tmp_path / "defaults.md").read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--windows-s", "25"], "window 25 s must be a whole number of hops (10 s)"),
        (["--windows-s", "thirty"], "--windows-s 'thirty': expected seconds separated by commas"),
    ],
)
def test_bad_window_lengths_end_in_one_line_and_status_2(tmp_path: Path, capsys, arguments: list[str], message: str) -> None:
    assert main(["study", "-o", str(tmp_path / "report"), "-q", *arguments]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bogiemon: error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "report").exists()


def test_an_output_that_is_a_file_ends_in_one_line_and_status_2(tmp_path: Path, capsys) -> None:
    target = tmp_path / "report.md"
    target.write_text("not a folder\n", encoding="utf-8")
    assert main(["study", "-o", str(target), "--quick"]) == 2
    assert capsys.readouterr().err == f"bogiemon: error: {target}: exists and is not a folder: choose a folder for the report with -o\n"
