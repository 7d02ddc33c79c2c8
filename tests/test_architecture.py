"""The house's import rules hold: import-linter's contracts in pyproject.toml (layers
hal < controllers, sim_backend < daemon < bench < tests; the client never imports the
loop's side; wire and recordings import no process folder; nothing but tests imports tests;
the daemon never imports its harness, daemon.testing, and reaches the simulator only by
name; no cycles between sibling modules)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LINT = Path(sys.executable).parent / "lint-imports"


def lint(config: Path) -> subprocess.CompletedProcess:
    # --no-cache: the linter writes nothing into the checkout
    return subprocess.run([str(LINT), "--config", str(config), "--no-cache"], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def test_every_import_contract_is_kept():
    result = lint(ROOT / "pyproject.toml")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def test_a_broken_contract_fails_with_the_import_that_breaks_it(tmp_path):
    config = tmp_path / "contracts.toml"
    config.write_text('[tool.importlinter]\nroot_packages = ["daemon"]\n\n'
                      '[[tool.importlinter.contracts]]\nname = "main builds nothing itself"\ntype = "forbidden"\n'
                      'source_modules = ["daemon.main"]\nforbidden_modules = ["daemon.assembly"]\n')
    result = lint(config)
    assert result.returncode != 0
    assert "daemon.main -> daemon.assembly" in result.stdout
