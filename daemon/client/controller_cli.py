"""pneumactl's ``KEY=VALUE`` controller settings (controller set, switch, shadow) read as the
daemon takes them."""
from __future__ import annotations

import json
import math


def key_values(items) -> dict:
    """``KEY=VALUE`` arguments as parameters: a VALUE is JSON (a number, a JSON list with one
    value per joint, true/false), else kept as text for the daemon to check against the
    parameter's type; a non-finite number (nan, inf) is refused here, as no parameter takes one."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"expected KEY=VALUE, got {item!r}")
        try:
            parsed = json.loads(value)
        except ValueError:
            number = _float_or_none(value)  # nan, inf: what JSON does not spell
            parsed = value if number is None else number
        if not _finite(parsed):
            raise SystemExit(f"error: {item}: not a finite number (a parameter takes finite values only)")
        out[key] = parsed
    return out


def _float_or_none(text: str):
    try:
        return float(text)
    except ValueError:
        return None


def _finite(value) -> bool:
    """False for a non-finite number, or a list holding one."""
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    return not isinstance(value, float) or math.isfinite(value)
