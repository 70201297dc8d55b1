"""docs/img/architecture.svg is what scripts/make_architecture_svg.py draws from its tables:
an edit by hand, or a table changed without rerunning the script, fails here."""

from __future__ import annotations

import runpy
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_picture_is_the_scripts_output() -> None:
    script = runpy.run_path(str(ROOT / "scripts" / "make_architecture_svg.py"))
    drawn = (ROOT / "docs" / "img" / "architecture.svg").read_text(encoding="utf-8")
    assert drawn == script["svg"](), "rerun: .venv/bin/python scripts/make_architecture_svg.py"


def test_every_layer_of_the_contract_is_drawn() -> None:
    script = runpy.run_path(str(ROOT / "scripts" / "make_architecture_svg.py"))
    drawn = {box.name for row in script["LAYERS"] for box in row}
    packages = {p.name for p in (ROOT / "globeview").iterdir() if (p / "__init__.py").is_file()}
    assert packages <= drawn, f"not drawn: {sorted(packages - drawn)}"
