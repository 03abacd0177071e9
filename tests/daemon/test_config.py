"""The config file: defaults documented in the shipped file, every bad field named with its path."""

import tomllib
from pathlib import Path

import pytest

from bogiemon.daemon import tomlout
from bogiemon.daemon.config import BogiemonConfig, ConfigError, default_config_text, load_config, parse_config
from bogiemon.judgement.vocabulary import LoadState
from bogiemon.detection import BogieGeometry, Corner, ProcessingSettings


def test_shipped_default_file_states_the_model_defaults() -> None:
    assert load_config(None) == BogiemonConfig()


def test_every_field_of_the_shipped_file_has_a_comment_above_it() -> None:
    lines = default_config_text().splitlines()
    for i, line in enumerate(lines):
        if "=" in line and not line.lstrip().startswith("#"):
            assert lines[i - 1].lstrip().startswith("#"), f"no comment above '{line}'"


def test_defaults_give_the_core_its_documented_settings() -> None:
    config = BogiemonConfig()
    assert config.processing_settings() == ProcessingSettings()
    assert config.bogie_geometry() == BogieGeometry()
    assert config.processing_settings(fs_hz=1000.0).window_n == 120000


def test_sensor_corners_reach_the_geometry() -> None:
    config = parse_config('[sensors]\na1 = "trailing-right"\na2 = "trailing-left"\na3 = "leading-right"\n', "t")
    assert config.bogie_geometry().corners == (Corner.TRAILING_RIGHT, Corner.TRAILING_LEFT, Corner.LEADING_RIGHT)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[processing]\nwindw_s = 30\n", "processing.windw_s: unknown field (did you mean 'window_s'?)"),
        ("[geometri]\n", "geometri: unknown field (did you mean 'geometry'?)"),
        ("[processing]\nfs_hz = -5\n", "processing.fs_hz: Input should be greater than 0 (got -5)"),
        ("[processing]\nhop_s = 7\n", "processing: window 120 s must be a whole number of hops (7 s): at 500 Hz that is 60000 samples and hops of 3500"),
        ("[processing]\nmax_lag_s = 120\n", "processing: max_lag_s (120 s, 60000 samples at 500 Hz) must be shorter than the window (60000 samples)"),
        ("[processing]\nfs_hz = 16\n", "processing: lowpass_hz (10 Hz) must lie between 0 and Nyquist (fs_hz / 2 = 8 Hz)"),
        ("[processing]\nhighpass_order = 'two'\n", "processing.highpass_order: expected a number, not a string (no quotes around a number) (got 'two')"),
        ('[sensors]\na1 = "up"\n', "sensors.a1: Input should be 'leading-left', 'leading-right', 'trailing-left' or 'trailing-right', got 'up'"),
        ('[sensors]\na2 = "leading-left"\n', "sensors: the three sensors must sit at three different corners"),
        ("[geometry]\nwheelbase_m = 18.0\n", "geometry.wheelbase_m: Input should be less than 5 (got 18.0)"),
    ],
)  # fmt: skip
def test_a_bad_field_is_named_with_its_path(text: str, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(text, "site.toml")
    assert str(info.value).startswith("site.toml: 1 problem(s):")
    assert expected in str(info.value)


def test_all_bad_fields_are_reported_together() -> None:
    with pytest.raises(ConfigError) as info:
        parse_config("[processing]\nfs_hz = 0\nwindow_s = 'long'\n[sensors]\na3 = 1\n", "site.toml")
    message = str(info.value)
    assert message.startswith("site.toml: 3 problem(s):")
    for path in ("processing.fs_hz", "processing.window_s", "sensors.a3"):
        assert f"\n  {path}: " in message


def test_invalid_toml_names_the_line() -> None:
    with pytest.raises(ConfigError, match=r"site.toml: invalid TOML: .*line 2"):
        parse_config("[processing]\nfs_hz = = 5\n", "site.toml")


def test_unreadable_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope.toml: cannot read the config file"):
        load_config(tmp_path / "nope.toml")


def test_resolved_config_written_as_toml_reads_back_identical() -> None:
    # hop_s 20 needs the thresholds method: the fused model was fitted on 10 s hops.
    text = '[processing]\nwindow_s = 120\nhop_s = 20\n[sensors]\na3 = "trailing-right"\n[decision]\nmethod = "thresholds"\n'
    config = parse_config(text, "t")
    text = tomlout.dumps(config.model_dump(mode="json"))
    assert parse_config(text, "round trip") == config


def test_toml_writer_escapes_strings_and_nests_tables() -> None:
    data = {"a": {"b": {"s": 'quote " and \\ and \n', "x": [1, 2.5, True]}}, "top": 1}
    assert tomllib.loads(tomlout.dumps(data)) == data


def test_digest_changes_with_any_value() -> None:
    a = BogiemonConfig()
    b = parse_config("[processing]\nlowpass_order = 6\n", "t")
    assert a.digest() == BogiemonConfig().digest() != b.digest()


def _leaf_keys(data: dict, prefix: str = "") -> set[str]:
    keys = set()
    for key, value in data.items():
        path = f"{prefix}{key}"
        keys |= _leaf_keys(value, path + ".") if isinstance(value, dict) else {path}
    return keys


def test_the_shipped_file_names_every_field_of_the_model() -> None:
    shipped = tomllib.loads(default_config_text())
    # TOML has no null: a field unset by default (decision.load_discriminant, which calibrate
    # writes) cannot be named with its value; the file describes it in a comment.
    assert _leaf_keys(shipped) == _leaf_keys(BogiemonConfig().model_dump(mode="json", exclude_none=True))
    assert "load_discriminant" in default_config_text()


def test_an_included_fragment_is_merged_over_the_file(tmp_path: Path) -> None:
    (tmp_path / "thresholds.toml").write_text("[decision.thresholds.full.i4_norm]\nwarning = 0.3\nalarm = 0.4\n")
    (tmp_path / "main.toml").write_text('include = ["thresholds.toml"]\n[processing]\nhop_s = 20.0\n[decision]\nmethod = "thresholds"\n')
    config = load_config(tmp_path / "main.toml")
    assert config.processing.hop_s == 20.0
    assert set(config.decision.thresholds[LoadState.FULL]) == {"i4_norm"}  # the named load state is replaced
    assert config.decision.thresholds[LoadState.FULL]["i4_norm"].alarm == 0.4
    assert config.decision.thresholds[LoadState.TARE] == BogiemonConfig().decision.thresholds[LoadState.TARE]


def test_a_missing_include_is_named(tmp_path: Path) -> None:
    (tmp_path / "main.toml").write_text('include = ["gone.toml"]\n')
    with pytest.raises(ConfigError, match=r"gone.toml: cannot read the config file"):
        load_config(tmp_path / "main.toml")


def test_warning_above_alarm_is_rejected() -> None:
    with pytest.raises(ConfigError, match=r"decision.thresholds.full.i2_norm: warning \(0.5\) must not exceed alarm"):
        parse_config("[decision.thresholds.full.i2_norm]\nwarning = 0.5\nalarm = 0.4\n", "t")
