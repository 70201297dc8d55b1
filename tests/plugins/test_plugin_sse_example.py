"""docs/plugins.md's provider examples, run as they are written (issue #29 item 11): the code
blocks marked ``<!-- tested: tests/plugins/test_plugin_sse_example.py ... -->`` are installed
as a real plugin distribution and run on the embedded terrain.

- "Reproducing chunked-sse": a `PolicyProvider` of `ScreenSpaceErrorPolicy` with
  chunked-sse's settings selects the same `RenderSet` as chunked-sse itself (keys, index
  variants, errors) at several views;
- "Counting triangles": the triangle-budget provider keeps its budget, counted as the
  frame stats count (`triangle_count`), and leaves a view already within it as chunked-sse
  draws it.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from globeview.app.testing import PluginSite

DOCS = Path(__file__).resolve().parents[2] / "docs" / "plugins.md"
MARK = "<!-- tested: tests/plugins/test_plugin_sse_example.py"

MANIFEST = """
    name = "gvt-docs-lod"
    version = "0.1.0"
    description = "the docs' LOD provider examples"
    kinds = ["lod"]
    api_version = "1.3"

    [[contributions]]
    name = "my-sse"
    kind = "lod"
    target = "gvt_docs_lod.impl:MySseProvider"

    [[contributions]]
    name = "tri-budget"
    kind = "lod"
    target = "gvt_docs_lod.impl:TriangleBudgetProvider"

    [[contributions]]
    name = "tri-budget-small"
    kind = "lod"
    target = "gvt_docs_lod.impl:SmallBudget"
    """

#: (lon, lat, height m, heading, pitch) views: the globe, the White Mountains from 300 and
#: 30 km (the second oblique), Crater Lake.
VIEWS = [
    (0.0, 20.0, 2.0e7, 0.0, -90.0),
    (-71.3, 44.27, 3.0e5, 0.0, -90.0),
    (-71.3, 44.0, 3.0e4, 20.0, -30.0),
    (-122.1, 42.94, 2.0e4, 0.0, -60.0),
]


def doc_blocks() -> list[str]:
    """The Python blocks of docs/plugins.md marked as run by this test, in order."""
    text = DOCS.read_text(encoding="utf-8")
    blocks = re.findall(re.escape(MARK) + r"[^\n]*\n```python\n(.*?)```", text, re.S)
    assert len(blocks) == 2, "docs/plugins.md lost a tested example"
    return blocks


@pytest.fixture
def registry(plugin_site: PluginSite, globeview_registry):
    code = "\n\n".join(doc_blocks())
    code += "\n\nclass SmallBudget(TriangleBudgetProvider):\n    budget = 8_000\n"
    plugin_site.add("gvt_docs_lod", MANIFEST, {"impl": code})
    return globeview_registry.discover()


def _select(registry, name: str, terrain, view):
    provider = registry.find("lod", name)
    assert provider is not None, registry.failure_of(name)
    rs = registry.select(provider, view, terrain)
    assert rs is not None, registry.failure_of(name)
    return rs


def _by_key(rs) -> dict[tuple[int, int, int], tuple]:
    """key -> (its index variant, its error) of a render set."""
    return {
        tuple(int(v) for v in k): (rs.variants[int(i)], float(e))
        for k, i, e in zip(rs.keys, rs.variant_ids, rs.error_px, strict=True)
    }


@pytest.mark.parametrize("camera", VIEWS)
def test_doc_provider_selects_what_chunked_sse_does(
    registry, globeview_terrain, headless_view, camera
) -> None:
    view = headless_view(*camera, viewport=(800, 600))
    ours = _select(registry, "my-sse", globeview_terrain, view)
    theirs = _select(registry, "chunked-sse", globeview_terrain, view)
    assert len(ours) == len(theirs) > 0
    assert _by_key(ours) == _by_key(theirs)


def test_doc_triangle_budget_provider(registry, globeview_terrain, headless_view) -> None:
    from globeview.plugins.api import triangle_count

    view = headless_view(-71.3, 44.0, 3.0e4, 20.0, -30.0, viewport=(800, 600))
    size = globeview_terrain.tile_size
    sse = _select(registry, "chunked-sse", globeview_terrain, view)
    full = triangle_count(sse, size)
    assert 8_000 < full <= 200_000  # the view: over the small budget, within the large one
    within = _select(registry, "tri-budget", globeview_terrain, view)
    assert within.stats["tau_used_px"] == view.tau_px
    assert _by_key(within) == _by_key(sse)
    small = _select(registry, "tri-budget-small", globeview_terrain, view)
    assert triangle_count(small, size) <= 8_000 < full
    assert small.stats["tau_used_px"] > view.tau_px
    assert np.isfinite(small.error_px).all()
