"""The frame budget a plugin author reads is the one the registry enforces (issue #29 item
10): `LodProvider`'s docstring said 250 ms while the registry's default, the docs' table and
the timeout messages say 1000 ms."""

from __future__ import annotations

import re
from pathlib import Path

from globeview.plugins.api import LodProvider
from globeview.plugins.isolation import Budget

DOCS = Path(__file__).resolve().parents[2] / "docs" / "plugins.md"


def _ms_figures(text: str) -> set[float]:
    """Every "N ms" figure in ``text`` (N with optional thousands separators)."""
    return {float(m.replace(",", "")) for m in re.findall(r"(\d[\d,]*)\s*ms\b", text)}


def test_lod_provider_docstring_states_the_enforced_budget() -> None:
    doc = " ".join((LodProvider.__doc__ or "").split())
    assert "plugins/budget_ms" in doc
    assert _ms_figures(doc) == {Budget().ms}


def test_docs_table_states_the_enforced_budget() -> None:
    row = next(
        line for line in DOCS.read_text().splitlines() if line.startswith("| `plugins/budget_ms`")
    )
    default = row.split("|")[2].strip()
    assert float(default) == Budget().ms
