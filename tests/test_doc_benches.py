"""Every bench line of the documents (docs/benchmarks.md and the figures elsewhere), run: read
through tests/doc_blocks.py, with the shortest arguments tests/doc_claims.toml declares (the
figures' own runs take minutes to an hour), from a scratch directory with the checkout on
PYTHONPATH (as ``python -m bench.x`` runs in a checkout; the figures and CSV files the lines
write land in the scratch directory's ``docs/``, never the checkout's). Each distinct line runs
once, however many documents show it; each must exit 0 and print its figures."""
from __future__ import annotations

import os
import re

import pytest

from tests import doc_blocks, doc_runs
from tests.doc_blocks import ROOT

BENCH_LINES = r"^(chrt -f \d+ )?python -m bench\.(?!osl_peer)|pneumad latency "
DOCUMENTS = ["docs/benchmarks.md", "docs/controllers.md", "docs/estimation.md", "docs/identification.md",
             "docs/model.md", "docs/muscle-rig.md", "systemd/README.md"]
# a line's wall time on a 2-core machine [s] (half what two 2-core runs beside other work took),
# by what it runs: tests/conftest.py starts the longest first
SECONDS = {"sim_cost": 10, "loop_latency": 15, "cycle_cost": 6, "latency": 4, "controller_cost": 2,
           "switch_load": 30, "transport_cost": 40, "transport_hil": 20, "command_stall": 25, "fuzz": 20,
           "soak": 15, "contact_force": 20, "contact_loop": 15, "compare_controllers": 20, "thesis_corners": 7,
           "robustness": 90, "payload": 2, "identification": 60, "muscle_steps": 20, "axis_control": 20,
           "evaluation_cost": 30, "model_watch": 30}


def chrt(match) -> str:
    """``chrt -f N`` where the suite may ask for real-time scheduling (root), else nothing."""
    return match.group(0) if os.geteuid() == 0 else ""


def distinct_lines() -> list:
    """One param per distinct line as it runs, with every document line it stands for."""
    by_text: dict[str, list[doc_blocks.Command]] = {}
    for doc in DOCUMENTS:
        for command in doc_blocks.commands(doc, None, match=BENCH_LINES, chrt=chrt):
            by_text.setdefault(command.text, []).append(command)
    params = []
    for text, shown in by_text.items():
        what = re.search(r"bench\.(\w+)|pneumad (latency)", text)
        name = what.group(1) or what.group(2)
        where = ",".join(f"{c.item.doc.removeprefix('docs/')}:{c.line}" for c in shown)
        params.append(pytest.param(shown, id=f"{name}@{where}", marks=pytest.mark.slow(seconds=SECONDS[name])))
    return params


@pytest.mark.parametrize("shown", distinct_lines())
def test_a_documents_bench_lines_run(shown, tmp_path):
    (tmp_path / "docs" / "images").mkdir(parents=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    done = doc_runs.run(shown[0], tmp_path, env=env, timeout=600)
    also = "".join(f"\n(also {c.item.doc}:{c.line}: {c.written})" for c in shown[1:])
    assert done.returncode == 0, done.explain() + also
    assert done.stdout.strip(), done.explain() + also  # its figures
