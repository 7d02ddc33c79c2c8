"""The cycle record's fields as a person reads them: the readers (``watch``, plots, the Bluesky
signals) take names, units and values from the layout (:mod:`daemon.wire.cycle_layout`), never
from a list of their own. A field is shown in its display unit (deg for rad, mm for m, kPa for Pa,
else its SI unit: ``Field.display``), labelled with that unit; commanded and measured values keep the
layout's distinct names (``p_head_cmd`` against ``p_head``)."""
from __future__ import annotations

import math

from daemon.wire.cycle_layout import CycleLayout, Field

# what a person calls each group of a joint's fields, in a legend or a column
WORDS = {"position": "position", "velocity": "velocity", "setpoint": "set-point", "error": "error"}


def display(field: Field, value) -> float:
    """``value`` [SI] in the field's display unit (NaN for a missing one)."""
    return math.nan if value is None else float(value) * field.display[1]


def unit(field: Field) -> str:
    return field.display[0]


def label(field: Field, with_owner: bool = True) -> str:
    """``"bottom position [deg]"``, ``"axis commanded p_head [kPa]"``: a legend entry or an axis label."""
    return f"{name(field, with_owner)} [{unit(field)}]"


def name(field: Field, with_owner: bool = True) -> str:
    """A field's name in words: its quantity, prefixed with what it is where the name alone
    would not say (a command, a commanded pressure, a shadow's command)."""
    q = field.quantity
    if field.group == "command":
        words = f"command {q[2:]}"
    elif field.group == "commanded":
        words = f"commanded {q[:-4]}"
    elif field.group == "shadow":
        words = f"shadow {q[len('shadow.'):]}"
    elif field.group == "output":
        words = f"output {q[len('out.'):]}"
    elif field.group == "measured" and q.startswith("p_"):
        words = f"measured {q}"
    else:
        words = WORDS.get(q, q)
    return f"{field.owner} {words}" if with_owner and field.owner else words


def shown(field: Field, value, width: int = 0) -> str:
    """``value`` [SI] as text in the display unit, e.g. ``"121.50 deg"``; ``"-"`` for a missing one."""
    v = display(field, value)
    if not math.isfinite(v):
        return "-".rjust(width)
    digits = f"{v:.2f}" if abs(v) < 1e4 else f"{v:,.0f}"
    return f"{digits} {unit(field)}".rjust(width)


def latest(message: dict, layout: CycleLayout, row: int = -1) -> dict:
    """One row of a ``state`` message (the last by default), by field name: SI values, ``mode`` by name."""
    return {n: message[n][row] for n in layout.names}


def check(message: dict, layout: CycleLayout) -> bool:
    """Whether a ``state`` message is written in ``layout`` (its ``layout`` id): a message of
    another (a daemon restarted with another rig file) is not read through this one."""
    return message.get("layout") == layout.id
