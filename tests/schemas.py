"""The protocol's JSON Schemas (docs/schemas), as validators for real replies and telemetry."""
from __future__ import annotations

import json
from pathlib import Path

import jsonschema

SCHEMAS = Path(__file__).resolve().parents[1] / "docs" / "schemas"


def schema(name: str, definition: str | None = None) -> jsonschema.Draft202012Validator:
    doc = json.loads((SCHEMAS / f"{name}.schema.json").read_text())
    if definition is not None:
        doc = {"$schema": doc["$schema"], **doc["$defs"][definition]}
    return jsonschema.Draft202012Validator(doc)
