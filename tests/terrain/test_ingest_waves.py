"""The ingest graph runs in waves (`schedule.stages`): the pole, each level's chunks finest
first, then the error windows; every task's dependencies are in an earlier wave or its own,
and dask is handed one wave at a time (ordering the whole pyramid at once costs memory and
CPU superlinear in the chunks: issue #25's 2 000-tile build)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from globeview.terrain.ingest import driver
from globeview.terrain.ingest.schedule import Graph, stages

DATA = Path(__file__).resolve().parents[2] / "data"


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Graph, list[list[str]]]:
    """A global build's graph (ETOPO 20': several chunks a level, poles, the lon-180 edge)
    and the key lists dask was handed, one call per wave."""
    handed: list[list[str]] = []
    seen: list[Graph] = []
    import dask.threaded

    real_get = dask.threaded.get

    def get(dsk: dict, keys: list[str], **kw: Any) -> Any:
        handed.append(list(keys))
        # Nothing but the wave's tasks, the plan, the sources and earlier results (data).
        tasks = [k for k, v in dsk.items() if isinstance(v, tuple) and v and callable(v[0])]
        assert sorted(tasks) == sorted(keys)
        return real_get(dsk, keys, **kw)

    real_run = driver.run_graph

    def run(graph: Graph, where: Any, on_done: Any) -> dict[str, Any]:
        seen.append(graph)
        return real_run(graph, where, on_done)

    mp = pytest.MonkeyPatch()
    mp.setattr(dask.threaded, "get", get)
    mp.setattr(driver, "run_graph", run)
    try:
        out = tmp_path_factory.mktemp("waves") / "s"
        driver.ingest([DATA / "etopo20.tif"], out, workers=2, max_level=4)
    finally:
        mp.undo()
    return seen[0], handed


@pytest.mark.slow
def test_each_wave_is_handed_to_dask_alone(built: tuple[Graph, list[list[str]]]) -> None:
    graph, handed = built
    assert handed == stages(graph)
    assert len(handed) == 1 + 5 + 1  # the pole, levels 4..0, the error windows


@pytest.mark.slow
def test_waves_cover_every_task_once_after_their_dependencies(
    built: tuple[Graph, list[list[str]]],
) -> None:
    graph, _ = built
    waves = stages(graph)
    flat = [k for w in waves for k in w]
    assert sorted(flat) == sorted(graph.keys) and len(flat) == len(set(flat))
    done: set[str] = set()
    levels = []
    for wave in waves:
        for key in wave:
            assert all(d in done or d in wave for d in graph.deps.get(key, ()))
        done |= set(wave)
        kinds = {k.split("-")[0] for k in wave}
        assert len(kinds) == 1
        if kinds == {"chunk"}:
            (lv,) = {int(k.split("-")[1]) for k in wave}
            levels.append(lv)
    assert levels == [4, 3, 2, 1, 0]  # finest first
    assert waves[0] == ["pole"] and waves[-1] == graph.error_keys


def test_a_graph_with_everything_known_has_no_wave() -> None:
    graph = Graph(dsk={}, chunk_keys=["chunk-1-0-0"], error_keys=["error-1-0-0"])
    graph.known.update({"pole": {}, "chunk-1-0-0": None, "error-1-0-0": []})
    assert stages(graph) == []
