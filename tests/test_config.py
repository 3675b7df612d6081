from __future__ import annotations

from pathlib import Path

import pytest

from catenary.config import load_settings
from catenary.errors import UserError


def test_default_database_is_sqlite_file_in_data_dir(isolated_environment: Path) -> None:
    settings = load_settings()
    assert settings.database_url == f"sqlite:///{isolated_environment / 'catenary.sqlite'}"
    assert settings.data_dir == isolated_environment


def test_precedence_option_over_environment_over_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = tmp_path / "c.toml"
    config.write_text('[database]\nurl = "sqlite:///from-file.sqlite"\n')
    assert load_settings(config_path=config).database_url == "sqlite:///from-file.sqlite"
    monkeypatch.setenv("CATENARY_DATABASE_URL", "sqlite:///from-env.sqlite")
    assert load_settings(config_path=config).database_url == "sqlite:///from-env.sqlite"
    chosen = load_settings(config_path=config, database_url="sqlite:///opt.sqlite")
    assert chosen.database_url == "sqlite:///opt.sqlite"


def test_config_from_environment_variable_and_unknown_sections_kept(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = tmp_path / "c.toml"
    config.write_text(
        '[paths]\ndata_dir = "/srv/catenary"\n[plugins]\ndisabled = ["x"]\n'
        '[maintenance]\npolicy = "db-ril-997"\n'
    )
    monkeypatch.delenv("CATENARY_DATA_DIR")
    monkeypatch.setenv("CATENARY_CONFIG", str(config))
    settings = load_settings()
    assert settings.config_path == config
    assert settings.data_dir == Path("/srv/catenary")
    assert settings.disabled_plugins == ("x",)
    assert settings.sections["maintenance"] == {"policy": "db-ril-997"}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[database\nurl = 1", "invalid TOML"),
        ("[database]\nulr = 'x'\n", "unknown key database.ulr (did you mean url?)"),
        ("[database]\nurl = 3\n", "database.url must be a string"),
        ("[plugins]\ndisabled = 'x'\n", "plugins.disabled must be a list"),
        ("database = 1\n", "[database] must be a table"),
    ],
)
def test_bad_config_is_one_line_naming_file_and_key(
    tmp_path: Path, text: str, message: str
) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(text)
    with pytest.raises(UserError, match=r"bad\.toml") as caught:
        load_settings(config_path=config)
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)


def test_missing_config_file(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="config file not found"):
        load_settings(config_path=tmp_path / "nope.toml")


def test_connect_timeout_defaults_to_10_s_and_is_configurable(tmp_path: Path) -> None:
    config = tmp_path / "c.toml"
    config.write_text("")
    assert load_settings(config_path=config).connect_timeout_s == 10
    config.write_text("[database]\nconnect_timeout_s = 2.5\n")
    assert load_settings(config_path=config).connect_timeout_s == 2.5


@pytest.mark.parametrize("key", ["connect_timeout_s", "statement_timeout_s"])
@pytest.mark.parametrize("value", ["0", "-1", '"10"', "true", "inf"])
def test_bad_timeout_is_one_line(tmp_path: Path, key: str, value: str) -> None:
    config = tmp_path / "c.toml"
    config.write_text(f"[database]\n{key} = {value}\n")
    with pytest.raises(UserError, match=rf"c\.toml: database\.{key} must be a positive"):
        load_settings(config_path=config)


def test_statement_timeout_is_off_by_default_and_configurable(tmp_path: Path) -> None:
    config = tmp_path / "c.toml"
    config.write_text("")
    assert load_settings(config_path=config).statement_timeout_s is None
    config.write_text("[database]\nstatement_timeout_s = 30\n")
    assert load_settings(config_path=config).statement_timeout_s == 30.0
