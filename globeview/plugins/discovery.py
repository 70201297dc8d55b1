"""Plugin discovery: the manifests named by the entry points of group ``globeview.plugins``
(`importlib.metadata`; the built-ins ship through the same group from globeview's own
pyproject) and manifest files given by path, read into `PluginRecord`s. Never imports
plugin code; a broken manifest or unreadable metadata is one 'failed' record, not a failed
discovery. One part of `globeview.plugins.registry.PluginRegistry`.
"""

from __future__ import annotations

import importlib.metadata as md
import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Self

from globeview.plugins.isolation import MAX_MESSAGE_CHARS, _clip, describe_exception
from globeview.plugins.manifest import Manifest, ManifestError, locate_manifest, read_manifest
from globeview.plugins.records import PluginRecord

__all__ = ["BUILTIN_DISTRIBUTION", "ENTRY_POINT_GROUP", "PluginDiscovery"]

log = logging.getLogger("globeview.plugins")

#: Entry point group plugins register under.
ENTRY_POINT_GROUP = "globeview.plugins"


#: Distribution whose entry points are the built-in plugins.
BUILTIN_DISTRIBUTION = "globeview"


class PluginDiscovery:
    """The part of the registry that finds plugins (``discover``, ``add_path``): it fills the
    registry's ``records`` (and resets ``_owners``/``_live``), each enabled as the user's
    stored choice says (``_stored_choice``, `EnableState`)."""

    records: dict[str, PluginRecord]
    _owners: dict[int, tuple[str, Any, str]]
    _live: set[int]

    def discover(self, paths: Iterable[str | Path] = ()) -> Self:
        """Find the plugins of the entry point group (and manifest files in ``paths``).

        Reads manifests only; imports no plugin code. Replaces what was known before.
        Returns self.
        """
        self.records = {}
        self._owners = {}
        self._live = set()
        seen: set[tuple[str, str]] = set()
        eps = _plugin_entry_points()
        facts = _dist_facts(eps)
        eps.sort(key=lambda e: (facts[id(e)][0] != BUILTIN_DISTRIBUTION, e.name))
        for ep in eps:
            if (ep.name, ep.value) in seen:  # the same distribution found twice on sys.path
                continue
            seen.add((ep.name, ep.value))
            try:
                self._discover_one(ep, *facts[id(ep)])
            except Exception as exc:  # noqa: BLE001  hostile metadata: one plugin's problem, not discovery's
                self._add_invalid(_clip(ep.name), ep.value, describe_exception(exc), False)
        for p in paths:
            self.add_path(p)
        return self

    def _discover_one(self, ep: md.EntryPoint, dist_name: str, source: str | None) -> None:
        """Read ``ep``'s manifest into a record; ``dist_name`` and ``source`` from
        `_dist_facts` (``source`` None: the entry point's value names the plugin)."""
        source = ep.value if source is None else source
        builtin = dist_name == BUILTIN_DISTRIBUTION
        try:
            manifest = read_manifest(locate_manifest(ep.value))
            if manifest.name != ep.name:
                raise ManifestError(
                    f"entry point name {_clip(ep.name)!r} differs from manifest name "
                    f"{manifest.name!r}"
                )
        except ManifestError as exc:
            self._add_invalid(_clip(ep.name), source, str(exc), builtin)
            return
        self._add(manifest, source, builtin)

    def add_path(self, path: str | Path) -> PluginRecord:
        """Register the plugin described by a manifest file (its targets must be importable
        from sys.path). An invalid manifest gives a 'failed' record named after the file."""
        p = Path(path)
        try:
            manifest = read_manifest(p)
        except ManifestError as exc:
            return self._add_invalid(p.stem, str(p), str(exc), False)
        return self._add(manifest, str(p), False)

    def _add(self, manifest: Manifest, source: str, builtin: bool) -> PluginRecord:
        name = manifest.name
        if name in self.records:
            other = self.records[name].source
            return self._add_invalid(
                f"{name} ({source})", source, f"duplicate plugin name {name!r}: {other}", builtin
            )
        enabled = self._stored_choice(name, default=True)
        rec = PluginRecord(
            name, manifest, source, builtin, enabled, "ok" if enabled else "disabled"
        )
        self.records[name] = rec
        return rec

    def _add_invalid(self, name: str, source: str, error: str, builtin: bool) -> PluginRecord:
        error = _clip(" ".join(error.split()), MAX_MESSAGE_CHARS)
        rec = PluginRecord(name, None, source, builtin, False, "failed", error)
        self.records[name] = rec
        # INFO, not WARNING: every command discovers every plugin, and a broken one nobody
        # asked for must not print into unrelated commands; `plugins list` shows it.
        log.info("plugin %s disabled: invalid manifest: %s", name, error)
        return rec


def _plugin_entry_points() -> list[md.EntryPoint]:
    """The entry points of group `ENTRY_POINT_GROUP`, read distribution by distribution: one
    installed distribution with unreadable metadata (not UTF-8, malformed) is skipped with a
    one-line warning instead of hiding every plugin (`importlib.metadata.entry_points` reads
    them all at once and raises)."""
    out: list[md.EntryPoint] = []
    try:
        dists = list(md.distributions())
    except Exception as exc:  # noqa: BLE001  installed metadata may be broken any way: skip, never fail discovery
        log.warning("plugin discovery failed: %s", describe_exception(exc))
        return out
    for dist in dists:
        try:
            out.extend(ep for ep in dist.entry_points if ep.group == ENTRY_POINT_GROUP)
        except Exception as exc:  # noqa: BLE001  installed metadata may be broken any way: skip, never fail discovery
            where = getattr(dist, "_path", None) or "a distribution"
            log.info(
                "plugins of %s skipped: unreadable metadata: %s", where, describe_exception(exc)
            )
    return out


def _dist_facts(eps: list[md.EntryPoint]) -> dict[int, tuple[str, str | None]]:
    """Per entry point (by ``id``): the normalised name of its distribution ("" when unknown
    or unreadable) and "Name version" (None when there is no distribution or its METADATA
    cannot be read). Each distribution's METADATA is parsed once (an email-format parse each
    time it is asked for: ~10 ms for globeview's own, four times per plugin before)."""
    by_dist: dict[int, tuple[str, str | None]] = {}
    out: dict[int, tuple[str, str | None]] = {}
    for ep in eps:
        dist = getattr(ep, "dist", None)
        if dist is None:
            out[id(ep)] = ("", None)
            continue
        hit = by_dist.get(id(dist))
        if hit is None:
            hit = by_dist[id(dist)] = _read_dist(dist)
        out[id(ep)] = hit
    return out


def _read_dist(dist: md.Distribution) -> tuple[str, str | None]:
    """(normalised name or "", "Name version" or None) of one distribution's METADATA."""
    try:
        meta = dist.metadata
    except Exception:  # noqa: BLE001  installed metadata may be broken any way: skip, never fail discovery
        return "", None
    try:
        name = (meta["Name"] or "").lower().replace("_", "-")
    except Exception:  # noqa: BLE001  as above
        name = ""
    try:
        source: str | None = f"{meta['Name']} {meta['Version']}"
    except Exception:  # noqa: BLE001  unreadable METADATA: the entry point still names the manifest
        source = None
    return name, source
