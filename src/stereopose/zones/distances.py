"""Approach distances by voltage: a zone's `voltage_kv` and `distance_table` give its approach
margin (`margin_m`, which an explicit `margin_m` overrides). Each table maps a nominal voltage
to the minimum distance in air a person keeps from live parts; a voltage between two rows takes
the higher row (the larger distance), and a voltage outside the table's range is a ConfigError
naming the zone and the range. The tables and their sources are in docs/zone-state.md.

- `gb26860` (default): GB 26860-2011, Electric power safety work procedure, power plants and
  substations (the Chinese safety code), Table 1, safety distance when equipment is not
  de-energized (AC rows): 10 kV and below 0.70 m, 20 and 35 kV 1.00 m, 66 and 110 kV 1.50 m,
  220 kV 3.00 m, 330 kV 4.00 m, 500 kV 5.00 m, 750 kV 7.20 m, 1000 kV 8.70 m.
- `en50110`: EN 50110-1:2013, Operation of electrical installations, Annex A, Table A.1: the
  outer limit of the vicinity zone D_V by nominal voltage.
- `osha`: 29 CFR 1910.333(c)(3), Table S-5, approach distances for qualified employees,
  alternating current (300 V to 140 kV).
"""

from __future__ import annotations

import math

from stereopose.errors import ConfigError

__all__ = ["DEFAULT_TABLE", "TABLES", "approach_distance"]

_FT, _IN = 0.3048, 0.0254

# name -> (what it is, rows of (the highest nominal voltage of the row in kV, metres)),
# rows in rising voltage; the first row also sets the lowest voltage the table covers
TABLES: dict[str, tuple[str, float, tuple[tuple[float, float], ...]]] = {
    "gb26860": (
        "GB 26860-2011 Table 1 (equipment not de-energized)",
        0.0,
        (
            (10.0, 0.70),
            (35.0, 1.00),
            (110.0, 1.50),
            (220.0, 3.00),
            (330.0, 4.00),
            (500.0, 5.00),
            (750.0, 7.20),
            (1000.0, 8.70),
        ),
    ),
    "en50110": (
        "EN 50110-1:2013 Table A.1 (vicinity zone D_V)",
        0.0,
        (
            (1.0, 0.30),
            (3.0, 1.12),
            (6.0, 1.12),
            (10.0, 1.15),
            (15.0, 1.16),
            (20.0, 1.22),
            (30.0, 1.32),
            (36.0, 1.38),
            (45.0, 1.48),
            (60.0, 1.63),
            (70.0, 1.75),
            (110.0, 2.00),
            (132.0, 3.00),
            (150.0, 3.00),
            (220.0, 3.00),
            (275.0, 4.00),
            (380.0, 4.00),
            (480.0, 6.10),
            (700.0, 8.40),
        ),
    ),
    "osha": (
        "29 CFR 1910.333 Table S-5 (qualified employees, AC)",
        0.3,
        (
            (0.75, 1 * _FT),
            (2.0, 1 * _FT + 6 * _IN),
            (15.0, 2 * _FT),
            (37.0, 3 * _FT),
            (87.5, 3 * _FT + 6 * _IN),
            (121.0, 4 * _FT),
            (140.0, 4 * _FT + 6 * _IN),
        ),
    ),
}
DEFAULT_TABLE = "gb26860"


def approach_distance(voltage_kv: object, table: object, where: str) -> float:
    """The table's distance (metres) for a nominal voltage (kV); ConfigError naming `where`,
    the table and its range for a voltage it does not cover or a table that is not one."""
    if not isinstance(table, str) or table not in TABLES:
        raise ConfigError(
            f"{where}: distance_table: expected one of {', '.join(TABLES)}, got {table!r}"
        )
    what, lowest, rows = TABLES[table]
    number = isinstance(voltage_kv, (int, float)) and not isinstance(voltage_kv, bool)
    if not number or not isinstance(voltage_kv, (int, float)) or not math.isfinite(voltage_kv):
        raise ConfigError(
            f"{where}: voltage_kv: expected a number of kilovolts, got {voltage_kv!r}"
        )
    kv = float(voltage_kv)
    if kv <= lowest or kv > rows[-1][0]:
        low = f"above {lowest:g} kV" if lowest else "above 0 kV"
        raise ConfigError(
            f"{where}: voltage_kv = {kv:g} is outside {table} ({what}): it covers {low} "
            f"up to {rows[-1][0]:g} kV"
        )
    return next(metres for top, metres in rows if kv <= top + 1e-9)
