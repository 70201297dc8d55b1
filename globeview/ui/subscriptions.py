"""`Subscriptions`: the model signals (psygnal) a Qt object listens to, kept so they can be
disconnected together when the object goes away (a closed window must not be called by a
model that outlives it, nor keep it alive)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class Subscriptions:
    """Connects callbacks to psygnal signals (or signal groups' ``all`` relays) and
    disconnects them all in `clear`."""

    def __init__(self) -> None:
        self._pairs: list[tuple[Any, Callable[..., Any]]] = []

    def connect(self, signal: Any, slot: Callable[..., Any]) -> None:
        """``signal.connect(slot)``, remembered for `clear`."""
        signal.connect(slot)
        self._pairs.append((signal, slot))

    def clear(self) -> None:
        """Disconnect every callback connected here."""
        pairs, self._pairs = self._pairs, []
        for signal, slot in pairs:
            signal.disconnect(slot, missing_ok=True)

    def __len__(self) -> int:
        return len(self._pairs)
