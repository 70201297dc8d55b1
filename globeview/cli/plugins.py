"""`globeview plugins`: list, validate, enable and disable plugins.

- ``plugins list [--json] [--check]``: name, version, kinds, enabled, status and error of
  every discovered plugin. Reads manifests only; ``--check`` also loads the enabled plugins'
  contributions, so import errors show up as 'failed'.
- ``plugins validate PATH_OR_NAME [--import]``: validate a manifest file or an installed
  plugin's manifest; exit 0 when valid, 2 with a one-line reason when not. ``--import`` also
  imports and creates its contributions.
- ``plugins enable NAME`` / ``plugins disable NAME``: the persisted choice.
- ``plugins set NAME.KEY VALUE``: store a contribution's setting (checked against its type
  and range) in the settings file; ``plugins get NAME[.KEY]``: the values in effect.

The settings file is ``settings.json`` in the config directory: ``$GLOBEVIEW_CONFIG_DIR``
if set, else ``$XDG_CONFIG_HOME/globeview``, else ``~/.config/globeview``
(`globeview.plugins.settings.config_dir`).
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from globeview.plugins.manifest import Manifest
    from globeview.plugins.registry import PluginRegistry


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
    p = sub.add_parser(
        "set",
        help="store a setting of a contribution (LOD provider, tool, layer type) in the "
        "settings file",
    )
    p.add_argument("setting", metavar="NAME.KEY", help="contribution name and setting key")
    p.add_argument("value", metavar="VALUE", nargs="?", help="the new value")
    p.add_argument(
        "--default", action="store_true", help="forget the stored value (the default applies)"
    )
    p = sub.add_parser("get", help="show a contribution's settings (or one of them)")
    p.add_argument("setting", metavar="NAME[.KEY]", help="contribution name, or NAME.KEY")


def run(args: argparse.Namespace) -> int:
    """Run one `plugins` action; returns the exit status."""
    return {
        "list": _list,
        "validate": _validate,
        "enable": _set_enabled,
        "disable": _set_enabled,
        "set": _set_setting,
        "get": _get_setting,
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


def _registry() -> PluginRegistry:
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
    imported = ""
    if args.do_import:
        problems, made = _import_contributions(reg, manifest)
        if problems:
            print(f"invalid: {manifest.name}: {'; '.join(problems)}", file=sys.stderr)
            return 2
        imported = "; imported and created " + ", ".join(made)
    kinds = ",".join(k.value for k in manifest.kinds)
    n = len(manifest.contributions)
    print(
        f"valid: {manifest.name} {manifest.version} ({kinds}; {n} contribution"
        f"{'s' if n != 1 else ''}; API {manifest.api_version}){imported}"
        + ("" if args.do_import else " (manifest only; --import also loads the code)")
    )
    return 0


def _import_contributions(reg: PluginRegistry, manifest: Manifest) -> tuple[list[str], list[str]]:
    """Import and create every contribution of ``manifest`` and check its settings'
    defaults; returns (problems, one "NAME (kind: Class, N settings)" per contribution)."""
    from globeview.plugins.settings import contribution_settings, settings_problems

    problems: list[str] = []
    made: list[str] = []
    with _quiet_plugin_log():
        for c in manifest.contributions:
            instance = reg.load_contribution(manifest.name, c.name)
            if instance is None:
                why = reg.failure_of(c.name) or reg.get(manifest.name).error
                why = why or "not created"
                # Name the contribution unless it is the plugin's namesake (the line has it).
                problems.append(why if c.name == manifest.name else f"{c.name}: {why}")
                continue
            declared = reg.call_for(
                instance, lambda i=instance: tuple(getattr(i, "settings", ()) or ()), default=()
            )
            problems += [f"{c.name}: {p}" for p in settings_problems(declared)]
            n = len(contribution_settings(reg, instance))
            made.append(
                f"{c.name} ({c.kind.value}: {type(instance).__name__}, {n} setting"
                f"{'s' if n != 1 else ''})"
            )
    return problems, made


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


def _show(value: object) -> str:
    """A setting value as typed on the command line: true/false, 0.3, fast."""
    import json

    if isinstance(value, str):
        return value
    return json.dumps(value)


def _split_setting(reg: PluginRegistry, text: str) -> tuple[str, str | None]:
    """``NAME`` or ``NAME.KEY`` -> (NAME, KEY or None); a whole text that names a
    contribution is a NAME even with dots in it."""
    declared = {c.name for rec in reg if rec.manifest for c in rec.manifest.contributions}
    if text in declared:
        return text, None
    name, dot, key = text.rpartition(".")
    return (name, key) if dot and name and key else (text, None)


def _set_setting(args: argparse.Namespace) -> int:
    from globeview.errors import GlobeviewError
    from globeview.plugins.settings import (
        contribution_key,
        find_setting,
        parse_setting_value,
        setting_problem,
        stored_values,
    )

    with _quiet_plugin_log():
        reg = _registry()
        name, key = _split_setting(reg, args.setting)
        if key is None:
            raise GlobeviewError(f"plugins set takes NAME.KEY VALUE, not {args.setting!r:.80}")
        target = find_setting(reg, name, key)
    if args.default == (args.value is not None):
        raise GlobeviewError(f"plugins set {target.label}: give a VALUE or --default")
    values = stored_values(reg.settings, target.plugin, target.contribution)
    if args.default:
        values.pop(key, None)
        shown = f"{_show(target.setting.default)} (the default)"
    else:
        try:
            value = parse_setting_value(target.setting, args.value)
        except ValueError as exc:
            raise GlobeviewError(
                f"plugins set {target.label}: {setting_problem(target.setting, exc)}"
            ) from None
        values[key] = value
        shown = _show(value)
    reg.settings.set(contribution_key(target.plugin, target.contribution), values)
    where = getattr(reg.settings, "path", None)
    print(f"{target.label} = {shown}" + (f" (saved in {where})" if where else ""))
    return 0


def _get_setting(args: argparse.Namespace) -> int:
    from globeview.errors import GlobeviewError
    from globeview.plugins.api import resolve_settings
    from globeview.plugins.settings import (
        contribution_settings,
        describe_setting,
        find_contribution,
        find_setting,
        stored_values,
    )

    with _quiet_plugin_log():
        reg = _registry()
        name, key = _split_setting(reg, args.setting)
        if key is not None:
            target = find_setting(reg, name, key)
            plugin, settings = target.plugin, (target.setting,)
        else:
            plugin, instance = find_contribution(reg, name)[0]
            settings = contribution_settings(reg, instance)
            if not settings:
                raise GlobeviewError(f"{name} has no settings")
    stored = stored_values(reg.settings, plugin, name)
    values = resolve_settings(settings, stored)
    if key is not None:
        print(_show(values[key]))
        return 0
    for s in settings:
        origin = "default"
        if s.name in stored:
            # A stored value the Setting cannot take as it is (a stale file, another
            # version) is clamped or replaced by the default when read: say so.
            raw = stored[s.name]
            origin = (
                "stored"
                if values[s.name] == raw
                and isinstance(raw, bool) == isinstance(values[s.name], bool)
                else f"stored {str(raw)[:40]!r}, read as {_show(values[s.name])}"
            )
        print(
            f"{name}.{s.name} = {_show(values[s.name])}  ({origin}; {describe_setting(s)}, "
            f"default {_show(s.default)})"
        )
    return 0
