"""The fault matrix (docs/faults.md) names tests that exist: a row cannot point at a test that
was renamed or removed."""
import re
from pathlib import Path

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


def test_every_import_a_document_shows_imports():
    """A code line `from X import Y` or `import X` in README.md or docs/*.md names what is there
    (docs/recordings.md showed `from daemon import recording` after the module had become
    daemon.recordings)."""
    import importlib
    import importlib.util
    shown = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "systemd").glob("*.md"))]:
        for line in path.read_text().splitlines():
            found = re.match(r"^ {4}(from ([\w.]+) import ([\w, ]+)|import ([\w.]+))\s*(#.*)?$", line)
            if found:
                shown.append((path.name, found))
    assert len(shown) >= 4
    for name, found in shown:
        if found.group(4):
            importlib.import_module(found.group(4))
            continue
        module = importlib.import_module(found.group(2))
        for attr in (a.strip() for a in found.group(3).split(",")):
            assert hasattr(module, attr) or importlib.util.find_spec(f"{found.group(2)}.{attr}"), \
                f"{name}: {found.group(0).strip()}: no {attr}"
