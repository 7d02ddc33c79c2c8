"""The fault matrix (docs/faults.md) names tests that exist: a row cannot point at a test that
was renamed or removed; and every import a document shows imports."""
import importlib
import importlib.util
import re
from pathlib import Path

import pytest

from tests import extras

ROOT = Path(__file__).resolve().parents[1]


def test_every_test_the_fault_matrix_names_exists():
    text = (ROOT / "docs" / "faults.md").read_text()
    named, last_file = [], None
    for file, test in re.findall(r"`(tests/[\w/]+\.py)?(?:::(test_\w+))?[^`]*`", text):
        last_file = file or last_file
        if test:
            named.append((last_file, test))
        elif file:
            named.append((file, None))
    assert len(named) > 25
    for file, test in named:
        source = (ROOT / file).read_text()
        assert test is None or re.search(rf"^def {test}\(", source, re.M), f"{file}::{test} is not there"


def shown_imports() -> list:
    """Each code line ``from X import Y`` or ``import X`` of README.md, docs/*.md and
    systemd/*.md, as a test case; one that needs an extra (``from bluesky import RunEngine``)
    is marked with it, so it is skipped, saying so, where the extra is not installed."""
    shown = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "systemd").glob("*.md"))]:
        for number, line in enumerate(path.read_text().splitlines(), 1):
            found = re.match(r"^ {4}(from ([\w.]+) import ([\w, ]+)|import ([\w.]+))\s*(#.*)?$", line)
            if found:
                extra = extras.extra_of(found.group(4) or found.group(2))
                shown.append(pytest.param(path.name, found, id=f"{path.name}:{number}",
                                          marks=[getattr(pytest.mark, extra)] if extra else []))
    return shown


def test_the_documents_show_imports():
    assert len(shown_imports()) >= 4


@pytest.mark.parametrize("name, found", shown_imports())
def test_every_import_a_document_shows_imports(name, found):
    """A code line `from X import Y` or `import X` in README.md or docs/*.md names what is there
    (docs/recordings.md showed `from daemon import recording` after the module had become
    daemon.recordings)."""
    if found.group(4):
        importlib.import_module(found.group(4))
        return
    module = importlib.import_module(found.group(2))
    for attr in (a.strip() for a in found.group(3).split(",")):
        assert hasattr(module, attr) or importlib.util.find_spec(f"{found.group(2)}.{attr}"), \
            f"{name}: {found.group(0).strip()}: no {attr}"
