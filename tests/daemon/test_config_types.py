"""A config's values are taken as TOML wrote them (no true as 1, no "5" as 5, no 1 as true), and a
byte-order mark an editor put in front of it is read past, or named."""

from __future__ import annotations

from pathlib import Path

import pytest

from bogiemon.daemon.config import ConfigError, load_config, parse_config


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[processing]\nwindow_s = true\n", "processing.window_s: expected a number, not true or false (got True)"),
        ('[processing]\nwindow_s = "120"\n', "processing.window_s: expected a number, not a string (no quotes around a number) (got '120')"),
        ("[decision]\nconfirm_k = false\n", "decision.confirm_k: expected a number, not true or false (got False)"),
        ("[decision]\nconfirm_k = 3.0\n", "decision.confirm_k: expected a whole number (got 3.0)"),
        ('[mqtt]\nport = "1883"\n', "mqtt.port: expected a number, not a string (no quotes around a number) (got '1883')"),
        ("[recorder]\nenabled = 1\n", "recorder.enabled: expected true or false (got 1)"),
        ('[recorder]\nenabled = "yes"\n', "recorder.enabled: expected true or false (got 'yes')"),
        ("[decision.load_states.full]\ncenter = [1.0, true]\nscale = [1.0, 1.0]\nlimit = 2.0\nlowest_excitation_mps2 = 0.1\n",
         "decision.load_states.full.center: item 1: expected a number, not true or false"),
    ],
)  # fmt: skip
def test_a_value_of_the_wrong_type_is_refused_naming_its_key(text: str, expected: str) -> None:
    with pytest.raises(ConfigError) as raised:
        parse_config(text, "site.toml")
    assert expected in str(raised.value)


def test_a_whole_number_where_a_float_goes_is_taken() -> None:
    assert parse_config("[processing]\nwindow_s = 120\nhop_s = 10\n", "site.toml").processing.window_s == 120.0


def test_a_config_saved_with_a_utf8_byte_order_mark_is_read_as_without(tmp_path: Path) -> None:
    text = "[decision]\nconfirm_k = 2\n"
    (tmp_path / "plain.toml").write_text(text, encoding="utf-8")
    (tmp_path / "bom.toml").write_text(text, encoding="utf-8-sig")
    assert (tmp_path / "bom.toml").read_bytes().startswith(b"\xef\xbb\xbf")
    assert load_config(tmp_path / "bom.toml") == load_config(tmp_path / "plain.toml")


def test_an_include_saved_with_a_utf8_byte_order_mark_is_read_as_without(tmp_path: Path) -> None:
    (tmp_path / "calibration.toml").write_text("[decision]\nconfirm_k = 2\n", encoding="utf-8-sig")
    (tmp_path / "bogiemon.toml").write_text('include = ["calibration.toml"]\n', encoding="utf-8")
    assert load_config(tmp_path / "bogiemon.toml").decision.confirm_k == 2


@pytest.mark.parametrize(("encoding", "name"), [("utf-16", "UTF-16"), ("utf-32", "UTF-32")])
def test_a_config_saved_as_utf16_or_utf32_is_named_so(tmp_path: Path, encoding: str, name: str) -> None:
    path = tmp_path / "bogiemon.toml"
    path.write_text("[decision]\nconfirm_k = 2\n", encoding=encoding)  # with its byte-order mark
    with pytest.raises(ConfigError, match=f"a {name} text file \\(it begins with a {name} byte-order mark\\); save it as UTF-8"):
        load_config(path)
