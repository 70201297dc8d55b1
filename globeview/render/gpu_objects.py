"""Every GL object globeview makes, tracked in one place per context.

The render adapters (the terrain renderer, the tile and index pools, the overlay adapters,
offscreen targets) create their GL objects through `gpu_objects(ctx)` instead of the bare
``ctx``: the same factory methods (``buffer``, ``texture``, ``texture_array``, ``program``,
``vertex_array``, ``framebuffer``, ``depth_texture``), each recording what it made and which
module made it. moderngl has no object counter of its own; this gives one:

- `GpuObjects.live` / `counts`: the objects not released yet (what the soak watches grow),
- `GpuObjects.leaked_since(mark)`: objects made after ``mark`` that nothing but the tracker
  references any more and that were not released: a GL leak (no code can free them), which
  the ``globeview_gl`` test fixture fails a test for.

Objects are released the usual way (``obj.release()``); the tracker sees that (moderngl swaps
a released object's ``mglo`` for an ``InvalidObject``). Nothing here runs per frame in steady
state: objects are made when model state first needs them (lazily, at frame time).
"""

from __future__ import annotations

import gc
import sys
import weakref
from collections import Counter
from dataclasses import dataclass
from typing import Any

import moderngl

__all__ = ["GpuObjects", "TrackedObject", "gpu_objects", "make_current"]


def make_current(ctx: moderngl.Context) -> None:
    """Make a context from `create_headless_context` current on this thread again; any other
    context (a window's, which its toolkit makes current before painting) is left alone.

    Why: creating a headless context makes it current, so a second context opened on the same
    thread (an in-process `globeview render`, a second session or benchmark) left the first
    one's later calls drawing into, reading from and deleting names of the other context:
    wrong images, an empty frame or another context's objects released. GL names are small
    integers in every context, so such calls often "work" on the wrong objects. Every GL
    object made through `gpu_objects`, each frame, and each read or release of a headless
    target calls this first (entering the context already current: ~1 us)."""
    if isinstance(ctx.extra, dict) and ctx.extra.get("globeview_headless"):
        ctx.__enter__()  # no __exit__: it stays current, as `create_headless_context` leaves it


@dataclass
class TrackedObject:
    """One GL object the tracker made: the moderngl object, its kind (the factory's name)
    and the module that asked for it."""

    obj: Any
    kind: str
    owner: str
    serial: int

    @property
    def released(self) -> bool:
        return isinstance(getattr(self.obj, "mglo", None), moderngl.InvalidObject)

    def __str__(self) -> str:
        return f"{self.kind} from {self.owner}"


class GpuObjects:
    """The tracker of one moderngl context (get it with `gpu_objects(ctx)`)."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self._ctx = weakref.ref(ctx)
        self._objects: list[TrackedObject] = []
        self._serial = 0
        self._prune_at = 256

    # -- factories (the moderngl.Context methods, recorded) ----------------------------------
    def _make(self, kind: str, *args: Any, **kwargs: Any) -> Any:
        ctx = self._ctx()
        if ctx is None:
            raise RuntimeError("the GL context of this tracker is gone")
        make_current(ctx)
        obj = getattr(ctx, kind)(*args, **kwargs)
        # The caller's module: who to blame in a leak report (creation only, not per frame).
        owner = sys._getframe(2).f_globals.get("__name__", "?")
        self._serial += 1
        self._objects.append(TrackedObject(obj, kind, owner, self._serial))
        if len(self._objects) >= self._prune_at:
            self._objects = [t for t in self._objects if not t.released]
            self._prune_at = max(256, 2 * len(self._objects))
        return obj

    def buffer(self, *args: Any, **kwargs: Any) -> moderngl.Buffer:
        return self._make("buffer", *args, **kwargs)

    def texture(self, *args: Any, **kwargs: Any) -> moderngl.Texture:
        return self._make("texture", *args, **kwargs)

    def texture_array(self, *args: Any, **kwargs: Any) -> moderngl.TextureArray:
        return self._make("texture_array", *args, **kwargs)

    def depth_texture(self, *args: Any, **kwargs: Any) -> moderngl.Texture:
        return self._make("depth_texture", *args, **kwargs)

    def program(self, *args: Any, **kwargs: Any) -> moderngl.Program:
        return self._make("program", *args, **kwargs)

    def vertex_array(self, *args: Any, **kwargs: Any) -> moderngl.VertexArray:
        return self._make("vertex_array", *args, **kwargs)

    def framebuffer(self, *args: Any, **kwargs: Any) -> moderngl.Framebuffer:
        return self._make("framebuffer", *args, **kwargs)

    def renderbuffer(self, *args: Any, **kwargs: Any) -> moderngl.Renderbuffer:
        return self._make("renderbuffer", *args, **kwargs)

    # -- counting ------------------------------------------------------------------------------
    @property
    def mark(self) -> int:
        """A point in time: `leaked_since` reports objects made after it."""
        return self._serial

    @property
    def live(self) -> list[TrackedObject]:
        """The objects made here and not released yet."""
        return [t for t in self._objects if not t.released]

    def counts(self) -> dict[str, int]:
        """Unreleased objects by kind (``{"buffer": 7, "program": 3, ...}``)."""
        return dict(Counter(t.kind for t in self.live))

    def leaked_since(self, mark: int = 0) -> list[TrackedObject]:
        """Objects made after ``mark``, not released, that nothing but this tracker
        references (after a garbage collection): nothing can release them any more."""
        gc.collect()
        leaked = []
        for t in self._objects:
            if t.serial <= mark or t.released:
                continue
            # References: the TrackedObject, getrefcount's argument. Anything more is a
            # holder (a live renderer's cache, a shared fixture) that can still release it.
            if sys.getrefcount(t.obj) <= 2:
                leaked.append(t)
        return leaked

    def release_leaked(self, leaked: list[TrackedObject]) -> None:
        """Release leaked objects (after reporting them), so one leak is reported once."""
        for t in leaked:
            t.obj.release()


_TRACKERS: weakref.WeakKeyDictionary[moderngl.Context, GpuObjects] = weakref.WeakKeyDictionary()


def gpu_objects(ctx: moderngl.Context) -> GpuObjects:
    """The tracker of ``ctx`` (made on first use; lives as long as the context)."""
    tracker = _TRACKERS.get(ctx)
    if tracker is None:
        tracker = _TRACKERS[ctx] = GpuObjects(ctx)
    return tracker
