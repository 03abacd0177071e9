"""The observability check (lab/robust/observability.py): its reference, visibility and signs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bogiemon.detection import Corner
from bogiemon.lab.robust.observability import BANDS, PAIRS, aligned_shifts, case_of, fit_reference, main, softer_sign, visible_share


def test_the_reference_shrinks_the_covariance_towards_its_diagonal_by_p_over_p_plus_the_independent_windows() -> None:
    rng = np.random.default_rng(3)
    x = rng.multivariate_normal([1.0, -2.0, 0.5], [[1.0, 0.6, 0.2], [0.6, 2.0, -0.4], [0.2, -0.4, 0.5]], size=240)
    reference = fit_reference(x, overlap=12.0)
    lam = 3 / (3 + 240 / 12.0)
    s = np.cov(x.T)
    expected = (1 - lam) * s + lam * np.diag(np.diag(s))
    covariance = np.linalg.inv(reference.whitening.T @ reference.whitening)
    np.testing.assert_allclose(covariance, expected, rtol=1e-10)
    np.testing.assert_allclose(reference.center, x.mean(axis=0), rtol=1e-12)
    # The score is the Mahalanobis distance squared, against a direct solve.
    row = x[7]
    direct = float((row - x.mean(axis=0)) @ np.linalg.solve(expected, row - x.mean(axis=0)))
    assert reference.scores(row)[0] == pytest.approx(direct, rel=1e-10)


def test_a_reference_of_fewer_than_two_windows_is_refused() -> None:
    with pytest.raises(ValueError, match="at least 2 windows"):
        fit_reference(np.zeros((1, 3)), overlap=1.0)


def test_visibility_is_near_the_tail_for_no_shift_and_one_for_a_gross_shift() -> None:
    rng = np.random.default_rng(11)
    healthy = rng.normal(size=(200_000, 4))
    reference = fit_reference(healthy[:100_000], overlap=1.0)
    healthy_scores = reference.scores(healthy[100_000:150_000])
    same = visible_share(healthy_scores, reference.scores(healthy[150_000:]))
    shifted = visible_share(healthy_scores, reference.scores(healthy[150_000:] + np.array([12.0, 0.0, 0.0, 0.0])))
    assert 0.0003 < same < 0.003  # 0.001 expected: the quantile's own tail
    assert shifted == 1.0


def test_visibility_without_scores_is_an_error() -> None:
    with pytest.raises(ValueError, match="both healthy and fault scores"):
        visible_share(np.array([]), np.array([1.0]))


def test_a_softer_corner_s_own_pattern_aligns_to_all_positive_at_every_corner() -> None:
    n = len(BANDS)
    shifts = {c: np.concatenate([np.full(n, 0.1 * softer_sign(pair, c)) for pair in PAIRS]) for c in Corner}
    aligned = aligned_shifts(shifts)
    assert aligned.shape == (4, 3, n)
    np.testing.assert_allclose(aligned, 0.1)
    # The diagonal corner's pattern, softened, reads as the stiffened one's: bounce-pitch and
    # bounce-roll flip, pitch-roll (x y) does not.
    c, d = Corner.LEADING_LEFT, Corner.TRAILING_RIGHT
    assert [softer_sign(p, c) for p in PAIRS] == [-softer_sign("bounce-pitch", d), -softer_sign("bounce-roll", d), softer_sign("pitch-roll", d)]


def test_only_broken_coils_are_cases() -> None:
    assert case_of("type_a.full.front_outer", 0.0) == "full front_outer"
    assert case_of("type_a.full.front_outer", 0.5) is None
    assert case_of("type_b.full", 0.0) is None
    assert case_of("healthy", 1.0) is None


def test_an_unreadable_data_file_is_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "data.pkl"
    bad.write_bytes(b"not a pickle")
    assert main(["--data", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("observability: error:") and str(bad) in err and "\n" not in err
