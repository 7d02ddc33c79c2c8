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
