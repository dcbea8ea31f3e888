"""The option tables of the topic pages (docs/generate.md, docs/train.md, docs/mair.md) are generated from the
configs' field metadata by ``python -m ebr_mitsuba.docgen`` (issue 11): none is hand-written, and
the pages in the repository are current."""

from __future__ import annotations

from pathlib import Path

import pytest

from ebr_mitsuba.docgen import TOPIC_PAGES, config_sections, fill_tables

DOCS = Path(__file__).resolve().parents[1] / "docs"


@pytest.mark.parametrize("name", TOPIC_PAGES)
def test_topic_page_tables_are_generated_and_current(name):
    text = (DOCS / name).read_text()
    assert text.count("<!-- options: ") >= 4, name
    assert fill_tables(text, name) == text, (
        f"docs/{name} is stale: run python -m ebr_mitsuba.docgen --out docs"
    )
    assert "| key | type | default | meaning |" not in text, f"docs/{name}: a hand-written default table"


def test_fill_tables_writes_the_section_table_and_names_an_unknown_one():
    title = next(title for title, prefix, *_ in config_sections() if prefix == "dataset.")
    page = f"intro\n<!-- options: {title} -->\nstale\n<!-- /options -->\noutro\n"
    filled = fill_tables(page)
    assert filled.startswith("intro\n") and filled.endswith("<!-- /options -->\noutro\n")
    assert "stale" not in filled and "| `count` | `int` | `100`" in filled
    assert fill_tables(filled) == filled
    with pytest.raises(ValueError, match=r"^x\.md: <!-- options: nope -->: no such section"):
        fill_tables("<!-- options: nope -->\n<!-- /options -->", "x.md")
