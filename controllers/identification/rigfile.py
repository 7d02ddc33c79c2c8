"""The identified model into a rig file: a ``[models.NAME]`` table (numbers with their units,
and where they came from), and the joint's ``model`` naming it, so the model-based
controllers design against it. The rest of the file, its comments and layout, stay as they
were (tomlkit). On the simulated rig the simulator's plant stays what it was (its
``transport.options.joints.JOINT.model`` pins it), so the file's model is the controllers'
belief, not a change of the truth."""
from __future__ import annotations

import dataclasses

import tomlkit

from hal import config
from hal.identified import IDENTIFICATION_KEYS, UNITS, JointParams


def with_model(source: str, joint: str, name: str, params: JointParams, provenance: str,
               judged: dict[str, float] | None = None) -> str:
    """``source`` (a rig file's text) with model ``name`` added (or replaced) and ``joint``
    using it, and what the identification ``judged`` of it (``heldout_fit_percent``,
    ``heldout_rms_deg``: the model beside the arm's band comes from the RMS); the result is
    checked by parsing it as a rig (ConfigError if it will not do)."""
    doc = tomlkit.parse(source)
    joints = [j for j in doc.get("joints", []) if j.get("name") == joint]
    if not joints:
        raise ValueError(f"no joint {joint!r} in the rig file")
    entry = joints[0]
    previous = str(entry.get("model", joint))
    table = tomlkit.table()
    table.add(tomlkit.comment("written by pneumactl identify: the joint model of rig-facts §1 [2-36..2-45]"))
    table["source"] = provenance
    for f in dataclasses.fields(JointParams):
        table[f.name] = float(getattr(params, f.name))
        table[f.name].comment(f"[{UNITS[f.name]}]")
    for key, value in (judged or {}).items():
        table[key] = float(value)
        table[key].comment(f"[{IDENTIFICATION_KEYS[key]}] on data the fit did not see")
    if "models" not in doc:
        doc.add(tomlkit.nl())
        doc["models"] = tomlkit.table(is_super_table=True)
    doc["models"][name] = table
    entry["model"] = name
    transport = doc.get("transport", {})
    if transport.get("backend") == "sim" and previous != name:
        options = transport.setdefault("options", tomlkit.table())
        sim_joints = options.setdefault("joints", tomlkit.table(is_super_table=True))
        pinned = sim_joints.setdefault(joint, tomlkit.table())
        if "model" not in pinned:
            pinned["model"] = previous
            pinned["model"].comment("the simulated plant stays the one it was")
            pinned.add(tomlkit.nl())
    text = tomlkit.dumps(doc)
    config.parse(text, "<identified rig>")
    return text
