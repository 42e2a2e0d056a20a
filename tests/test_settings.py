import json

from puppet import settings
from puppet.settings import LiveSettings


def test_a_bundle_keeps_its_settings_in_its_folder_and_an_image_under_the_config_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    folder = tmp_path / "cat.puppet"
    folder.mkdir()
    assert settings.settings_path(folder, "cat") == folder / settings.SETTINGS_FILE
    image = tmp_path / "cat.png"
    other = tmp_path / "other" / "cat.png"
    assert settings.settings_path(image, "cat").parent == tmp_path / "config" / "puppet" / "live"
    assert settings.settings_path(image, "cat") != settings.settings_path(other, "cat")
    assert settings.settings_path(None, "character") != settings.settings_path(image, "character")


def test_saved_settings_come_back(tmp_path):
    path = tmp_path / "live.json"
    chosen = LiveSettings(sensitivity_db=6.0, gate_db=-40.0, blink_rate=20.0, expression="happy", push_to_talk=True)
    settings.save(path, chosen)
    assert settings.load(path) == chosen
    assert not list(tmp_path.glob(".*partial"))


def test_missing_damaged_or_odd_files_give_defaults_and_values_are_clamped(tmp_path, capsys):
    assert settings.load(tmp_path / "none.json") == LiveSettings()
    path = tmp_path / "live.json"
    path.write_text("{not json")
    assert settings.load(path) == LiveSettings()
    assert "ignoring" in capsys.readouterr().err
    path.write_text(json.dumps({"gate_db": "loud"}))
    assert settings.load(path) == LiveSettings()
    path.write_text(json.dumps({"sensitivity_db": 99, "blink_rate": -3, "future_setting": 1}))
    loaded = settings.load(path)
    assert loaded.sensitivity_db == 24.0 and loaded.blink_rate == 0.0


def test_an_unknown_expression_in_the_file_gives_defaults(tmp_path):
    path = tmp_path / "live.json"
    path.write_text(json.dumps({"expression": "smug", "blink_rate": 10}))
    assert settings.load(path) == LiveSettings()
