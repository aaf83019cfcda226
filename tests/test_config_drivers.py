"""Per-driver config models (the driver registries): configs written before them still load to the same
validated values, and a section's errors still name its field and what is allowed.

``data/config_dumps_before_registries.json`` holds, for every shipped config, the full ``model_dump`` and
the journal's snapshot (``exclude_defaults``) made by gonio before the drivers owned their models (one
flat axis model held every driver's fields then); a config shipped since (emulated-sample-stage-dynamixel)
was dumped when it was added."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gonio.campaign import config_hash, config_snapshot
from gonio.config import ConfigError, load_config, packaged_configs, parse_config
from gonio.registries import AXIS_DRIVERS, BUS_DRIVERS, DETECTOR_DRIVERS, LIGHT_DRIVERS

BEFORE = json.loads((Path(__file__).parent / "data" / "config_dumps_before_registries.json").read_text())


def test_every_shipped_config_is_dumped_before():
    assert set(BEFORE) == set(packaged_configs())


@pytest.mark.parametrize("name", sorted(BEFORE))
def test_shipped_configs_keep_their_snapshot_and_values(name):
    cfg = load_config(name)
    # The journal's snapshot (and so a journaled campaign's config hash) is unchanged.
    assert config_snapshot(cfg) == BEFORE[name]["snapshot"]
    # Every value the new models hold is the one the flat model held; what they no longer hold is
    # another driver's setting, left at its default.
    new, old = cfg.model_dump(mode="json"), BEFORE[name]["full"]
    dropped, added = _compare(new, old, name)
    for where, key in dropped:
        section = _section(cfg, where)
        assert key not in type(section).model_fields, (where, key)
    # A field added since (e.g. a detector's stream) holds its default: the snapshot above shows it.
    for where, key in added:
        section = _section(cfg, where)
        field = type(section).model_fields[key]
        assert getattr(section, key) == field.get_default(call_default_factory=True), (where, key)
    # A full dump by the older gonio still loads, to the same config.
    assert parse_config(old, f"{name} (older full dump)") == cfg


def _section(cfg, where: str):
    for table in ("axes", "buses"):
        if where.startswith(f"{table}."):
            return getattr(cfg, table)[where.split(".")[1]]
    return getattr(cfg, where)


def _compare(new: dict, old: dict, where: str) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """(dropped, added): the keys of ``old`` that ``new`` no longer has and those it has that ``old``
    had not, as (section, key); every value both hold is asserted equal."""
    dropped, added = [], []
    for key, value in old.items():
        if key not in new:
            dropped.append((where.split(":", 1)[-1], key))
        elif isinstance(value, dict) and isinstance(new[key], dict):
            d, a = _compare(new[key], value, f"{where}:{key}" if ":" not in where else f"{where}.{key}")
            dropped += d
            added += a
        else:
            assert new[key] == value, (where, key)
    added += [(where.split(":", 1)[-1], key) for key in set(new) - set(old)]
    return dropped, added


def test_a_campaign_config_hash_survives():
    """What resume compares: the snapshot's hash, as the journal of a campaign created before holds it."""
    import hashlib

    for name, dumps in BEFORE.items():
        text = json.dumps(dumps["snapshot"], sort_keys=True, separators=(",", ":"))
        assert config_hash(load_config(name)) == hashlib.sha256(text.encode()).hexdigest()


def _data(name="emulated-two-arm-dynamixel") -> dict:
    return load_config(name).model_dump(mode="json")


@pytest.mark.parametrize(("edit", "message"), [
    # another driver's setting: refused by name, with what the driver does take
    (lambda d: d["axes"]["light_tilt"].update(zero_steps=5),
     "axes.light_tilt: zero_steps: not a setting of a 'dynamixel' axis (allowed: bus, direction, family, "
     "gear_ratio, homing_offset_ticks, id, operating_mode, reference, reference_current_a, reference_deg, "
     "reference_direction, reference_velocity_deg_s, watchdog_s)"),
    # ... unless it holds that setting's default (a full dump of an older config)
    (lambda d: d["axes"]["light_tilt"].update(zero_steps=0, device_id=None, profile="generic"), None),
    # a setting no driver has
    (lambda d: d["axes"]["light_tilt"].update(wattage=5), "axes.light_tilt.wattage: unknown key"),
    # the driver itself
    (lambda d: d["axes"]["light_tilt"].update(driver="stepper"),
     "axes.light_tilt.driver: Input should be " + " or ".join(", ".join(
         f"'{n}'" for n in AXIS_DRIVERS.names()).rsplit(", ", 1))),
    (lambda d: d["buses"]["arm"].pop("driver"), "buses.arm.driver: Field required"),
    (lambda d: d["light"].update(driver="laser"), "light.driver: Input should be"),
    # a driver's own field, named without the union's tag
    (lambda d: d["axes"]["light_tilt"].update(id=300), "axes.light_tilt.id: Input should be less than or "
     "equal to 252"),
    (lambda d: d["buses"]["arm"].update(retries=9),
     "buses.arm.retries: Input should be less than or equal to 5"),
    (lambda d: d["buses"]["arm"].update(latency_timer_ms=float("nan")),
     "buses.arm.latency_timer_ms: Input should be a finite number"),
    (lambda d: d["buses"]["arm"].update(latency_timer_ms=0),
     "buses.arm.latency_timer_ms: Input should be greater"),
    (lambda d: d["detector"].update(wavelength_nm=50.0), "detector.wavelength_nm: Input should be greater"),
])
def test_section_errors_name_the_field(edit, message):
    data = _data()
    edit(data)
    if message is None:
        assert parse_config(data) == load_config("emulated-two-arm-dynamixel")
        return
    with pytest.raises(ConfigError) as err:
        parse_config(data, "x.toml")
    assert f"x.toml: {message}" in str(err.value)


def test_a_sim_section_refuses_a_real_drivers_settings():
    data = _data("sim")
    data["light"]["profile"] = "thorlabs-pm100"
    with pytest.raises(ConfigError, match="light: profile: not a setting of a 'sim' light"):
        parse_config(data)


def test_the_registries_hold_each_drivers_model():
    """Each driver's model takes exactly its registered name (a plugin's mismatch is refused at load)."""
    from gonio.device_config import driver_name

    for registry in (AXIS_DRIVERS, LIGHT_DRIVERS, DETECTOR_DRIVERS, BUS_DRIVERS):
        for entry in registry.entries():
            assert driver_name(entry.load()) == entry.name
