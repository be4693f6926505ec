"""The command line is generated from ``Settings``: one field is one flag, with its help."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Annotated

import pytest
from canal_service.core.cli import build_parser, settings_from_args, settings_options
from canal_service.core.config import Flag, Settings
from pydantic import Field


def _help(parser_help: str) -> str:
    return " ".join(parser_help.split())  # argparse wraps lines


def test_every_setting_is_a_flag_with_its_help_and_variable() -> None:
    text = _help(build_parser().format_help())
    options = {o.field: o for o in settings_options()}
    assert set(options) == set(Settings.model_fields)
    for name, info in Settings.model_fields.items():
        assert info.description, f"Settings.{name} has no description (it is its --help)"
        option = options[name]
        assert option.flag in text and f"CANAL_{name.upper()}" in text
        assert " ".join(info.description.rstrip(".").split()) in text


def test_documented_spellings_parse(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("CANAL_PORT", raising=False)
    s = settings_from_args([
        "--host", "0.0.0.0", "--port", "8123", "--data-dir", str(tmp_path),
        "--database-url", "postgresql+psycopg://u@h/db", "--recordings-dir", str(tmp_path / "r"),
        "--no-recordings", "--token", "t0k", "--cors-origin", "http://a", "--cors-origin",
        "http://b", "--max-body-bytes", "1000", "--log-level", "warning", "--no-zenoh",
        "--zenoh-listen", "tcp/127.0.0.1:1", "--zenoh-listen", "tcp/127.0.0.1:2",
        "--zenoh-connect", "tcp/10.0.0.1:7447", "--zenoh-config", "z.json5",
        "--zenoh-prefix", "lab", "--zenoh-processes", "0", "--upload-max-seconds", "2.5",
        "--zenoh-idle-s", "5", "--upload-workers", "3"])
    assert (s.host, s.port, s.data_dir) == ("0.0.0.0", 8123, tmp_path)
    assert s.database_url == "postgresql+psycopg://u@h/db"
    assert s.recordings_dir == tmp_path / "r" and not s.recordings_enabled
    assert s.token is not None and s.token.get_secret_value() == "t0k"
    assert s.cors_origins == ["http://a", "http://b"] and s.max_body_bytes == 1000
    assert s.log_level == "warning" and not s.zenoh_enabled
    assert s.zenoh_listen == ["tcp/127.0.0.1:1", "tcp/127.0.0.1:2"]
    assert s.zenoh_connect == ["tcp/10.0.0.1:7447"] and s.zenoh_config == Path("z.json5")
    assert s.zenoh_prefix == "lab" and s.zenoh_processes == 0
    assert s.upload_max_seconds == 2.5 and s.zenoh_idle_s == 5.0
    assert s.upload_workers == 3


def test_flags_override_the_environment_which_overrides_defaults(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CANAL_PORT", "9001")
    monkeypatch.setenv("CANAL_ZENOH_LISTEN", '["tcp/127.0.0.1:7600"]')
    monkeypatch.setenv("CANAL_RECORDINGS_ENABLED", "false")
    s = settings_from_args([])
    assert s.port == 9001 and s.zenoh_listen == ["tcp/127.0.0.1:7600"]
    assert not s.recordings_enabled and s.zenoh_enabled  # untouched switch keeps its default
    s = settings_from_args(["--port", "9002", "--zenoh-listen", "tcp/127.0.0.1:7601"])
    assert s.port == 9002 and s.zenoh_listen == ["tcp/127.0.0.1:7601"]


@pytest.mark.parametrize(("argv", "named"), [
    (["--port", "70000"], "--port"),
    (["--port", "eighty"], "--port"),
    (["--zenoh-processes", "-1"], "--zenoh-processes"),
    (["--upload-max-seconds", "0"], "--upload-max-seconds"),
    (["--upload-workers", "0"], "--upload-workers"),
    (["--token", "tokén"], "--token"),
    (["--log-level", "loud"], "--log-level"),
    (["--log-level", "trace"], "--log-level"),
    (["--token", "s3cret "], "--token"),
    # a wildcard prefix: the bridge would subscribe to, and answer on, every key it matches
    (["--zenoh-prefix", "canal/*"], "--zenoh-prefix"),
    (["--zenoh-prefix", "a//b"], "--zenoh-prefix"),
])
def test_a_bad_value_is_a_usage_error_naming_the_flag(
        argv: list[str], named: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        settings_from_args(argv)
    assert exit_info.value.code == 2
    assert f"error: {named} (or CANAL_" in capsys.readouterr().err


def test_a_log_level_is_one_of_uvicorns_named_in_any_case(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    # 'loud' was a KeyError traceback from uvicorn's logging setup, after the port was bound.
    monkeypatch.setenv("CANAL_LOG_LEVEL", "loud")
    with pytest.raises(SystemExit) as exit_info:
        settings_from_args([])
    assert exit_info.value.code == 2
    assert "error: --log-level (or CANAL_LOG_LEVEL): Input should be 'debug', 'info', " \
           "'warning', 'error' or 'critical', got 'loud'" in " ".join(capsys.readouterr().err.split())
    assert settings_from_args(["--log-level", "WARNING"]).log_level == "warning"


def test_a_token_no_header_can_carry_is_refused_without_echoing_it(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    # It started, and no client could send it: 'tokén' cannot be encoded in a header, and
    # 's3cret ' arrives as 's3cret' (HTTP strips the space), so every request was a 401.
    monkeypatch.setenv("CANAL_TOKEN", "s3cret ")
    with pytest.raises(SystemExit) as exit_info:
        settings_from_args([])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert "--token (or CANAL_TOKEN): expected visible ASCII characters without spaces or " \
           "control characters, got a space at character 7 of 7" in " ".join(err.split())
    assert "s3cret" not in err  # a secret is not printed back
    monkeypatch.setenv("CANAL_TOKEN", "")
    assert settings_from_args([]).token is None  # empty: no token


def test_a_new_setting_is_one_field() -> None:
    class Extended(Settings):
        widget_count: int = Field(3, ge=1, description="Widgets to keep.")
        zenoh_widget: Annotated[list[str], Flag("--zenoh-gadget", metavar="G")] = Field(
            default_factory=list, description="Gadgets.")
        fancy_enabled: Annotated[bool, Flag("--no-fancy")] = Field(
            True, description="Be fancy.")

    text = _help(build_parser(Extended).format_help())
    assert "--widget-count WIDGET_COUNT Widgets to keep (CANAL_WIDGET_COUNT, default 3)" in text
    assert "--zenoh-gadget G Gadgets (CANAL_ZENOH_WIDGET as a JSON list" in text
    assert "--zenoh-gadget G Gadgets" in text.split("live bridge (Zenoh):")[1]
    assert "--no-fancy Be fancy (this flag turns it off: CANAL_FANCY_ENABLED=false)" in text
    s = settings_from_args(["--widget-count", "7", "--zenoh-gadget", "a", "--zenoh-gadget",
                            "b", "--no-fancy"], Extended)
    assert isinstance(s, Extended)
    assert (s.widget_count, s.zenoh_widget, s.fancy_enabled) == (7, ["a", "b"], False)


def test_python_m_canal_service_help_lists_every_flag() -> None:
    p = subprocess.run([sys.executable, "-m", "canal_service", "--help"], capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 0
    for option in settings_options():
        assert option.flag in p.stdout


@pytest.mark.parametrize(("value", "items"), [
    ('["tcp/127.0.0.1:7600"]', ["tcp/127.0.0.1:7600"]),
    ("tcp/127.0.0.1:7600", ["tcp/127.0.0.1:7600"]),  # one endpoint, as its flag takes it
    ("tcp/127.0.0.1:7600, tcp/127.0.0.1:7601", ["tcp/127.0.0.1:7600", "tcp/127.0.0.1:7601"]),
    ("", []),
])
def test_a_list_variable_takes_json_or_plain_items(
        monkeypatch: pytest.MonkeyPatch, value: str, items: list[str]) -> None:
    # A plain endpoint in CANAL_ZENOH_LISTEN stopped the service with a traceback from the
    # settings library's JSON decoder.
    for name in ("CANAL_ZENOH_LISTEN", "CANAL_ZENOH_CONNECT", "CANAL_CORS_ORIGINS"):
        monkeypatch.setenv(name, value)
    s = settings_from_args([])
    assert s.zenoh_listen == s.zenoh_connect == s.cors_origins == items


@pytest.mark.parametrize("value", ['["tcp/127.0.0.1:7600"', "[1, 2]", '[""]'])
def test_a_list_variable_that_is_no_list_is_a_usage_error(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], value: str) -> None:
    monkeypatch.setenv("CANAL_ZENOH_LISTEN", value)
    with pytest.raises(SystemExit) as exit_info:
        settings_from_args([])
    assert exit_info.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "error: --zenoh-listen (or CANAL_ZENOH_LISTEN)" in err and "Traceback" not in err, err
