"""The documents derived from the command catalog (:mod:`daemon.wire.catalog`):
docs/schemas/args.schema.json (:func:`args_schema`) and docs/protocol.md's command summary
(:func:`summary_table`); tests/test_catalog.py checks both are up to date."""
from __future__ import annotations

from daemon.wire.catalog import COMMANDS
from daemon.wire.command_spec import Command, Variant, offset_words


def args_schema() -> dict:
    """docs/schemas/args.schema.json: each command's ``args`` as JSON Schema, every check
    :func:`check_args` makes but which lengths go together (JSON Schema cannot compare two
    lengths): those are stated in ``x-lengths`` and in the list's description."""
    defs = {}
    for c in COMMANDS.values():
        properties = {a.name: a.schema() for a in c.args}
        if not c.strict:  # never refused for its arguments: described, not constrained
            properties = {a.name: {"description": a.help()} for a in c.args}
        defs[c.name] = {"type": "object", "description": c.doc, "properties": properties,
                        "required": [a.name for a in c.args if a.required],
                        "additionalProperties": not c.strict}
        if c.one_of:
            defs[c.name]["oneOf"] = [{"required": [name]} for name in c.one_of]
        if c.variants:
            defs[c.name]["allOf"] = [_variant_schema(c, v) for v in c.variants]
        if c.lengths:
            defs[c.name]["x-lengths"] = [{"argument": name, "items_of": list(of), "offset": offset,
                                          "description": f"{name} holds {offset_words(offset)} the items of "
                                                         f"{' or '.join(of)}"} for name, of, offset in c.lengths]
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "$id": "pneumad/args.schema.json",
            "title": "pneumad command arguments (generated from daemon/wire/catalog.py)", "$defs": defs}


def _variant_schema(command: Command, variant: Variant) -> dict:
    """One variant as an if/then: when its argument has its value (or, for the default, is
    absent), the arguments the other variants take are absent, its own required are present,
    and the limits it puts on another argument's choices hold."""
    condition = {"properties": {variant.on: {"const": variant.value}}}
    if variant.value != command.arg(variant.on).default:
        condition["required"] = [variant.on]
    others = sorted({name for v in command.variants if v.on == variant.on for name in v.takes} - set(variant.takes))
    then: dict = {"properties": {name: False for name in others}}
    for name, allowed in variant.limits:
        then["properties"][name] = {"enum": list(allowed)}
    if variant.requires:
        then["required"] = list(variant.requires)
    return {"if": condition, "then": then}


def summary_table() -> str:
    """docs/protocol.md's command summary (between its catalog markers)."""
    rows = ["| cmd | served by | sockets | lease | role | deferred | args |", "|---|---|---|---|---|---|---|"]
    for c in COMMANDS.values():
        args = "; ".join(f"`{a.name}`{' (required)' if a.required else ''}: {a.kind}, {a.help()}" for a in c.args)
        if not c.strict:
            args += " (never refused for its arguments)"
        if c.one_of:
            args += f"; exactly one of {', '.join(f'`{name}`' for name in c.one_of)}"
        for name, of, offset in c.lengths:
            args += f"; `{name}` holds {offset_words(offset)} the items of {' or '.join(f'`{o}`' for o in of)}"
        for v in c.variants:
            args += f"; {v.on} {v.value} takes {', '.join(f'`{t}`' for t in v.takes)}" + (
                f" (requires {', '.join(f'`{r}`' for r in v.requires)})" if v.requires else "") + "".join(
                f", `{name}` one of {', '.join(allowed)}" for name, allowed in v.limits)
        rows.append(f"| `{c.name}` | {c.server} | {', '.join(c.sockets)} | {'yes' if c.lease else ''} | {c.role} "
                    f"| {'yes' if c.deferred else ''} | {args} |")
    return "\n".join(rows)
