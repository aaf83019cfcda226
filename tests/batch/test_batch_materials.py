"""MATERIALS of a batch: spans, alternatives, files, and what is refused."""

from __future__ import annotations

import pytest

from gonio.batch.materials import MAX_SPAN, expand, read_materials


def test_a_span_gives_n_values_from_a_to_b_both_included_and_alternatives_each_the_first_option_slowest():
    got = expand("ggx:alpha=0.02..0.5x5,metal=gold|copper")
    assert got == [f"ggx:alpha={a},metal={m}" for a in ("0.02", "0.14", "0.26", "0.38", "0.5")
                   for m in ("gold", "copper")]
    assert len(read_materials("ggx:alpha=0.02..0.5x20,metal=gold|copper")) == 40


def test_a_path_or_a_model_without_options_is_never_a_span():
    assert expand("merl:../data/a|b..c.binary") == ["merl:../data/a|b..c.binary"]
    assert expand("lambert") == ["lambert"]


def test_a_file_one_line_each_with_comments_blank_lines_and_spans(tmp_path):
    f = tmp_path / "m.txt"
    f.write_text("# metals\nggx:alpha=0.1|0.2,metal=gold\n\n  lambert:albedo=0.5  \n")
    got = read_materials(str(f))
    assert len(got) == 3 and got[2] == "lambert:albedo=0.5"
    assert got[0].startswith("ggx:alpha=0.1,") and got[1].startswith("ggx:alpha=0.2,")


@pytest.mark.parametrize("text, message", [
    ("ggx:alpha=0.1..0.3x1,metal=gold", "N from 2 to"),
    (f"ggx:alpha=0.1..0.3x{MAX_SPAN + 1},metal=gold", "N from 2 to"),
    ("ggx:alpha=0.1|,metal=gold", "empty alternative"),
    ("ggx:alpha=-1..0.3x3,metal=gold", "alpha"),
    ("nosuchmodel:x=1", "unknown material model"),
    ("lambert:albedo=0.5|0.50", "lambert:albedo=0.50 is already in the batch as lambert:albedo=0.5"),
    ("lambert:albedo=0.1..0.9x10000,x=1|2|3|4|5|6|7|8|9|10|11", "at most"),     # 110,000 materials
])
def test_bad_materials_are_refused_in_one_line_naming_where(text, message):
    with pytest.raises(ValueError, match=message) as e:
        read_materials(text)
    assert str(e.value).startswith("MATERIALS") and "\n" not in str(e.value)


def test_a_bad_line_of_a_file_is_named_by_file_and_line(tmp_path):
    f = tmp_path / "m.txt"
    f.write_text("lambert:albedo=0.5\n# fine\nlambert:albedo=7\n")
    with pytest.raises(ValueError, match=rf"^{f}:3: .*albedo"):
        read_materials(str(f))
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing\n\n")
    with pytest.raises(ValueError, match="holds no MATERIAL line"):
        read_materials(str(empty))
    with pytest.raises(ValueError, match="is not a file"):
        read_materials(str(tmp_path))
