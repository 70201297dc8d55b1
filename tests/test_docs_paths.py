"""The maps in the docs stay true: every file or folder that CONTRIBUTING.md ("where does X
live"), docs/architecture.md, docs/papers.md, docs/collapse.md, docs/benchmarks.md and the
README name in backticks exists, and the images and documents they link to exist. A module
moved or renamed without its docs fails here, with the doc line that still names the old
path."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Documents whose backticked paths must exist.
DOCS = [
    "CONTRIBUTING.md",
    "docs/architecture.md",
    "docs/papers.md",
    "docs/collapse.md",
    "docs/benchmarks.md",
    "docs/python_api.md",
    "README.md",
]

#: Top folders a backticked path may start with; layer folders are under globeview/.
TOP = ("globeview/", "tests/", "benchmarks/", "docs/", "scripts/", "examples/", "data/")
LAYERS = ("ui/", "plugins/", "render/", "model/", "lod/", "terrain/", "geodesy/", "cli/", "bench/")

#: Folders the docs name that scripts make on first use (git-ignored, so a fresh clone lacks
#: them): `benchmarks/cache/` holds the generated benchmark DEM and its store.
GENERATED = ("benchmarks/cache", "benchmarks/out")

TICKED = re.compile(r"`([A-Za-z0-9_./<>*-]+)`")
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def _candidates(token: str) -> list[Path] | None:
    """The paths a backticked token stands for, or None if it is not a path."""
    if token.startswith(TOP):
        rel = token
    elif token.startswith(LAYERS):
        rel = "globeview/" + token
    else:
        return None
    if "." not in rel.rsplit("/", 1)[-1] and not rel.endswith("/"):
        return None  # e.g. `lod/` is a folder (ends in /); `plugins/api` is not a file name
    return [ROOT / rel.rstrip("/")]


def _named_paths(doc: str) -> list[tuple[int, str]]:
    out = []
    for n, line in enumerate((ROOT / doc).read_text(encoding="utf-8").splitlines(), 1):
        out += [(n, m.group(1)) for m in TICKED.finditer(line)]
    return out


@pytest.mark.parametrize("doc", DOCS)
def test_backticked_paths_exist(doc: str) -> None:
    missing = []
    for n, token in _named_paths(doc):
        cands = _candidates(token)
        if cands is None or token.rstrip("/").startswith(GENERATED):
            continue
        for c in cands:
            pattern = str(c.relative_to(ROOT)).replace("<name>", "*")
            found = any(ROOT.glob(pattern)) if "*" in pattern else c.exists()
            if not found:
                missing.append(f"{doc}:{n}: {token}")
    assert not missing, "named in the docs but not in the tree:\n" + "\n".join(missing)


@pytest.mark.parametrize("doc", DOCS)
def test_relative_links_exist(doc: str) -> None:
    base = (ROOT / doc).parent
    text = (ROOT / doc).read_text(encoding="utf-8")
    missing = [
        target
        for target in LINK.findall(text)
        if "://" not in target and not (base / target).exists()
    ]
    assert not missing, f"{doc} links to missing files: {missing}"


def test_the_map_names_real_paths_at_all() -> None:
    """The check above is not vacuous: the map names dozens of paths."""
    named = [t for _, t in _named_paths("CONTRIBUTING.md") if _candidates(t)]
    assert len(named) > 40
