"""Failure isolation: every call into plugin code runs here (`Isolation.call`, ``invoke``,
``call_for``, ``select``), and a failure fails the contribution it came from, not the host.

An exception in plugin code fails the **contribution** it came from for this session (that
contribution is dropped, so the host stops calling it; the plugin's other contributions keep
working and the plugin's status reads 'partial'), is logged with its traceback to the
``globeview.plugins`` logger, and the call returns a default. Once every contribution of a
plugin has failed, or when the failure cannot be pinned on one contribution (an invalid
manifest), the plugin as a whole is 'failed'. A failure found by the host itself (e.g. a
displacement shader that does not compile) is reported with `fail` (the contribution) or
`report_failure`. A failure is not persisted: the next start tries the plugin again.

Isolation covers every `BaseException` raised by plugin code — ``SystemExit``,
``GeneratorExit``, a ``KeyboardInterrupt`` the plugin raises itself — except a real Ctrl-C: the
host installs a SIGINT handler (`install_sigint_marker`) that counts the signals it delivers,
and a KeyboardInterrupt escaping plugin code is re-raised only when a SIGINT arrived during
that call. Frame-path calls (``budgeted=True``) are timed; see `Budget`. The failure is logged
as one line at WARNING on ``globeview.plugins`` and its traceback at DEBUG (and kept on the
record, `PluginRecord.traceback`), so a terminal sees one line, never a traceback.

`Isolation` is one part of `globeview.plugins.registry.PluginRegistry` (the records it
updates and the loaded contributions it drops are the registry's).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeVar

from globeview.errors import GlobeviewError
from globeview.interrupts import install_sigint_marker, sigint_count
from globeview.lod.render_set import RenderSet
from globeview.paths import log_path
from globeview.plugins.api import LodProvider, PluginKind
from globeview.plugins.records import ContributionFailure, PluginRecord
from globeview.plugins.settings import SettingsBackend

__all__ = [
    "BUDGET_MS_KEY",
    "BUDGET_OVERRUNS_KEY",
    "BUDGET_POLICY_KEY",
    "FRAME_PATH_METHODS",
    "LOG_MAX_BYTES",
    "MAX_MESSAGE_CHARS",
    "Budget",
    "Isolation",
    "PluginTimeout",
    "describe_exception",
    "failure_log_path",
    "install_sigint_marker",
    "read_budget",
    "sigint_count",
]

log = logging.getLogger("globeview.plugins")

T = TypeVar("T")


#: Settings keys of the frame-path time budget (see `Budget`).
BUDGET_MS_KEY = "plugins/budget_ms"


BUDGET_OVERRUNS_KEY = "plugins/budget_overruns"


BUDGET_POLICY_KEY = "plugins/budget_policy"


#: Methods called on the UI thread every frame or input event: timed against the budget
#: (`invoke`). Not ``displacement_numpy``: providers call it inside their own ``select``.
FRAME_PATH_METHODS = frozenset({"select", "overlay", "displacement_uniforms", "on_mouse", "on_key"})


#: Longest error text kept on a record or logged (hostile plugins raise huge messages).
MAX_MESSAGE_CHARS = 300


class PluginTimeout(Exception):
    """A plugin's frame-path calls overran the time budget too many times in a row."""


def describe_exception(exc: BaseException) -> str:
    """``"ExcType: message"`` on one line, at most `MAX_MESSAGE_CHARS` characters."""
    try:
        msg = " ".join(str(exc).split())
    except Exception:  # noqa: BLE001  a plugin's exception whose __str__ itself raises
        msg = "<unprintable message>"
    text = f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
    if len(text) > MAX_MESSAGE_CHARS:
        text = text[: MAX_MESSAGE_CHARS - 3] + "..."
    return text


# -- telling a real Ctrl-C from a KeyboardInterrupt raised by plugin code ----------------------
# The counting SIGINT handler and its count live in globeview.interrupts (the terrain's remote
# reads defer a Ctrl-C with it too); `install_sigint_marker` and `sigint_count` are re-exported.


def _not_ready(exc: BaseException) -> bool:
    """Whether ``exc`` is a remote tile not fetched yet (`TileNotReady`), imported only then
    (the registry serves `globeview plugins` too, which reads no terrain)."""
    from globeview.terrain.store.backend import TileNotReady

    return isinstance(exc, TileNotReady)


@dataclass
class Budget:
    """The time budget of frame-path plugin calls (``select``, a tool's per-frame hooks).

    Attributes:
        ms: milliseconds one call may take (<= 0: no budget).
        overruns: consecutive overruns after which the ``disable`` policy disables the plugin.
        policy: what ``overruns`` consecutive overruns do: 'disable' the plugin (the window:
            a slow provider would freeze it) or 'warn' (headless renders and benchmarks: one
            warning line per plugin, the plugin keeps running).
    """

    # 1 s, not a frame's 33 ms: a built-in provider rebuilding its meshes on llvmpipe under
    # load takes a few hundred ms a call (quadtree-clod ~200 ms at 1280x720), and a slow
    # machine must not cost the user a built-in. Five calls in a row over 1 s still catch a
    # provider that freezes the window.
    ms: float = 1000.0
    overruns: int = 5
    policy: Literal["warn", "disable"] = "warn"


def read_budget(settings: SettingsBackend, default_policy: Literal["warn", "disable"]) -> Budget:
    """The `Budget` from ``settings`` (``plugins/budget_ms``, ``plugins/budget_overruns``,
    ``plugins/budget_policy``); values of the wrong type or range are ignored."""
    b = Budget(policy=default_policy)
    ms = settings.get(BUDGET_MS_KEY)
    if isinstance(ms, int | float) and not isinstance(ms, bool) and math.isfinite(ms):
        b.ms = float(ms)
    n = settings.get(BUDGET_OVERRUNS_KEY)
    if isinstance(n, int) and not isinstance(n, bool) and n >= 1:
        b.overruns = n
    policy = settings.get(BUDGET_POLICY_KEY)
    if policy in ("warn", "disable"):
        b.policy = policy
    return b


class Isolation:
    """The part of the registry that runs plugin code: ``call`` (and ``invoke``, ``call_for``,
    ``select``) isolated and timed, ``fail`` / ``report_failure`` recording a failure, and
    which contribution an object is (``owner_of``, ``contribution_of``, ``failure_of``).

    Uses the registry's ``records``, ``budget``, ``_owners``/``_live`` (the contributions
    created / still loaded) and ``_unload``, ``contribution_active``, ``is_active``.
    """

    records: dict[str, PluginRecord]
    budget: Budget
    _owners: dict[int, tuple[str, Any, str]]
    _live: set[int]

    def owner_of(self, instance: Any) -> str:
        """The name of the plugin that made a contribution object (loaded now or before)."""
        return self.contribution_of(instance)[0]

    def contribution_of(self, instance: Any) -> tuple[str, str]:
        """(plugin name, contribution name) of a contribution object (loaded now or before)."""
        try:
            plugin, _instance, name = self._owners[id(instance)]
        except KeyError:
            raise KeyError(f"{instance!r} is not a loaded plugin contribution") from None
        return plugin, name

    def failure_of(self, name: str, kind: PluginKind | str | None = None) -> str | None:
        """Why contribution ``name`` (of ``kind``, if given) failed this session —
        ``"ExcType: message"``, its own failure or its plugin's — or None when no plugin
        declaring it has failed it (it may still be disabled by the user, or unknown)."""
        kind = PluginKind(kind) if kind is not None else None
        for rec in self.records.values():
            if rec.manifest is None or not any(
                c.name == name and (kind is None or c.kind == kind)
                for c in rec.manifest.contributions
            ):
                continue
            if name in rec.failures:
                return rec.failures[name].error
            if rec.status == "failed":
                return rec.error or "failed"
        return None

    def call(
        self,
        plugin_name: str,
        fn: Callable[..., T],
        *args: Any,
        default: Any = None,
        user_errors: bool = False,
        budgeted: bool = False,
        contribution: str | None = None,
        pass_not_ready: bool = False,
        **kwargs: Any,
    ) -> T | Any:
        """Run ``fn(*args, **kwargs)`` — plugin code — isolated.

        Returns ``default`` without calling when the plugin (or ``contribution`` of it) is
        not active, and when ``fn`` raises any `BaseException` (SystemExit, GeneratorExit, a
        KeyboardInterrupt of its own...): ``contribution`` — or, without one, the whole
        plugin — is then disabled for the session (`report_failure`). Only a real Ctrl-C — a
        SIGINT delivered while ``fn`` ran, see `install_sigint_marker` — is re-raised. With
        ``user_errors``, a `GlobeviewError` (bad input the user gave, e.g. a broken file to a
        layer type's ``open``) propagates to the caller instead: the plugin is not at fault.
        With ``budgeted`` (frame-path calls) the call is timed against `budget` (see
        `Budget`). With ``pass_not_ready``, `TileNotReady` (a remote tile not fetched yet,
        read on a thread that never waits for the network) propagates: the data is late, the
        plugin is not at fault (`LodHost.select` draws that frame without it).
        """
        if contribution is not None:
            if not self.contribution_active(plugin_name, contribution):
                return default
        elif not self.is_active(plugin_name):
            return default
        before = sigint_count()
        t0 = time.perf_counter()
        try:
            result = fn(*args, **kwargs)
        except GlobeviewError as exc:
            if user_errors or (pass_not_ready and _not_ready(exc)):
                raise
            self.report_failure(plugin_name, exc, contribution=contribution)
            return default
        except BaseException as exc:
            if _is_user_interrupt(exc, before):
                raise
            self.report_failure(plugin_name, exc, contribution=contribution)
            return default
        if budgeted:
            ms = (time.perf_counter() - t0) * 1e3
            self._check_budget(plugin_name, fn, ms, contribution)
        return result

    def _check_budget(
        self, plugin_name: str, fn: Any, ms: float, contribution: str | None = None
    ) -> None:
        """Count a frame-path call of ``ms`` milliseconds against the budget of
        ``contribution`` (or of the plugin): after ``budget.overruns`` consecutive overruns
        the 'disable' policy disables it; the 'warn' policy logs one warning per plugin and
        session."""
        b = self.budget
        rec = self.records.get(plugin_name)
        if rec is None or b.ms <= 0:
            return
        key = contribution or ""
        if ms <= b.ms:
            rec.overruns[key] = 0
            return
        n = rec.overruns[key] = rec.overruns.get(key, 0) + 1
        if n < b.overruns:  # one slow call (a cold cache) is no verdict
            return
        what = f"{getattr(fn, '__name__', 'call')}()"
        if b.policy == "disable":
            self.report_failure(
                plugin_name,
                PluginTimeout(
                    f"{what} took {ms:.0f} ms, over the {b.ms:g} ms budget "
                    f"({BUDGET_MS_KEY}) {n} calls in a row"
                ),
                contribution=contribution,
            )
        elif not rec.budget_warned:
            rec.budget_warned = True
            log.warning(
                "plugin %s: %s took %.0f ms, over the %g ms frame budget (%s) %d calls in a "
                "row; kept running (%s is 'warn')",
                plugin_name,
                what,
                ms,
                b.ms,
                BUDGET_MS_KEY,
                n,
                BUDGET_POLICY_KEY,
            )

    def invoke(
        self,
        instance: Any,
        method: str,
        *args: Any,
        default: Any = None,
        user_errors: bool = False,
        budgeted: bool | None = None,
        pass_not_ready: bool = False,
        **kwargs: Any,
    ) -> Any:
        """``call`` a method of a loaded contribution, e.g.
        ``registry.invoke(tool, "on_mouse", event, default=False)``.

        A failure (any exception, or no such method) fails that contribution only; the
        plugin's other contributions keep working. Returns ``default`` for an object whose
        contribution or plugin was disabled or failed since (the host may still hold it),
        without calling it.

        ``user_errors=True``: a `globeview.errors.GlobeviewError` raised by the method is the
        user's bad input, not a plugin bug (e.g. a layer type's ``open`` given a broken
        file): it propagates to the caller — which shows its one line — and the
        contribution stays enabled. Any other exception still fails the contribution.
        Use it only for methods whose input comes from the user (``open`` of a file).

        ``budgeted`` defaults to whether ``method`` is one of `FRAME_PATH_METHODS` (timed
        against the budget)."""
        if budgeted is None:
            budgeted = method in FRAME_PATH_METHODS
        plugin, name = self.contribution_of(instance)
        if id(instance) not in self._live:
            return default
        fn = getattr(instance, method, None)
        if not callable(fn):
            self.report_failure(
                plugin,
                TypeError(f"{type(instance).__name__} has no {method}()"),
                contribution=name,
            )
            return default
        return self.call(
            plugin,
            fn,
            *args,
            default=default,
            user_errors=user_errors,
            budgeted=budgeted,
            contribution=name,
            pass_not_ready=pass_not_ready,
            **kwargs,
        )

    def call_for(
        self, instance: Any, fn: Callable[..., T], *args: Any, default: Any = None, **kwargs: Any
    ) -> T | Any:
        """`call` ``fn`` (plugin code that belongs to contribution object ``instance``, e.g.
        a method of the layer a layer type opened), failing that contribution if it raises.
        Takes `call`'s keyword arguments."""
        plugin, name = self.contribution_of(instance)
        if id(instance) not in self._live:
            return default
        return self.call(plugin, fn, *args, default=default, contribution=name, **kwargs)

    def select(
        self,
        provider: LodProvider,
        view: Any,
        terrain: Any,
        check: Callable[[Any], None] | None = None,
    ) -> Any | None:
        """``provider.select(view, terrain)`` isolated and timed (frame path), checking it
        returned a RenderSet — and, with ``check`` (e.g. `RenderSet.validate` with the
        renderer's limits), a valid one: ``check`` raising fails the provider's plugin.

        Returns None when the provider failed (the host then falls back to another)."""
        failed = object()
        result = self.invoke(
            provider, "select", view, terrain, default=failed, budgeted=True, pass_not_ready=True
        )
        if result is failed:
            return None
        if not isinstance(result, RenderSet):
            self.fail(
                provider, TypeError(f"select() returned {type(result).__name__}, not a RenderSet")
            )
            return None
        if check is not None:
            before = sigint_count()
            try:
                check(result)  # may run plugin code: a RenderSet subclass's properties
            except BaseException as exc:
                if _is_user_interrupt(exc, before):
                    raise
                self.fail(provider, exc)
                return None
        return result

    def fail(self, instance: Any, exc: BaseException) -> None:
        """Fail the contribution object ``instance`` after ``exc`` (found by the host, e.g.
        garbage it returned or a shader of it that does not compile): `report_failure` for
        that contribution only."""
        plugin, name = self.contribution_of(instance)
        self.report_failure(plugin, exc, contribution=name)

    def report_failure(
        self, plugin_name: str, exc: BaseException, contribution: str | None = None
    ) -> None:
        """Mark a contribution — or, without ``contribution``, the whole plugin — failed
        after ``exc`` (raised by it, or found by the host such as a shader compile error).

        A failed contribution is dropped and recorded in `PluginRecord.failures`; the
        plugin's other contributions keep working and its status reads 'partial'. When no
        contribution of the plugin is left working, or without ``contribution``, the plugin
        is 'failed': all its contributions are dropped and it counts as disabled for the
        session. The error is logged as one WARNING line, its traceback at DEBUG and in the
        log file. The persisted enable choice is unchanged."""
        rec = self.records.get(plugin_name)
        message = describe_exception(exc)
        try:
            tb = "".join(traceback.format_exception(exc)).rstrip()
        except Exception:  # noqa: BLE001  a hostile exception object
            tb = message
        declared = (
            {c.name: c for c in rec.manifest.contributions}
            if rec is not None and rec.manifest is not None
            else {}
        )
        if contribution is not None and contribution not in declared:
            contribution = None  # not one of its contributions: blame the plugin
        whole = contribution is None or set(declared) <= set(rec.failures) | {contribution}
        # One WARNING line (the host carries on; a terminal sees exactly this line); the
        # traceback at DEBUG, in the log file and on the record (`plugins list --json`).
        if contribution is None or len(declared) == 1:
            what = f"plugin {plugin_name}"
        else:
            what = f"plugin {plugin_name}: {declared[contribution].kind.value} {contribution}"
        where = _append_failure_log(what, tb)
        details = f" (details in {where})" if where is not None else ""
        rest = "" if whole else "; its other contributions keep working"
        log.warning("%s failed and was disabled: %s%s%s", what, message, rest, details)
        log.debug("%s failure traceback:\n%s", what, tb)
        if rec is None:
            return
        if contribution is not None:
            rec.failures[contribution] = ContributionFailure(
                declared[contribution].kind, message, tb
            )
        rec.traceback = tb
        if whole:
            self._unload(rec)
            rec.enabled = False
            rec.status = "failed"
        else:
            self._unload(rec, only=contribution)
            rec.status = "partial"
        rec.error = message if contribution is None else _failure_summary(rec, message)


def _failure_summary(rec: PluginRecord, message: str) -> str:
    """`PluginRecord.error` after a contribution failed with ``message``: the message for a
    plugin of one contribution, or when every contribution failed with that same error
    (a shared module that does not import); else ``"NAME: error"`` per distinct error, the
    names that share one joined by ``", "`` and the groups by ``"; "``."""
    declared = len(rec.manifest.contributions) if rec.manifest is not None else 0
    if declared <= 1 or not rec.failures:
        return message
    by_error: dict[str, list[str]] = {}
    for name, f in rec.failures.items():
        by_error.setdefault(f.error, []).append(name)
    if len(by_error) == 1 and len(rec.failures) == declared:
        return message
    text = "; ".join(f"{', '.join(names)}: {error}" for error, names in by_error.items())
    return _clip(text, 2 * MAX_MESSAGE_CHARS)


#: Size past which the log is moved to ``globeview.log.1`` before appending.
LOG_MAX_BYTES = 4 * 1024 * 1024


def failure_log_path() -> Path:
    """Where plugin failure tracebacks are appended: the log the CLI and the window write
    internal errors to (`globeview.paths.log_path`)."""
    return log_path()


def _append_failure_log(what: str, tb: str) -> Path | None:
    """Append a plugin failure's traceback to the log under the heading ``what`` (``"plugin
    NAME"`` or ``"plugin NAME: KIND CONTRIBUTION"``); best effort (None when the log cannot
    be written: a read-only cache must not turn a plugin failure into a host failure)."""
    path = failure_log_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(OSError):
            if path.stat().st_size > LOG_MAX_BYTES:
                os.replace(path, path.with_name(path.name + ".1"))
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        with path.open("a", encoding="utf-8", errors="replace") as f:
            f.write(f"{stamp} {what} failed and was disabled:\n{tb}\n\n")
    except OSError:
        return None
    return path


def _is_user_interrupt(exc: BaseException, sigints_before: int) -> bool:
    """True for a KeyboardInterrupt from a SIGINT delivered since ``sigints_before`` was read
    (the user's Ctrl-C); False for one plugin code raised itself, and for anything else."""
    return isinstance(exc, KeyboardInterrupt) and sigint_count() != sigints_before


def _clip(text: str, limit: int = 100) -> str:
    """``text`` cut to ``limit`` characters (hostile names and values are huge)."""
    return text if len(text) <= limit else text[: limit - 3] + "..."
