"""Hostile and careless configs (issue 17): every bad file, include or value is one ConfigError,
what validates is what the service builds, and credential files are checked. Real files, real
FIFOs, real modes."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import structlog
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from bogiemon.daemon import tomlout
from bogiemon.daemon.config import (
    MAX_CONFIG_BYTES,
    BogiemonConfig,
    CanSourceConfig,
    ConfigError,
    ReplaySourceConfig,
    SerialSourceConfig,
    SimulatedSourceConfig,
    load_config,
    parse_config,
)
from bogiemon.daemon.delivery.connection import CredentialsError, read_secret, readable_by_others
from bogiemon.daemon.ringbuffer import BlockRing
from bogiemon.detection import IndicatorStream

BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]
THRESHOLDS = '[decision]\nmethod = "thresholds"\n'  # windows other than the fused model's 120 s / 10 s


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


def config_error(load: Any, *args: Any) -> str:
    with pytest.raises(ConfigError) as info:
        load(*args)
    return str(info.value)


# --- includes -----------------------------------------------------------------------------------


def test_include_5_is_a_config_error_naming_include(tmp_path: Path) -> None:
    main = write(tmp_path / "main.toml", "include = 5\n")
    assert config_error(load_config, main) == (
        f'{main}: include: expected a list of file names, e.g. include = ["calibration.toml"], got 5'
    )


def test_include_of_a_nul_name_is_a_config_error(tmp_path: Path) -> None:
    main = write(tmp_path / "main.toml", 'include = ["\\u0000"]\n')
    assert config_error(load_config, main) == f"{main}: include '\\x00': not a file name"


def test_include_of_dev_zero_is_refused_as_an_absolute_path(tmp_path: Path) -> None:
    main = write(tmp_path / "main.toml", 'include = ["/dev/zero"]\n')
    message = config_error(load_config, main)
    assert message.startswith(f"{main}: include '/dev/zero': an absolute path;")
    assert "allow_absolute_includes = true" in message


def test_include_of_dev_zero_allowed_outside_is_refused_as_not_a_regular_file(tmp_path: Path) -> None:
    main = write(tmp_path / "main.toml", 'allow_absolute_includes = true\ninclude = ["/dev/zero"]\n')
    assert config_error(load_config, main) == "/dev/zero: not a regular file; a config is a TOML text file"


def test_a_config_file_that_is_dev_zero_is_refused_without_reading_it() -> None:
    assert config_error(load_config, "/dev/zero") == "/dev/zero: not a regular file; a config is a TOML text file"


def test_a_fifo_as_include_is_refused_without_blocking(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "pipe.toml")  # nobody writes to it: opening it for reading would block
    main = write(tmp_path / "main.toml", 'include = ["pipe.toml"]\n')
    assert config_error(load_config, main) == f"{tmp_path / 'pipe.toml'}: not a regular file; a config is a TOML text file"


def test_a_folder_as_config_is_refused(tmp_path: Path) -> None:
    assert config_error(load_config, tmp_path) == f"{tmp_path}: a folder; a config is a TOML text file"


def test_a_config_file_over_one_mebibyte_is_refused(tmp_path: Path) -> None:
    big = write(tmp_path / "big.toml", "# padding\n" * (MAX_CONFIG_BYTES // 10 + 1))
    assert config_error(load_config, big) == f"{big}: larger than 1024 KiB; a config is a page of TOML: is this the right file?"


def test_a_truncated_utf8_byte_in_a_config_is_named(tmp_path: Path) -> None:
    path = tmp_path / "cut.toml"
    path.write_bytes("[wagon]\n# café".encode()[:-1])  # the file ends inside the two bytes of "é"
    assert config_error(load_config, path) == f"{path}: not a UTF-8 text file (byte 13); a config is TOML"


def test_deeply_nested_toml_is_a_config_error() -> None:
    message = config_error(parse_config, "a = " + "[" * 5000 + "]" * 5000 + "\n", "deep.toml")
    assert message == "deep.toml: invalid TOML: arrays or tables nested too deeply"


def test_include_leading_out_with_dotdot_is_refused(tmp_path: Path) -> None:
    write(tmp_path / "outside.toml", "[health]\nnoise_ratio = 3.0\n")
    main = write(tmp_path / "etc" / "main.toml", 'include = ["../outside.toml"]\n')
    message = config_error(load_config, main)
    assert message.startswith(f"{main}: include '../outside.toml': leads out of the config's folder {main.parent}")


def test_include_through_a_symlink_leading_out_is_refused(tmp_path: Path) -> None:
    write(tmp_path / "secret.toml", "[health]\nnoise_ratio = 3.0\n")
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "cal.toml").symlink_to(tmp_path / "secret.toml")
    main = write(tmp_path / "etc" / "main.toml", 'include = ["cal.toml"]\n')
    assert f"(to {tmp_path / 'secret.toml'}, '..' and symlinks resolved)" in config_error(load_config, main)


def test_include_in_a_subfolder_is_merged(tmp_path: Path) -> None:
    write(tmp_path / "site" / "cal.toml", "[health]\nnoise_ratio = 3.0\n")
    main = write(tmp_path / "main.toml", 'include = ["site/../site/cal.toml"]\n')
    assert load_config(main).health.noise_ratio == 3.0


def test_allow_absolute_includes_merges_a_file_from_elsewhere(tmp_path: Path) -> None:
    elsewhere = write(tmp_path / "shared" / "cal.toml", "[health]\nnoise_ratio = 3.0\n")
    main = write(tmp_path / "etc" / "main.toml", f'allow_absolute_includes = true\ninclude = ["{elsewhere}", "../shared/cal.toml"]\n')
    assert load_config(main).health.noise_ratio == 3.0


def test_an_included_file_cannot_allow_absolute_includes(tmp_path: Path) -> None:
    write(tmp_path / "cal.toml", "allow_absolute_includes = true\n")
    main = write(tmp_path / "main.toml", 'include = ["cal.toml"]\n')
    assert config_error(load_config, main) == (
        f"{tmp_path / 'cal.toml'}: an included file cannot set allow_absolute_includes: only the file that includes it"
    )


def test_allow_absolute_includes_must_be_a_boolean(tmp_path: Path) -> None:
    main = write(tmp_path / "main.toml", 'allow_absolute_includes = "yes"\n')
    assert config_error(load_config, main) == f"{main}: allow_absolute_includes: expected true or false, got 'yes'"


# --- values -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[processing]\nwindow_s = inf\n", "processing.window_s: Input should be a finite number (got inf)"),
        ("[processing]\nhop_s = nan\n", "processing.hop_s: Input should be a finite number (got nan)"),
        ("[decision.thresholds.full.i4_norm]\ncenter = -inf\nwarning = 0.1\nalarm = 0.2\n",
         "decision.thresholds.full.i4_norm.center: Input should be a finite number (got -inf)"),
        ("[processing]\nfs_hz = 1e300\n", "processing.fs_hz: Input should be less than or equal to 10000 (got 1e+300)"),
        ("[processing]\nwindow_s = 1e6\n", "processing.window_s: Input should be less than or equal to 3600 (got 1000000.0)"),
        # The CSV rates, as configured rates.
        ("[processing]\nfs_hz = 10\n", "processing: lowpass_hz (10 Hz) must lie between 0 and Nyquist (fs_hz / 2 = 5 Hz)"),
        ("[processing]\nfs_hz = 333.33\n",
         "processing: window 120 s must be a whole number of hops (10 s): at 333.33 Hz that is 40000 samples and hops of 3333"),
        ("[processing]\nfs_hz = 0.01\n", "processing: fs_hz 0.01 Hz is outside the sample rates the core handles, 1 to 100000 Hz"),
        ("[processing]\nhop_s = 5e-324\n", "processing: hop_s (4.94066e-324 s) is 0 sample(s) at 500 Hz: a hop needs at least 2 samples"),
        # Found by make fuzz (config): a hop of more samples than a float holds overflowed int().
        ("[processing]\nhop_s = 1.7976931348623157e+308\n", "processing: hop_s (1.79769e+308 s) is inf samples at 500 Hz, more than the"),
        ("[processing]\nwindow_s = 3600\nfs_hz = 1000\n" + THRESHOLDS,
         "processing: windows of 3600 s every 10 s with lags of 10 s at 1000 Hz hold 7200000 samples of cross-spectra, more than the 4194304 the core allows"),
        ("[processing]\nhighpass_hz = 1e-300\n", "processing: highpass_hz (1e-300 Hz) is below fs_hz x 1e-06 = 0.0005 Hz: the filter cannot be computed in double precision"),
        ("[pipeline]\nring_capacity_s = 1e300\n", "pipeline.ring_capacity_s: Input should be less than or equal to 600 (got 1e+300)"),
        ("[pipeline]\nring_capacity_s = 0.5\n", "pipeline.ring_capacity_s (0.5) must hold one block of source.max_block_s (1)"),
        ("[source]\nreconnect_backoff_max_s = 1e300\n", "source.reconnect_backoff_max_s: Input should be less than or equal to 3600"),
        ("[source]\nreceive_buffer_bytes = 1180591620717411303424\n",
         "source.receive_buffer_bytes: Input should be less than or equal to 2147483647"),
        ("[mqtt]\noutbox_max_messages = 99999999999999999999\n", "mqtt.outbox_max_messages: Input should be less than or equal to 10000000"),
        ('[source]\nchannel = "can\\u0000"\n', "source.channel: a NUL character (\\u0000) cannot be in a name or a path (got 'can\\x00')"),
        ('[state]\ndirectory = "/var/\\u0000"\n', "state.directory: a NUL character (\\u0000) cannot be in a name or a path"),
        ('[source]\nkind = "simulated"\ntrack = "moon"\n', "source: unknown track 'moon': use one of"),
        ('[source]\nkind = "simulated"\nfaults = ["broken"]\n', "source: fault 'broken': expected KIND:POSITION:SEVERITY@CORNER"),
        ('[source]\nkind = "simulated"\nduration_s = 10\nfault_at_s = 20\nfaults = ["type_a:rear_outer:0.0@leading-left"]\n',
         "source: fault_at_s (20) must lie before the end of the run, duration_s = 10"),
        ("[processing]\nhop_s = 20\n", "decision.method 'fused': its model (config/fused_model.toml) was fitted on windows of 120 s every 10 s"),
    ],
)  # fmt: skip
def test_an_absurd_value_is_one_config_error_naming_its_key(text: str, expected: str) -> None:
    message = config_error(parse_config, text, "site.toml")
    assert message.startswith("site.toml: 1 problem(s):\n  ")
    assert expected in message


@pytest.mark.parametrize(
    ("fs_hz", "expected"),
    [
        (10.0, "processing at a sample rate of 10 Hz: lowpass_hz (10 Hz) must lie between 0 and Nyquist (fs_hz / 2 = 5 Hz)"),
        (333.33, "processing at a sample rate of 333.33 Hz: window 120 s must be a whole number of hops (10 s): at 333.33 Hz"),
        (0.01, "processing at a sample rate of 0.01 Hz: fs_hz 0.01 Hz is outside the sample rates the core handles, 1 to 100000 Hz"),
        (1 / 4.9e-324, "processing at a sample rate of inf Hz: fs_hz must be a finite number, got inf"),
        (math.nan, "processing at a sample rate of nan Hz: fs_hz must be a finite number, got nan"),
        (-500.0, "processing at a sample rate of -500 Hz: fs_hz -500 Hz is outside the sample rates the core handles, 1 to 100000 Hz"),
    ],
)
def test_a_recordings_rate_the_processing_cannot_run_is_a_config_error(fs_hz: float, expected: str) -> None:
    assert config_error(BogiemonConfig().processing_settings, fs_hz).startswith(expected)


def test_check_config_rejects_a_config_run_cannot_start_in_one_error_without_traceback(tmp_path: Path) -> None:
    site = write(tmp_path / "site.toml", "[processing]\nhop_s = 20.0\n")  # valid fields; the fused model needs 10 s hops
    proc = subprocess.run([*BOGIEMON, "check-config", str(site)], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"bogiemon: error: {site}: 1 problem(s):\n  decision.method 'fused':")
    assert "Traceback" not in proc.stderr


def test_check_config_names_include_5_in_one_line(tmp_path: Path) -> None:
    site = write(tmp_path / "site.toml", "include = 5\n")
    proc = subprocess.run([*BOGIEMON, "check-config", str(site)], capture_output=True, text=True)
    assert (proc.returncode, proc.stdout) == (2, "")
    assert proc.stderr == f'bogiemon: error: {site}: include: expected a list of file names, e.g. include = ["calibration.toml"], got 5\n'


# --- one config truth: what validates, the service builds ---------------------------------------

_KIND_DEFAULTS: dict[str, dict[str, Any]] = {
    "can": CanSourceConfig().model_dump(mode="json"),
    "serial": SerialSourceConfig(kind="serial").model_dump(mode="json"),
    "replay": ReplaySourceConfig(kind="replay", path="run.csv").model_dump(mode="json"),
    "simulated": SimulatedSourceConfig(kind="simulated").model_dump(mode="json"),
}


def _leaves(data: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for key, value in data.items():
        out += _leaves(value, (*prefix, key)) if isinstance(value, dict) and value else [(*prefix, key)]
    return out


def _base(kind: str) -> dict[str, Any]:
    data = BogiemonConfig().model_dump(mode="json")
    data["source"] = dict(_KIND_DEFAULTS[kind])
    return data


HOSTILE = [math.inf, -math.inf, math.nan, 1e300, -1e300, 0, 0.0, -1, 2**70, -(2**70), 2**63 - 1, 5e-324, 1e-300,
           1e-9, 0.5, 333.33, "", "x", "\u0000", "/dev/zero", True, False, [], [math.nan], {}]  # fmt: skip


@st.composite
def mutated_configs(draw: st.DrawFn) -> str:
    """The full config of one source kind, a few known fields set to hostile or nearby values."""
    kind = draw(st.sampled_from(sorted(_KIND_DEFAULTS)))
    data = _base(kind)
    # Half of them on the thresholds method: the fused one takes only its model's windows.
    data["decision"]["method"] = draw(st.sampled_from(["fused", "thresholds"]))
    paths = _leaves(data)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(paths))
        table = data
        for key in path[:-1]:
            table = table[key]
        old = table[path[-1]]
        nearby: st.SearchStrategy[Any] = st.nothing()
        if isinstance(old, bool):
            nearby = st.just(not old)
        elif isinstance(old, int | float):

            def scaled(f: float, v: float = old) -> float:
                return type(v)(v * f)

            nearby = st.sampled_from([0.001, 0.1, 0.5, 1.5, 2.0, 3.0, 7.0, 1000.0, 1e6, -1.0]).map(scaled)
        table[path[-1]] = draw(st.one_of(st.sampled_from(HOSTILE), nearby, st.floats(), st.integers(), st.text(max_size=4)))
    return tomlout.dumps(data)


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_configs())
def test_a_mutated_config_is_a_config_error_or_builds_everything_run_builds(text: str) -> None:
    try:
        config = parse_config(text, "mutated.toml")
    except ConfigError:
        event("rejected")
        return
    event("valid")
    config.monitor_settings()
    IndicatorStream(config.processing_settings(), config.bogie_geometry())
    BlockRing(max(1, int(config.pipeline.ring_capacity_s * config.processing.fs_hz)))  # as the service sizes it
    assert config.source.max_block_s <= config.pipeline.ring_capacity_s


# --- credentials --------------------------------------------------------------------------------


def _mqtt(tmp_path: Path, extra: str) -> str:
    (tmp_path / "user").write_text("wagon\n")
    (tmp_path / "password").write_text("s3cret\n")
    os.chmod(tmp_path / "user", 0o600)
    os.chmod(tmp_path / "password", 0o600)
    return f'[mqtt]\nusername_file = "{tmp_path / "user"}"\npassword_file = "{tmp_path / "password"}"\n{extra}'


def test_a_password_without_tls_is_refused(tmp_path: Path) -> None:
    message = config_error(parse_config, _mqtt(tmp_path, "tls = false\n"), "site.toml")
    assert message == (
        "site.toml: 1 problem(s):\n  mqtt: password_file with tls = false would send the password in clear: "
        "set tls = true (and the broker's TLS port), or allow_plaintext = true on a bench"
    )


def test_allow_plaintext_accepts_a_password_without_tls_with_a_warning(tmp_path: Path) -> None:
    config = parse_config(_mqtt(tmp_path, "tls = false\nallow_plaintext = true\n"), "site.toml")
    assert config.credential_warnings() == ["mqtt: allow_plaintext = true: the password crosses the network in clear (tls = false)"]


def test_a_password_file_others_can_read_is_warned_about(tmp_path: Path) -> None:
    config = parse_config(_mqtt(tmp_path, ""), "site.toml")
    assert config.credential_warnings() == []
    os.chmod(tmp_path / "password", 0o644)
    assert config.credential_warnings() == [
        f"mqtt.password_file: {tmp_path / 'password'} is readable by its group and others (mode 0644): "
        f"chmod 600 {tmp_path / 'password'}, or hand it over with systemd's LoadCredential="
    ]


def test_a_key_file_its_group_can_read_is_warned_about(tmp_path: Path) -> None:
    key = tmp_path / "client.key"
    key.write_text("-----BEGIN PRIVATE KEY-----\n")
    os.chmod(key, 0o640)
    assert readable_by_others(str(key)) == f"{key} is readable by its group (mode 0640): chmod 600 {key}, or hand it over with systemd's LoadCredential="


def test_a_missing_credential_file_gives_no_warning(tmp_path: Path) -> None:
    assert readable_by_others(str(tmp_path / "absent")) is None


def test_load_config_logs_a_warning_for_a_readable_password_file(tmp_path: Path) -> None:
    site = write(tmp_path / "site.toml", _mqtt(tmp_path, ""))
    os.chmod(tmp_path / "password", 0o604)
    with structlog.testing.capture_logs() as logs:
        load_config(site)
    assert [(entry["log_level"], entry["event"]) for entry in logs] == [
        ("warning", f"mqtt.password_file: {tmp_path / 'password'} is readable by others (mode 0604): "
                    f"chmod 600 {tmp_path / 'password'}, or hand it over with systemd's LoadCredential=")
    ]  # fmt: skip


def test_check_config_prints_the_credential_warning_as_a_comment(tmp_path: Path) -> None:
    site = write(tmp_path / "site.toml", _mqtt(tmp_path, ""))
    os.chmod(tmp_path / "password", 0o644)
    proc = subprocess.run([*BOGIEMON, "check-config", str(site)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith(f"# {site}: valid (digest ")
    assert lines[1] == f"# warning: mqtt.password_file: {tmp_path / 'password'} is readable by its group and others (mode 0644): " \
        f"chmod 600 {tmp_path / 'password'}, or hand it over with systemd's LoadCredential="
    assert proc.stderr == ""


def test_read_secret_refuses_dev_zero_without_reading_it() -> None:
    with pytest.raises(CredentialsError, match=r"^MQTT password file /dev/zero: not a regular file$"):
        read_secret("/dev/zero", "MQTT password file")


def test_read_secret_refuses_a_fifo_without_blocking(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "password")
    with pytest.raises(CredentialsError, match=r"password: not a regular file$"):
        read_secret(str(tmp_path / "password"), "MQTT password file")


def test_read_secret_refuses_a_first_line_longer_than_4096_bytes(tmp_path: Path) -> None:
    (tmp_path / "password").write_text("x" * 5000)
    with pytest.raises(CredentialsError, match=r"its first line is longer than 4096 bytes: not a credentials file$"):
        read_secret(str(tmp_path / "password"), "MQTT password file")


def test_read_secret_returns_the_first_line_without_its_line_end(tmp_path: Path) -> None:
    (tmp_path / "password").write_text("s3cret\r\nsecond line\n" + "y" * 10000)
    assert read_secret(str(tmp_path / "password"), "MQTT password file") == "s3cret"
