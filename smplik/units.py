"""Length units of skeleton and motion files: one table of names, one parser.

``UNIT_NAMES`` maps a unit name to metres per unit. The CMU mocap unit is the ASF file's
``length 0.45`` in inches: one CMU unit is ``1 / 0.45`` inch = 0.05644 m (the cgspeed CMU BVH
conversion keeps it), so a 30-unit tall CMU subject is 1.7 m, not 3 m (as decimetres would say).
"""

from __future__ import annotations

import math

UNIT_NAMES: dict[str, float] = {
    "m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001,
    "in": 0.0254, "inch": 0.0254, "ft": 0.3048,
    "cmu": 0.0254 / 0.45,
}
"""Metres per unit of every accepted unit name."""

DETECTABLE_UNITS: tuple[str, ...] = ("m", "ft", "dm", "cmu", "in", "cm", "mm")
"""Units :func:`detect_units` chooses among: every unit of a real skeleton file (a 5.6 ft character is 1.7 m in
feet, 0.56 m in decimetres; a 17 dm one 1.7 m in decimetres, 5.2 m in feet)."""


def parse_units(units: str | float, error: type[ValueError] = ValueError) -> float:
    """Metres per unit from a name in :data:`UNIT_NAMES` or a positive number; raises ``error`` otherwise."""
    if isinstance(units, bool):
        raise error(f"Units must be a unit name or metres per unit, got {units!r}.")
    if isinstance(units, (int, float)):
        value = float(units)
    else:
        key = str(units).strip().lower()
        if key in UNIT_NAMES:
            return UNIT_NAMES[key]
        try:
            value = float(key)
        except ValueError:
            raise error(f"Unknown units {str(units)[:40]!r}; use one of {', '.join(UNIT_NAMES)}, 'auto', or metres "
                        "per unit as a number.") from None
    if not math.isfinite(value) or value <= 0 or value < 1e-9 or value > 1e6:
        raise error(f"Units must be a positive number of metres per unit (1e-9 to 1e6), got {units!r}.")
    return value


def detect_units(stature_units: float, target_m: float = 1.7) -> str:
    """The unit of :data:`DETECTABLE_UNITS` that makes ``stature_units`` closest to ``target_m`` (log scale)."""
    if not (math.isfinite(stature_units) and stature_units > 0):
        raise ValueError(f"Cannot detect units from a stature of {stature_units!r} file units.")
    return min(DETECTABLE_UNITS, key=lambda u: abs(math.log(stature_units * UNIT_NAMES[u] / target_m)))
