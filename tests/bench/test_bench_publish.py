"""The generated figures in the docs: blocks rewritten only between their markers, and every
block in docs/benchmarks.md and README.md belonging to a job `benchmarks/publish.py` runs."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

from globeview.bench.report import BlockError, blocks_in, machine_tag, replace_block

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "docs" / "benchmarks.md", ROOT / "README.md"]

DOC = """# Title

Prose before.
<!-- bench:render@cpu -->
| old | table |
<!-- /bench:render@cpu -->
Prose between.
<!-- bench:render@gpu -->
gpu figures
<!-- /bench:render@gpu -->
Prose after.
"""


def _publish():
    spec = importlib.util.spec_from_file_location("publish", ROOT / "benchmarks" / "publish.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["publish"] = module  # dataclasses look their module up while decorating
    spec.loader.exec_module(module)
    return module


def test_replace_block_rewrites_only_that_block() -> None:
    out = replace_block(DOC, "render@cpu", "| new | table |")
    assert "| new | table |" in out and "| old | table |" not in out
    assert "gpu figures" in out
    for prose in ("Prose before.", "Prose between.", "Prose after."):
        assert prose in out
    # Idempotent, and the markers are kept for the next run.
    assert replace_block(out, "render@cpu", "| new | table |") == out
    assert set(blocks_in(out)) == {"render@cpu", "render@gpu"}


def test_replaced_table_is_separated_by_blank_lines() -> None:
    out = replace_block(DOC, "render@cpu", "| a |\n|---|\n| 1 |")
    assert "<!-- bench:render@cpu -->\n\n| a |" in out
    assert "| 1 |\n\n<!-- /bench:render@cpu -->" in out


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("<!-- bench:a@cpu -->\nx\n", "never closed"),
        ("<!-- bench:a@cpu -->\n<!-- /bench:a@cpu -->\n" * 2, "twice"),
        (
            "<!-- bench:a@cpu -->\n<!-- bench:b@cpu -->\n<!-- /bench:b@cpu -->\n"
            "<!-- /bench:a@cpu -->\n",
            "inside",
        ),
    ],
)
def test_malformed_blocks_are_one_line_errors(text: str, needle: str) -> None:
    with pytest.raises(BlockError, match=needle) as info:
        blocks_in(text)
    assert "\n" not in str(info.value)


def test_unknown_block_is_refused() -> None:
    with pytest.raises(BlockError, match="no generated block 'nope@cpu'"):
        replace_block(DOC, "nope@cpu", "x")


@pytest.mark.parametrize(
    ("renderer", "tag"),
    [
        ("llvmpipe (LLVM 15.0.6, 256 bits)", "cpu"),
        ("softpipe", "cpu"),
        ("NVIDIA H100 80GB HBM3/PCIe/SSE2", "gpu"),
        ("AMD Radeon RX 7900 XTX (radeonsi, navi31, LLVM 15.0.7)", "gpu"),
    ],
)
def test_machine_tag(renderer: str, tag: str) -> None:
    assert machine_tag(renderer) == tag


@pytest.mark.parametrize("doc", DOCUMENTS, ids=lambda p: p.name)
def test_every_block_in_the_docs_belongs_to_a_job(doc: Path) -> None:
    jobs = _publish().JOBS
    blocks = blocks_in(doc.read_text())
    for name in blocks:
        job, _, tag = name.partition("@")
        assert tag in ("cpu", "gpu"), f"{doc.name}: block {name} has no @cpu/@gpu"
        assert job in jobs, f"{doc.name}: block {name} names no job in benchmarks/publish.py"
        assert doc in jobs[job].documents, f"{doc.name}: job {job} does not write this file"


@pytest.mark.parametrize("doc", DOCUMENTS, ids=lambda p: p.name)
def test_every_generated_block_names_machine_and_date(doc: Path) -> None:
    text = doc.read_text()
    for name, (start, end) in blocks_in(text).items():
        first = text[start:end].strip().splitlines()[0]
        assert re.search(r"\d{4}-\d{2}-\d{2}", first), f"{name}: no date in {first!r}"
        assert "load" in first and "cores" in first, f"{name}: no machine/load in {first!r}"


def test_every_job_has_its_block_on_this_machine_kind() -> None:
    """A CPU run of publish.py finds a place for every job's output in every document it
    names (a GPU run needs the @gpu blocks only for the jobs that have them)."""
    publish = _publish()
    texts = {doc: blocks_in(doc.read_text()) for doc in DOCUMENTS}
    for job in publish.JOBS.values():
        for doc in job.documents:
            assert f"{job.name}@cpu" in texts[doc], f"{doc.name} lacks block {job.name}@cpu"
