"""The worked controller plugin of docs/writing-controllers.md (``examples/controller_plugin``),
as its package's wheel, made here from its own pyproject.toml (the name, version, entry points
and module it declares: what its build makes, without a build backend or the network), for the
document's ``pip install`` line to install into a directory the test puts on a daemon's path
(``PYTHONPATH``), never into the checkout or the suite's environment."""
from __future__ import annotations

import tomllib
from pathlib import Path

from tests import wheels
from tests.doc_blocks import ROOT

SOURCE = ROOT / "examples" / "controller_plugin"


def wheel(directory: Path, source: Path = SOURCE) -> Path:
    """The package at ``source`` as a wheel (PEP 427) in ``directory``."""
    project = tomllib.loads((source / "pyproject.toml").read_text())
    meta = project["project"]
    name, version = meta["name"].replace("-", "_"), meta["version"]
    dist = f"{name}-{version}.dist-info"
    files = {f"{module}.py": (source / f"{module}.py").read_text() for module in project["tool"]["setuptools"]["py-modules"]}
    groups = "".join(f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in entries.items()) + "\n"
                     for group, entries in meta["entry-points"].items())
    files[f"{dist}/METADATA"] = (f"Metadata-Version: 2.1\nName: {meta['name']}\nVersion: {version}\n"
                                 f"Summary: {meta['description']}\n")
    files[f"{dist}/entry_points.txt"] = groups
    return wheels.write(directory, name, version, files, "tests/controller_plugin.py")
