"""`globeview plugins`: list, validate, enable and disable plugins.

- ``plugins list [--json] [--check]``: name, version, kinds, enabled, status and error of
  every discovered plugin. Reads manifests only; ``--check`` also loads the enabled plugins'
  contributions, so import errors show up as 'failed'.
- ``plugins validate PATH_OR_NAME [--import]``: validate a manifest file or an installed
  plugin's manifest; exit 0 when valid, 2 with a one-line reason when not. ``--import`` also
  imports and creates its contributions.
- ``plugins enable NAME`` / ``plugins disable NAME``: the persisted choice.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register `plugins`' sub-subcommands on its subparser."""
    sub = parser.add_subparsers(dest="plugins_command", metavar="ACTION", required=True)
    p = sub.add_parser("list", help="list discovered plugins and their state")
    p.add_argument("--json", action="store_true", help="print a JSON list instead of a table")
    p.add_argument(
        "--check", action="store_true", help="also load enabled plugins to catch import errors"
    )
    p = sub.add_parser("validate", help="validate a plugin manifest (file path or plugin name)")
    p.add_argument("target", metavar="PATH_OR_NAME")
    p.add_argument(
        "--import",
        dest="do_import",
        action="store_true",
        help="also import and create the plugin's contributions",
    )
    for action in ("enable", "disable"):
        p = sub.add_parser(action, help=f"{action} a plugin (remembered in the settings)")
        p.add_argument("name", metavar="NAME")


def run(args: argparse.Namespace) -> int:
    """Run one `plugins` action; returns the exit status."""
    return {
        "list": _list,
        "validate": _validate,
        "enable": _set_enabled,
        "disable": _set_enabled,
    }[args.plugins_command](args)


@contextlib.contextmanager
def _quiet_plugin_log() -> Iterator[None]:
    """Keep plugin failure lines off the terminal (the table reports them), and whatever
    plugin code prints while it is imported off stdout (``list --json`` must stay JSON)."""
    import io
    import logging

    logger = logging.getLogger("globeview.plugins")
    saved = logger.propagate
    handler = logging.NullHandler()
    logger.propagate = False
    logger.addHandler(handler)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            yield
    finally:
        logger.removeHandler(handler)
        logger.propagate = saved


def _registry():
    from globeview.plugins.registry import PluginRegistry

    return PluginRegistry().discover()


def _list(args: argparse.Namespace) -> int:
    import json

    with _quiet_plugin_log():
        reg = _registry()
        if args.check:
            for kind in ("lod", "tool", "layer"):
                reg.contributions(kind)
    rows = [rec.as_dict() for rec in reg]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    if not rows:
        print("no plugins found")
        return 0
    table = [("NAME", "VERSION", "KINDS", "ENABLED", "STATUS", "DETAIL")]
    for r in rows:
        detail = r["error"] or r["description"]
        table.append(
            (
                r["name"],
                r["version"] or "-",
                ",".join(r["kinds"]) or "-",
                "yes" if r["enabled"] else "no",
                r["status"],
                detail,
            )
        )
    widths = [max(len(row[i]) for row in table) for i in range(5)]
    for row in table:
        print("  ".join(c.ljust(w) for c, w in zip(row[:5], widths)) + "  " + row[5])
    return 0


def _validate(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from globeview.plugins.manifest import ManifestError, read_manifest
    from globeview.plugins.registry import PluginRegistry
    from globeview.plugins.settings import MemorySettings

    target = args.target
    path = Path(target)
    reg = PluginRegistry(MemorySettings())
    try:
        # A path (a file, a directory, /dev/null, anything with a slash) is read as a
        # manifest file, so the reason names the file; a bare word is a plugin name.
        if path.suffix == ".toml" or path.exists() or "/" in target or "\\" in target:
            manifest = read_manifest(path)
            reg.add_path(path)
        else:
            reg.discover()
            if target not in reg:
                known = ", ".join(sorted(reg.records)) or "none"
                raise ManifestError(f"no plugin named {target!r} (installed: {known})")
            rec = reg.get(target)
            if rec.manifest is None:
                raise ManifestError(rec.error or "invalid manifest")
            manifest = rec.manifest
    except ManifestError as exc:
        print(f"invalid: {exc}", file=sys.stderr)
        return 2
    if args.do_import:
        with _quiet_plugin_log():
            for c in manifest.contributions:
                reg.load_contribution(manifest.name, c.name)
        rec = reg.get(manifest.name)
        if rec.status == "failed":
            print(f"invalid: {manifest.name}: {rec.error}", file=sys.stderr)
            return 2
    kinds = ",".join(k.value for k in manifest.kinds)
    n = len(manifest.contributions)
    print(
        f"valid: {manifest.name} {manifest.version} ({kinds}; {n} contribution"
        f"{'s' if n != 1 else ''}; API {manifest.api_version})"
    )
    return 0


def _set_enabled(args: argparse.Namespace) -> int:
    from globeview.errors import GlobeviewError

    reg = _registry()
    if args.name not in reg:
        known = ", ".join(sorted(reg.records)) or "none"
        raise GlobeviewError(f"no plugin named {args.name!r} (installed: {known})")
    rec = reg.enable(args.name) if args.plugins_command == "enable" else reg.disable(args.name)
    if rec.manifest is None:
        raise GlobeviewError(f"plugin {args.name!r} cannot be enabled: {rec.error}")
    print(f"{rec.name}: {'enabled' if rec.enabled else 'disabled'}")
    return 0
