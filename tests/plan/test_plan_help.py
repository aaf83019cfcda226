"""`gonio plan --help` lists every grid kind and option from the registries the parser itself uses
(`isotropy` was accepted but written nowhere)."""

from __future__ import annotations

import pytest

from gonio.cli import main
from gonio.plan import parse_grid
from gonio.registries import GRID_KINDS, GRID_OPTIONS, ORDERS

VALUES = {"step": "30", "stride": "30", "theta_max": "60", "reciprocity": "false", "mirror": "true",
          "order": "serpentine"}
#: What each kind of size option takes (a grid names exactly one of them).
SIZES = {"step": "step=30", "stride": "stride=30", "budget": "poses=30"}
SIZE_OPTIONS = ("step", "stride", "poses", "budget_s")


def test_plan_help_lists_every_kind_and_option(capsys):
    with pytest.raises(SystemExit):
        main(["plan", "--help"])
    text = capsys.readouterr().out
    for kind in GRID_KINDS.entries():
        assert f"\n  {kind.name}:" in text and ", ".join(kind.extra["options"]) in " ".join(text.split())
    for option in GRID_OPTIONS:
        assert f"\n  {option}: " in text
    for order in ORDERS:
        assert f"\n  {order} " in text
    assert "isotropy" in text


@pytest.mark.parametrize("kind", list(GRID_KINDS))
def test_the_parser_takes_exactly_the_options_the_registry_lists(kind):
    options = GRID_KINDS[kind].extra["options"]
    size = SIZES[GRID_KINDS[kind].extra["size"]]
    for option in GRID_OPTIONS:
        value = VALUES.get(option, "true" if kind != "full" else "false")
        grid = f"{kind}:{option}=30" if option in SIZE_OPTIONS else f"{kind}:{size},{option}={value}"
        if option in options:
            parse_grid(grid)
        else:
            with pytest.raises(ValueError, match=f"unknown option '{option}'"):
                parse_grid(grid)
