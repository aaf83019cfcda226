"""`gonio materials`: the catalogue of models, keys, ranges and defaults is read from the parsers
themselves, so it says what load() accepts: every key of every model is listed, each listed default is
what load() fills in, and a value just beyond each listed range is refused naming the key."""

from __future__ import annotations

import re

import pytest
from cli_helpers import one_clear_line

from gonio.cli import main
from gonio.sim.materials import MODELS, load
from gonio.sim.materials.catalog import catalog

ENTRIES = {e.model: e for e in catalog()}


def test_every_model_and_every_key_it_knows_is_listed():
    assert list(ENTRIES) == list(MODELS)
    for name, cls in MODELS.items():
        e = ENTRIES[name]
        assert [k.key for k in e.keys] == list(getattr(cls, "KEYS", ())), name
        assert e.examples or e.usage, name
        for example in e.examples:
            assert load(example).spec.startswith(name + ":")


def _without(spec: str, key: str) -> str:
    name, _, rest = spec.partition(":")
    return f"{name}:{','.join(i for i in rest.split(',') if i.split('=')[0] != key)}"


def _with(spec: str, key: str, value: str) -> str:
    rest = _without(spec, key)
    return f"{rest}{',' if not rest.endswith(':') else ''}{key}={value}"


@pytest.mark.parametrize("name", [n for n in MODELS if ENTRIES[n].examples])
def test_listed_defaults_and_ranges_are_what_load_does(name):
    e = ENTRIES[name]
    checked = 0
    for k in e.keys:
        example = next(x for x in e.examples if f"{k.key}=" in load(x).spec or f"{k.key}=" in x)
        if k.default not in ("none", "depends on the other keys"):
            without = _without(example, k.key)
            assert f"{k.key}={k.default}" in load(without).spec.split(":", 1)[1].split(","), (k, without)
        for text in k.ranges:
            beyond = None
            if m := re.match(r"in [\[(]([-\d.]+), ([-\d.]+)[\])]", text):
                beyond = float(m.group(2)) + 0.5
            elif m := re.match(r"> ([-\d.]+)", text):
                beyond = float(m.group(1))
            elif m := re.match(r">= ([-\d.]+)", text):
                beyond = float(m.group(1)) - 0.5
            elif m := re.match(r"one of (.*)", text):
                with pytest.raises(ValueError, match=k.key):
                    load(_with(example, k.key, "nonsense"))
                checked += 1
                continue
            assert beyond is not None, (k, text)
            ctx = re.search(r"\(with (.*)\)", text)
            spec = example
            if ctx:   # the words that chose this range
                for item in ctx.group(1).split(", "):
                    spec = _with(spec, *item.split("="))
            with pytest.raises(ValueError, match=f"'{k.key}' must be"):
                load(_with(spec, k.key, repr(beyond)))
            checked += 1
    assert checked >= len(e.keys)


def test_gonio_materials_lists_them_and_one_by_name(capsys):
    assert main(["materials"]) == 0
    text = capsys.readouterr().out
    for name in MODELS:
        assert f"\n{name}: " in text
    assert "rho_d + rho_s <= 1 in each channel" in text and "in (0, 1.5708) rad (with d=blinn)" in " ".join(
        text.split())
    assert main(["materials", "ggx"]) == 0
    one = capsys.readouterr().out
    assert "\nggx: " in one and "\nward: " not in one and "smith" in one
    assert main(["materials", "velvet"]) == 2
    one_clear_line(capsys, "'velvet' is not a material model", "lambert")
