"""The status bar's cursor position text (`globeview.ui.status.format_lonlat`): a pure
function, no window needed."""

from __future__ import annotations

import pytest

from globeview.ui.status import format_lonlat


@pytest.mark.parametrize(
    ("lon", "lat", "text"),
    [
        (-123.12, 49.28, "49.28000°N 123.12000°W"),
        (151.2, -33.87, "33.87000°S 151.20000°E"),
        # Zero is neither south nor west, however it was reached: a negative zero...
        (-0.0, -0.0, "0.00000°N 0.00000°E"),
        # ...or a value that rounds to zero at five decimals.
        (-4e-6, -4.9e-6, "0.00000°N 0.00000°E"),
        (-1e-300, -1e-300, "0.00000°N 0.00000°E"),
        # Just past the rounding, the hemisphere is the value's.
        (-6e-6, -5.1e-6, "0.00001°S 0.00001°W"),
        (180.0, 90.0, "90.00000°N 180.00000°E"),
    ],
)
def test_zero_is_north_and_east(lon: float, lat: float, text: str) -> None:
    assert format_lonlat(lon, lat) == text
