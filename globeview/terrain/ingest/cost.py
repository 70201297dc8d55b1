"""Measured ingest constants behind `globeview ingest --plan`'s estimates (issue #25, §4.3).

Each figure says where it comes from (command, date, machine); `benchmarks/bench_plan.py
--measure` re-measures the CPU and bytes a node on this machine and prints the lines to
paste here.
"""

from __future__ import annotations

__all__ = [
    "BYTES_PER_NODE",
    "CLUSTER_FACTOR",
    "COST_SOURCE",
    "META_BYTES_PER_CHUNK",
    "NS_PER_NODE",
    "core_hours",
]

#: CPU nanoseconds an ingest spends per node of the chunks it computes, every level counted
#: (source hash and scan, chunks, the wavelet, errors, compression, writes; Dask, 1 worker):
#: a whole build's CPU over the nodes of its chunk files. Store format 7's chunks are whole
#: 1024^2 windows of the global grid, NaN where no source has data: the nodes `--plan`
#: counts. Measured on one SRTM3 tile, whose chunks are mostly NaN, so a build's fixed costs
#: and its NaN nodes weigh more than on a planet's full land chunks.
NS_PER_NODE = 249.0
#: Store bytes per node with data (ZSTD chunks of a real SRTM3 tile, every level; NaN nodes
#: compress to almost nothing): bytes of full chunks, an upper bound for partial ones.
BYTES_PER_NODE = 2.85
#: Where NS_PER_NODE and BYTES_PER_NODE come from (what `--plan` prints beside them).
COST_SOURCE = "bench_plan.py --measure, N44W072.hgt, median of 5, 2026-11-28, load 11.6"
#: A dask.distributed cluster spends this much more CPU than one local worker (reopened
#: sources, chunk re-reads, results shipped): docs/scale.md, bench_ingest 8192^2, 2026-11-23.
CLUSTER_FACTOR = 1.77
#: Metadata bytes a chunk (its tiles' errors, heights and stride errors in a shard,
#: compressed): design issue25.md §2.4, measured on the 4096^2 benchmark store.
META_BYTES_PER_CHUNK = 4400


def core_hours(nodes: int, ns_per_node: float = NS_PER_NODE) -> float:
    """Estimated CPU core-hours of a build writing ``nodes`` nodes (every level)."""
    return nodes * ns_per_node * 1e-9 / 3600.0
