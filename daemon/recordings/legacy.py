"""Recordings made before the cycle layout, read into today's flat samples.

Before the layout, a recording's ``describe`` had no ``cycle_layout``; its MCAP state samples
were nested (``{"joints": {"elbow": {"angle_rad": ..., "p_head_pa": ...}}, "out_volts": {...},
"force_n": ..., "commands": {"elbow.pressure_a": ...}}``) and a ``.pnrec`` held the ``state``
messages' old columns (``angle_rad``: a list per cycle of one value per joint ...). Both
become one flat sample per cycle keyed by the field names of :func:`layout_of` (the layout
their describe implies), so every reader sees one shape. What those recordings called
``p_head_pa``/``p_rod_pa`` were the COMMANDED chamber pressures (``<joint>.p_<chamber>_cmd``);
they held no measured pressure.
"""
from __future__ import annotations

import math

from daemon.wire.cycle_layout import CycleLayout, Field

NAN = math.nan
OLD = (("angle_rad", "position"), ("velocity_rad_s", "velocity"), ("setpoint_rad", "setpoint"), ("error_rad", "error"))


def layout_of(describe: dict) -> CycleLayout:
    """The layout of a recording's (or a daemon's) ``describe``: its ``cycle_layout``, or for one
    made before it, the fields its state samples held."""
    if "cycle_layout" in describe:
        return CycleLayout.from_describe(describe["cycle_layout"])
    joints = describe["joints"]
    interfaces = describe.get("command_interfaces") or [
        {"joint": j["name"], "name": "v_mv", "unit": "V"} for j in joints]
    fields: list[Field] = []

    def add(owner: str, quantity: str, unit: str, group: str) -> None:
        fields.append(Field(f"{owner}.{quantity}" if owner else quantity, unit, owner, quantity, group, len(fields)))

    add("", "cycle", "-", "clock")
    add("", "t", "s", "clock")
    for quantity, group in (("position", "measured"), ("velocity", "measured"), ("setpoint", "reference"),
                            ("error", "reference")):
        for j in joints:
            unit = "m" if j.get("kind") == "linear" else "rad"
            add(j["name"], quantity, unit + ("/s" if quantity == "velocity" else ""), group)
    for c in interfaces:
        add(c["joint"], f"u.{c['name']}", c.get("unit", "V"), "command")
    pairs = [j for j in joints if j.get("actuation") != "valve"]
    for k in range(2):
        for j in pairs:
            add(j["name"], f"p_{_chambers(j)[k]}_cmd", "Pa", "commanded")
    add("", "force", "N", "measured")
    for o in describe["transport"]["outputs"]:
        add("", f"out.{o[0]}", "V", "output")
    for c in interfaces:
        add(c["joint"], f"shadow.{c['name']}", c.get("unit", "V"), "shadow")
    add("", "mode", "-", "mode")
    return CycleLayout(fields)


def _chambers(joint: dict) -> list[str]:
    return list(joint.get("chambers") or ("head", "rod"))


class Converter:
    """Old state samples and messages of one recording (its ``describe``) as flat samples."""

    def __init__(self, describe: dict):
        self.layout = layout_of(describe)
        self.joints = [j["name"] for j in describe["joints"]]
        self.chambers = {j["name"]: _chambers(j) for j in describe["joints"]}
        self.commands = [f.quantity[2:] for f in self.layout.of_group("command")]
        self.command_owners = [f.owner for f in self.layout.of_group("command")]
        self.outputs = [o[0] for o in describe["transport"]["outputs"]]

    def _blank(self) -> dict:
        return dict.fromkeys(self.layout.names, NAN)

    def nested(self, sample: dict) -> dict:
        """One nested MCAP state sample (NaN already where it held null) as a flat one."""
        flat = self._blank()
        flat["cycle"], flat["t"], flat["mode"] = sample["cycle"], sample["t"], sample["mode"]
        for name, joint in sample["joints"].items():
            for old, new in OLD:
                flat[f"{name}.{new}"] = joint.get(old, NAN)
            first, second = self.chambers.get(name, ("head", "rod"))
            if f"{name}.p_{first}_cmd" in flat:
                flat[f"{name}.p_{first}_cmd"] = joint.get("p_head_pa", NAN)
                flat[f"{name}.p_{second}_cmd"] = joint.get("p_rod_pa", NAN)
            if f"{name}.u.v_mv" in flat:
                flat[f"{name}.u.v_mv"] = joint.get("u_volts", NAN)
                flat[f"{name}.shadow.v_mv"] = joint.get("shadow_u_volts", NAN)
        for key, value in sample.get("commands", {}).items():
            joint, _, command = key.partition(".")
            flat[f"{joint}.u.{command}"] = value
        for ch, value in sample.get("out_volts", {}).items():
            flat[f"out.{ch}"] = value
        flat["force"] = sample.get("force_n", NAN)
        return flat

    def columns(self, m: dict) -> list[dict]:
        """One old ``state`` message (its columns: a list per cycle of one value per joint) as
        flat samples."""
        out = []
        for i, cycle in enumerate(m["cycle"]):
            flat = self._blank()
            flat["cycle"], flat["t"], flat["mode"] = cycle, m["t"][i], m["mode"][i]
            for old, new in OLD:
                for name, value in zip(self.joints, m[old][i]):
                    flat[f"{name}.{new}"] = value
            for name, head, rod in zip(self.joints, m["p_head_pa"][i], m["p_rod_pa"][i]):
                first, second = self.chambers[name]
                if f"{name}.p_{first}_cmd" in flat:
                    flat[f"{name}.p_{first}_cmd"], flat[f"{name}.p_{second}_cmd"] = head, rod
            shadow = m["shadow_u_volts"][i]
            for owner, command, u, s in zip(self.command_owners, self.commands, m["u_volts"][i],
                                            shadow if shadow is not None else [NAN] * len(self.commands)):
                flat[f"{owner}.u.{command}"], flat[f"{owner}.shadow.{command}"] = u, s
            for ch, value in zip(self.outputs, m["out_volts"][i]):
                flat[f"out.{ch}"] = value
            flat["force"] = m["force_n"][i]
            out.append(flat)
        return out
