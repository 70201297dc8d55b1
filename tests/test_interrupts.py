"""Ctrl-C counted, and held back inside C code that swallows exceptions (globeview.interrupts):
a SIGINT inside `deferred_sigint` is raised when the block ends, in place of what the block
did; inside code marked `sigint_raised_in` it is raised at once."""

from __future__ import annotations

import signal
import threading

import pytest

from globeview.interrupts import (
    deferred_sigint,
    install_sigint_marker,
    sigint_count,
    sigint_pending,
    sigint_raised_in,
)


@pytest.fixture(autouse=True)
def _counting_handler() -> None:
    assert install_sigint_marker(), "the counting SIGINT handler is not in place"


def _ctrl_c() -> None:
    signal.raise_signal(signal.SIGINT)  # the handler runs before this returns


@sigint_raised_in
def _catching(steps: list[str]) -> None:
    _ctrl_c()
    steps.append("not reached")


def test_outside_a_deferred_block_a_ctrl_c_is_raised_at_once_and_counted() -> None:
    before = sigint_count()
    with pytest.raises(KeyboardInterrupt):
        _ctrl_c()
    assert sigint_count() == before + 1 and not sigint_pending()


def _block(steps: list[str], then: BaseException | None = None) -> None:
    """A deferred block (a GDAL call) that a Ctrl-C reaches, then goes on; raises ``then``."""
    with deferred_sigint():
        _ctrl_c()
        steps.append(f"went on, pending {sigint_pending()}")
        if then is not None:
            raise then


def test_inside_a_deferred_block_it_is_raised_when_the_block_ends() -> None:
    steps: list[str] = []
    with pytest.raises(KeyboardInterrupt):
        _block(steps)
    assert steps == ["went on, pending True"] and not sigint_pending()


def test_it_replaces_what_the_block_raised() -> None:
    # What a swallowed interrupt became (GDAL's generic I/O error) is not what the user sees.
    with pytest.raises(KeyboardInterrupt):
        _block([], OSError("read error"))
    with pytest.raises(OSError, match="read error"), deferred_sigint():  # no Ctrl-C
        raise OSError("read error")


def _nested(steps: list[str]) -> None:
    with deferred_sigint():
        try:
            _catching(steps)  # our file object's read: it catches and records
        except KeyboardInterrupt:
            steps.append("caught inside")
        with deferred_sigint():
            _ctrl_c()
        steps.append("inner block ended")


def test_marked_code_gets_it_at_once_and_nested_blocks_raise_at_the_outermost_end() -> None:
    steps: list[str] = []
    with pytest.raises(KeyboardInterrupt):
        _nested(steps)
    assert steps == ["caught inside", "inner block ended"]


def test_off_the_main_thread_a_block_does_nothing() -> None:
    seen: list[bool] = []

    def work() -> None:
        with deferred_sigint():
            seen.append(sigint_pending())

    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert seen == [False]
