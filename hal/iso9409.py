"""ISO 9409-1 mechanical interface plates: the one table of main dimensions in the project.

Used by the simulated robots' flange geometry (``hal/sim/flange.py``) and by the hand-eye plugin's
flange models (``plugins/handeye/flange_model.py``), which may import the hal but not the reverse.

Values: nominal ISO 9409-1:2004 Table 1 dimensions for the common sizes, in millimetres — pitch
circle d1 (the key), centring hole d2 (H7), outer diameter d3, tapped-hole thread size d4, positioning
pin hole d5 (on d1), number of tapped holes n (on d1). The 50 mm row is the ISO 9409-1-50-4-M6 plate
of UR, Franka and AUBO arms (paper 003 Fig. 5). Check the robot maker's drawing; every user accepts
explicit dimensions instead of a row.
"""

from __future__ import annotations

from types import MappingProxyType

from weldcell.sdk.errors import DataError

#: d1 (mm) -> {"d2", "d3", "d4", "d5" (mm), "n"}; read-only.
ISO9409_1 = MappingProxyType(
    {
        31.5: MappingProxyType({"d2": 20.0, "d3": 40.0, "d4": 5.0, "d5": 5.0, "n": 4}),
        40.0: MappingProxyType({"d2": 25.0, "d3": 50.0, "d4": 6.0, "d5": 6.0, "n": 4}),
        50.0: MappingProxyType({"d2": 31.5, "d3": 63.0, "d4": 6.0, "d5": 6.0, "n": 4}),
        63.0: MappingProxyType({"d2": 40.0, "d3": 80.0, "d4": 6.0, "d5": 6.0, "n": 4}),
        80.0: MappingProxyType({"d2": 50.0, "d3": 100.0, "d4": 8.0, "d5": 8.0, "n": 6}),
        100.0: MappingProxyType({"d2": 63.0, "d3": 125.0, "d4": 8.0, "d5": 8.0, "n": 6}),
    }
)

#: the keys of a full dimension set
DIMENSION_KEYS = ("d1", "d2", "d3", "d4", "d5", "n")


def iso9409_dimensions(d1_mm: float) -> dict:
    """The table row for pitch circle ``d1_mm`` as a new dict ``{"d1", "d2", "d3", "d4", "d5", "n"}``
    (mm); DataError listing the known sizes for any other value."""
    key = float(d1_mm)
    if key not in ISO9409_1:
        raise DataError(
            f"no ISO 9409-1 flange with pitch circle {d1_mm} mm in the table",
            f"use one of {sorted(ISO9409_1)} or give the dimensions (d1, d2, d3, d4, d5, n) explicitly",
        )
    return {"d1": key, **ISO9409_1[key]}


def check_dimensions(dims: dict) -> dict:
    """Validate explicit plate dimensions (mm): all of d1..d5 and n present and d2 < d1 < d3.
    Returns a new dict with floats (and int n)."""
    missing = [k for k in DIMENSION_KEYS if k not in dims]
    if missing:
        raise DataError(
            f"flange dimensions lack {', '.join(missing)}", f"give all of {', '.join(DIMENSION_KEYS)}"
        )
    d = {k: float(dims[k]) for k in DIMENSION_KEYS[:-1]}
    d["n"] = int(dims["n"])
    if not (0 < d["d2"] < d["d1"] < d["d3"]) or d["n"] < 1 or min(d["d4"], d["d5"]) <= 0:
        raise DataError(
            f"flange dimensions are inconsistent: d2={d['d2']}, d1={d['d1']}, d3={d['d3']} mm, n={d['n']}",
            "need 0 < d2 (centring hole) < d1 (pitch circle) < d3 (outer diameter), n >= 1, d4, d5 > 0",
        )
    return d
