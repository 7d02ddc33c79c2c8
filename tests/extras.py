"""The optional extras of pyproject.toml (``pip install -e '.[bluesky]'``) in the suite: whether
one is installed here, and the skip that says how to install it.

README.md's test command installs ``.[test]`` alone, so a test that needs another extra is
skipped there, saying so, never run half-way or passed: a test marked with the extra's name
(``@pytest.mark.bluesky``; tests/conftest.py adds the skip), or a whole file that imports the
extra at its top (before those imports, ``if extras.missing("bluesky"): pytest.skip(
extras.reason("bluesky"), allow_module_level=True)``, and the mark in its ``pytestmark``).
``pytest -m bluesky`` runs those tests alone once the extra is installed (.ci/run's second step)."""
from __future__ import annotations

import importlib.metadata
import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
# Every extra but the test command's own; each is a marker of the same name (pyproject.toml's markers).
EXTRAS = {name: [re.match(r"[A-Za-z0-9_.-]+", requirement).group(0) for requirement in requirements]
          for name, requirements in _PROJECT["optional-dependencies"].items() if name != "test"}
# Our own packages that import an extra's modules (so a module shown in a document needs that extra).
OUR_PACKAGES = {"bluesky": ("daemon.client.bluesky",)}


def missing(extra: str) -> list[str]:
    """The distributions of ``extra`` that are not installed here."""
    absent = []
    for distribution in EXTRAS[extra]:
        try:
            importlib.metadata.version(distribution)
        except importlib.metadata.PackageNotFoundError:
            absent.append(distribution)
    return absent


def reason(extra: str) -> str:
    return f"needs the {extra} extra ({', '.join(missing(extra))} not installed): pip install -e '.[{extra}]'"


def extra_of(module: str) -> str | None:
    """The extra that importing ``module`` needs (its top package is one of the extra's
    distributions, or one of ours that imports them), None if the base install has it."""
    top = module.split(".")[0].lower()
    for extra, distributions in EXTRAS.items():
        if top in {d.lower().replace("-", "_") for d in distributions}:
            return extra
        if any(module == ours or module.startswith(ours + ".") for ours in OUR_PACKAGES.get(extra, ())):
            return extra
    return None
