"""Instrument profiles as data: the shipped ones load, a malformed one is one line naming the file and the
field, and through the CLI an unknown profile, a profile missing a command or a malformed profile file
is exit 2 with that line, nothing written and nothing moved (no device is opened)."""

from __future__ import annotations

import tomllib

import pytest

from gonio.cli import main
from gonio.config import CONFIG_DIR
from gonio.drivers.serial.profile import PROFILES, load_profile, parse_number

ROOT_PROFILES = CONFIG_DIR.parent / "drivers" / "serial" / "profiles"
PM100 = (ROOT_PROFILES / "thorlabs-pm100.toml").read_text()


def test_shipped_profiles_describe_the_dialects_their_manuals_give():
    pm, src, ack = (load_profile(n) for n in ("thorlabs-pm100", "scpi-current-source", "acknowledging"))
    assert set(PROFILES) == {p.stem for p in ROOT_PROFILES.glob("*.toml")}
    assert (pm.setters, pm.errors, pm.complete) == ("silent", "SYST:ERR?", "*OPC?")
    assert pm.kinds == ("power_meter",)
    assert (src.setters, src.errors, src.complete, src.kinds) == ("silent", "SYST:ERR?", None, ("light",))
    assert src.light.level_field == "current_a" and ack.light.level_field == "percent"
    assert (ack.setters, ack.ok_reply, ack.errors) == ("ok", "OK", None)
    assert len({p.sha256 for p in (pm, src, ack)}) == 3


def test_scpi_numbers():
    assert parse_number("1.234567E-03") == 1.234567e-3 and parse_number("+42") == 42.0
    for bad in ("", "NAN", "nan", "inf", "9.91E37", "-9.9E+37", "1.2.3", "0x10", "1e-3 W"):
        assert parse_number(bad) is None, bad


def _broken(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize("edit, field", [
    (lambda t: _broken(t, 'unit = "W"', 'configure2 = 1'), "power_meter.configure2: unknown"),
    (lambda t: _broken(t, 'measure = ["INIT", "FETC?"]', ''), "power_meter.measure: missing"),
    (lambda t: _broken(t, '"FETC?"]', '"FETC"]'), "power_meter.measure: ['INIT', 'FETC'] must be setters"),
    (lambda t: _broken(t, "{count:d}", "{averages}"), "power_meter.configure[1]: placeholder {averages}"),
    (lambda t: _broken(t, 'setters = "silent"', 'setters = "quiet"'), "setters: 'quiet' is not one of"),
    (lambda t: _broken(t, 'errors = "SYST:ERR?"\n', ''), "errors: missing"),
    (lambda t: _broken(t, 'identify = "*IDN?"\n', ''), "identify: missing"),
    (lambda t: _broken(t, "sample_s = 0.003", "sample_s = -1"), "power_meter.sample_s: -1 is outside"),
    (lambda t: _broken(t, 'complete = "*OPC?"', 'complete = "*OPC"'), "complete: '*OPC' must be a query"),
    (lambda t: t + "\n[light]\non = 'OUTP ON'\n", "light.off: missing"),
    (lambda t: t.replace("[power_meter]", "[power_meter"), "not valid TOML"),
])
def test_a_malformed_profile_is_one_line_naming_the_file_and_field(tmp_path, edit, field):
    path = tmp_path / "mine.toml"
    path.write_text(edit(PM100))
    with pytest.raises(ValueError) as err:
        load_profile(path)
    message = str(err.value)
    assert message.startswith(f"instrument profile {path}: ") and field in message and "\n" not in message


def test_an_unknown_profile_names_the_shipped_ones():
    with pytest.raises(ValueError, match="'pm100' is neither one of acknowledging, thorlabs-pm100, "
                                         "scpi-current-source, streaming-photodiode nor a file"):
        load_profile("pm100")


# -- through the CLI ------------------------------------------------------------------------------------
def _config(tmp_path, light: str = "", detector: str = "", current: str = "current_a = 1.5") -> str:
    """The emulated SCPI two-arm config, its [light] / [detector] profile lines replaced."""
    text = (CONFIG_DIR / "emulated-two-arm-scpi.toml").read_text().replace("current_a = 1.5", current)
    if light:
        text = text.replace('profile = "scpi-current-source"', light)
    if detector:
        text = text.replace('profile = "thorlabs-pm100"', detector)
    tomllib.loads(text)
    path = tmp_path / "gantry.toml"
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize("case, says", [
    ("unknown", "light: profile: instrument profile 'no-such-source' is neither one of"),
    ("missing-command", "detector: profile: instrument profile {profile}: power_meter.measure: missing"),
    ("malformed", "detector: profile: instrument profile {profile}: not valid TOML"),
    ("wrong-kind", "light: profile: instrument profile thorlabs-pm100: has no [light] section"),
    ("level-unit", "light: level_percent: profile scpi-current-source sets the lamp's level as a current"),
])
@pytest.mark.parametrize("command", ["run", "gantry", "emulate"])
def test_bad_profiles_through_the_cli_are_one_line_exit_2_and_nothing_written(tmp_path, capsys, case, says,
                                                                              command):
    profile = tmp_path / "pm.toml"
    if case == "missing-command":
        profile.write_text(_broken(PM100, 'measure = ["INIT", "FETC?"]', ""))
    else:
        profile.write_text(PM100.replace("[power_meter]", "[power_meter"))
    cfg = {
        "unknown": lambda: _config(tmp_path, light='profile = "no-such-source"'),
        "missing-command": lambda: _config(tmp_path, detector=f'profile = "{profile}"'),
        "malformed": lambda: _config(tmp_path, detector=f'profile = "{profile}"'),
        "wrong-kind": lambda: _config(tmp_path, light='profile = "thorlabs-pm100"'),
        "level-unit": lambda: _config(tmp_path, current="level_percent = 50"),
    }[case]()
    out = tmp_path / "out"
    argv = {"run": ["run", "--config", cfg, "--grid", "iso:step=30", "--out", str(out), "--sample", "s"],
            "gantry": ["gantry", "status", "--config", cfg],
            "emulate": ["emulate", "--config", cfg]}[command]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    assert str(tmp_path / "gantry.toml") in err and says.format(profile=profile) in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gantry.toml", "pm.toml"]  # no out/
