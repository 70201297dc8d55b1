"""Ctrl-C, counted, and held back inside C code that swallows exceptions.

`install_sigint_marker` replaces Python's default SIGINT handler by one that counts the
signals it delivers (`sigint_count`) and raises KeyboardInterrupt as the default does. Two
users:

- the plugin isolation (`globeview.plugins.isolation`) tells the user's Ctrl-C, a SIGINT
  delivered during a call into plugin code, from a KeyboardInterrupt plugin code raises
  itself;
- GDAL reading through Python file objects (a remote store's chunk files, rasterio's
  ``opener=``). rasterio's callbacks swallow what Python raises inside them: a
  KeyboardInterrupt raised in a seek, a tell, an open or a close became a generic GDAL error
  (a tile stood in for by its ancestor, so an interrupted ``render`` finished and exited 0),
  a close that returned normally, or, raised as a read callback began, a garbage length and
  an aborted process. Inside `deferred_sigint` (a GDAL call, on the main thread) a SIGINT is
  counted but not raised, and the block raises KeyboardInterrupt when it ends, whatever the
  call did meanwhile. Code of ours inside the call that catches KeyboardInterrupt itself (a
  file object's read: it records the interrupt and returns "no bytes", so the wait for the
  network ends at once) is marked `sigint_raised_in`: a SIGINT arriving while it, or what it
  calls, runs is raised there as usual; `sigint_pending` lets it stop at once for one held
  back earlier in the same call.

Python runs signal handlers on the main thread only, so all of this concerns the main
thread; elsewhere the blocks and checks do nothing. Bottom layer: imports nothing of
globeview.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from types import CodeType, FrameType
from typing import Any, TypeVar

__all__ = [
    "deferred_sigint",
    "install_sigint_marker",
    "sigint_count",
    "sigint_pending",
    "sigint_raised_in",
]

F = TypeVar("F", bound=Callable[..., Any])

_lock = threading.Lock()
_installed = False
_count = 0
#: Code objects inside which (and below which) a SIGINT is raised even in a deferred block.
_raised_in: set[CodeType] = set()


class _Deferral:
    """The main thread's deferred blocks: how deep, and the count when the outermost began."""

    depth = 0
    mark = 0


_deferral = _Deferral()


def _counting_sigint_handler(signum: int, frame: FrameType | None) -> None:
    """SIGINT handler: count the signal, then raise KeyboardInterrupt as Python's default
    handler does; inside a `deferred_sigint` block, only where `sigint_raised_in` allows."""
    global _count
    _count += 1
    if _deferral.depth and not _inside_raising_code(frame):
        return  # held back: the block raises it when the C code has returned
    raise KeyboardInterrupt


def _inside_raising_code(frame: FrameType | None) -> bool:
    while frame is not None:
        if frame.f_code in _raised_in:
            return True
        frame = frame.f_back
    return False


def install_sigint_marker() -> bool:
    """Make Ctrl-C countable (and deferrable, `deferred_sigint`).

    Replaces Python's default SIGINT handler (`signal.default_int_handler`) by one that counts
    the signal and then raises KeyboardInterrupt exactly as the default does (outside a
    deferred block). Leaves any other handler (SIG_DFL, SIG_IGN, an application's own) alone:
    with those a Ctrl-C is neither counted nor deferred. Only possible from the main thread;
    idempotent. Returns True when the counting handler is in place.
    """
    global _installed
    with _lock:
        if _installed:
            return signal.getsignal(signal.SIGINT) is _counting_sigint_handler
        if threading.current_thread() is not threading.main_thread():
            return False
        try:
            if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
                return False
            signal.signal(signal.SIGINT, _counting_sigint_handler)
        except (ValueError, OSError):  # not the main interpreter / no signals here
            return False
        _installed = True
        return True


def sigint_count() -> int:
    """How many SIGINTs the counting handler has delivered in this process."""
    return _count


def sigint_pending() -> bool:
    """Whether a SIGINT arrived on this (the main) thread during the deferred block it is in
    and waits to be raised when the block ends."""
    return (
        _deferral.depth > 0
        and _count != _deferral.mark
        and threading.current_thread() is threading.main_thread()
    )


@contextlib.contextmanager
def deferred_sigint() -> Iterator[None]:
    """Around a call into C code that calls back into Python and swallows exceptions (a GDAL
    read through a Python file object): a SIGINT during it is counted, not raised (but inside
    `sigint_raised_in` code), and KeyboardInterrupt is raised when the block ends, in place
    of whatever the call raised or returned. Nested blocks raise at the outermost's end. On
    another thread than the main one, or without the counting handler, it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _deferral.depth == 0:
        _deferral.mark = _count
    mark = _deferral.mark
    _deferral.depth += 1
    try:
        yield
    except BaseException:
        _deferral.depth -= 1
        if _deferral.depth == 0 and _count != mark:
            raise KeyboardInterrupt from None
        raise
    _deferral.depth -= 1
    if _deferral.depth == 0 and _count != mark:
        raise KeyboardInterrupt


def sigint_raised_in(fn: F) -> F:
    """Mark ``fn`` as code whose caller catches a KeyboardInterrupt raised in it or in what it
    calls: inside a `deferred_sigint` block a SIGINT is raised there as usual (it ends the
    wait under way at once). Only for functions always called inside such a ``try``."""
    _raised_in.add(fn.__code__)
    return fn
