"""`DisplaySettings`: how the globe is drawn (exaggeration, wireframe, hillshade, fog,
colours), evented: each field has a signal under ``settings.events`` that fires on change."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from psygnal import evented

from globeview.errors import SettingError
from globeview.validate import check_exaggeration

#: The colour of space behind the globe (linear RGB, 0..1).
SPACE_RGB = (0.02, 0.02, 0.05)


@evented
@dataclass
class DisplaySettings:
    """Live display settings; all take effect on the next frame.

    exaggeration: vertical exaggeration factor (1 = true heights); refused where it is set
    (`globeview.validate.check_exaggeration`: `SettingError`, a `GlobeviewError` and a
    ValueError, one line with the range, nothing changes, no event), so no frame trips over
    a NaN; background and wire_color: RGB, each 0..1.
    ``settings.events.<field>.connect(callback)`` subscribes to one field,
    ``settings.events.connect(callback)`` to all (psygnal).
    """

    exaggeration: float = 1.0
    wireframe: bool = False
    hillshade: bool = False
    fog: bool = True
    background: tuple[float, float, float] = SPACE_RGB
    wire_color: tuple[float, float, float] = (0.05, 0.05, 0.05)

    def __setattr__(self, name: str, value: Any) -> None:
        # psygnal's evented setter wraps this one and emits only after it returned, so a
        # refused value raises before anything changes or any listener hears of it.
        if name == "exaggeration":
            try:
                value = check_exaggeration(value)
            except ValueError as exc:
                raise SettingError(str(exc)) from None
        super().__setattr__(name, value)
