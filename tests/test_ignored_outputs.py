"""What the documented commands write where they run, keys first, is left out of the checkout's
git by its .gitignore: a `git add -A` after the README's tour or its keys example commits no
private key and no output. Each path comes with the document whose command writes it (checked
to still show that command), and is asked of git as if it lay in the checkout (``git
check-ignore --no-index``: nothing is written)."""
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# path as written in the checkout -> the document whose command writes it, and what of that command it shows
OUTPUTS = {
    "alice.key_secret": ("README.md", "keys --keys lab-keys client alice"),
    "lab-keys/server.key_secret": ("README.md", "keys --keys lab-keys init"),
    "lab-keys/server.key": ("README.md", "keys --keys lab-keys init"),
    "lab-keys/clients/alice.key": ("README.md", "keys --keys lab-keys client alice"),
    "recordings/20260101-120000-translation.mcap": ("README.md", "(./recordings/*.mcap)"),
    "run.mcap": ("README.md", "pneumactl record run.mcap"),
    "run.csv": ("README.md", "pneumactl export run.mcap run.csv"),
    "plots/run-joints.png": ("README.md", "pneumactl plot run.mcap --out plots"),
    "run-joints.png": ("docs/recordings.md", "`pneumactl plot FILE [FILE ...] --out DIR` writes PNGs"),  # no --out: here
    "identified/rig.toml": ("README.md", "--out identified"),
    "identify-bottom-20260101-120000/report.json": ("docs/identification.md", "`identify-bottom-DATE-TIME/`"),
    "payload-reference.json": ("docs/estimation.md", "pneumactl payload identify --unloaded"),
    "dump.rdb": ("docs/bluesky.md", "redis-server --port 6379"),  # written where it runs, unless --dir
    "bench-identification/report.json": ("docs/benchmarks.md", "python -m bench.identification"),
}


def git_work_tree() -> bool:
    if shutil.which("git") is None:
        return False
    done = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--show-toplevel"], capture_output=True, text=True)
    return done.returncode == 0 and Path(done.stdout.strip()).resolve() == ROOT


@pytest.mark.skipif(not git_work_tree(), reason="not a git checkout (or no git): nothing to commit outputs to")
def test_what_documented_commands_write_in_the_checkout_is_ignored():
    for path, (document, command) in OUTPUTS.items():
        assert command in (ROOT / document).read_text(), f"{document} no longer shows {command!r}: what writes {path}?"
    done = subprocess.run(["git", "-C", str(ROOT), "check-ignore", "--no-index", "--verbose", "--non-matching",
                           *OUTPUTS], capture_output=True, text=True)
    committed = [line.split("\t")[-1] for line in done.stdout.splitlines() if line.startswith("::")]
    assert not committed, f"a `git add -A` in the checkout would commit {committed}"
