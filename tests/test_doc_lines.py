"""Every shell line and Python snippet of README.md, docs/*.md and systemd/README.md is run by a
test that reads it from the document, or listed with the reason it cannot run here
(tests/doc_claims.toml; tests/doc_blocks.py says how to add to it); the TOML and JSON the
documents show parse, and a rig file's tables pass the rig file's checks."""
from __future__ import annotations

import ast
import json
import re
import tomllib
from pathlib import Path

import pytest

from tests import doc_blocks
from tests.doc_blocks import ROOT

CLAIMS = doc_blocks.load_claims()


def test_every_shell_line_and_snippet_is_run_by_a_test_or_listed_with_its_reason():
    result = doc_blocks.account(doc_blocks.all_items(), CLAIMS)
    assert not result.problems, "\n".join(result.problems)
    assert len(result.run) > 100 and len(result.listed) > 10  # what the documents hold today, roughly


def reads_through_doc_blocks(claim: dict) -> str | None:
    """What is wrong with a [[run]] claim's test, or None: the file and the test function
    exist, the file imports tests/doc_blocks.py and names the claim's document and section."""
    file, _, function = claim["test"].partition("::")
    path = ROOT / file
    if not path.exists():
        return f"{file} does not exist"
    tree = ast.parse(path.read_text())
    names = {node.name for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))}
    if function not in names:
        return f"{file} has no function {function}"
    imports = [node for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))]
    if not any("doc_blocks" in ast.unparse(node) for node in imports):
        return f"{file} does not import tests/doc_blocks.py (a test reads the document through it, never a copy)"
    strings = {node.value for node in ast.walk(tree) if isinstance(node, ast.Constant) and isinstance(node.value, str)}
    for key in ("doc", "section"):
        if key in claim and claim[key] not in strings:
            return f"{file} never names {key} {claim[key]!r}: it does not read what it claims"
    return None


def claim_params():
    for k, claim in enumerate(CLAIMS["run"]):
        label = f"{k + 1}:{claim.get('doc', '*')}:{claim.get('section', '')}"[:80]
        marks = [pytest.mark.xfail(strict=True, reason=claim["awaiting"])] if "awaiting" in claim else []
        yield pytest.param(claim, id=label, marks=marks)


@pytest.mark.parametrize("claim", list(claim_params()))
def test_a_claiming_test_exists_and_reads_its_section_through_doc_blocks(claim):
    """(A claim ``awaiting`` a test from another branch fails here until it is merged and reads
    through tests/doc_blocks.py; then this test's strict xfail fails: remove ``awaiting``.)"""
    wrong = reads_through_doc_blocks(claim)
    assert wrong is None, f"tests/doc_claims.toml: [[run]] {claim}: {wrong}"


def test_a_line_neither_run_nor_listed_fails_naming_the_document_line_and_text():
    text = "# Title\n\n## Use\n\n    pneumactl status\n    pneumactl frobnicate --now   # new\n\nProse.\n"
    found = doc_blocks.items("docs/x.md", text)
    claims = {"run": [{"doc": "docs/x.md", "section": "Use", "lines": "status", "test": "tests/t.py::test_t"}],
              "cannot": [], "substitute": []}
    problems = doc_blocks.account(found, claims).problems
    assert len(problems) == 1
    assert problems[0].startswith("docs/x.md:6 (Use): pneumactl frobnicate --now: run by no test")
    assert "[[run]]" in problems[0] and "[[cannot]]" in problems[0]
    claims["cannot"].append({"doc": "docs/x.md", "lines": "frobnicate", "reason": "it needs the real arm"})
    assert doc_blocks.account(found, claims).problems == []
    claims["cannot"].append({"doc": "docs/x.md", "section": "Gone", "reason": "a section since removed"})
    stale, = doc_blocks.account(found, claims).problems
    assert "matches no line" in stale


def test_blocks_are_classified_and_commands_read_as_a_shell_would():
    text = "\n".join([
        "# Doc", "", "## Fenced", "", "```", "$ python -m bench.x --seconds 2   # a comment", "output line 1",
        "cyclictest latency us : p50 1", "```", "", "```", "# a bench's own output", "command: python -m bench.y",
        "pneumad row : 1", "```", "", "## Indented", "",
        "    .venv/bin/pneumad --no-rt --transport can \\", "        --transport-option channel=x   # joined",
        "    python -m bench.z --cycles 5     (vm x86_64 2 cpus,", "                                       noted)",
        "    pneumad WARNING: SCHED_FIFO not permitted", "    T(t) = K L (A dP)", "", "Prose (a blank line alone",
        "would continue the block).", "", "    from daemon import recordings", "    data = recordings.load('x.mcap')",
        "", "Prose.", "", "    [transport]", "    backend = \"can\"", "", "Prose.", "", "    {\"a\": [1, 2]}", "",
        "Prose.", "", "    PNEUMAD_X=/etc/y start-re-manager --opt '#not a comment'", ""])
    kinds = [(b.line, b.kind) for b in doc_blocks.blocks("docs/x.md", text)]
    assert kinds == [(6, "lines"), (12, "lines"), (19, "lines"), (29, "python"), (34, "toml"), (39, "json"),
                     (43, "lines")]
    found = [(i.line, i.section, i.kind, i.written) for i in doc_blocks.items("docs/x.md", text)]
    assert found == [
        (6, "Fenced", "shell", "python -m bench.x --seconds 2"),
        (13, "Fenced", "shell", "python -m bench.y"),
        (19, "Indented", "shell", ".venv/bin/pneumad --no-rt --transport can --transport-option channel=x"),
        (21, "Indented", "shell", "python -m bench.z --cycles 5"),
        (29, "Indented", "python", "from daemon import recordings\ndata = recordings.load('x.mcap')"),
        (43, "Indented", "shell", "PNEUMAD_X=/etc/y start-re-manager --opt '#not a comment'")]


def test_substitutions_are_made_as_declared_and_a_missing_value_is_named():
    item, = doc_blocks.items("docs/x.md", "## S\n\n    .venv/bin/pneumad --port 5020 --x 5020\n")
    subs = [{"pattern": r"^\.venv/bin/", "with": "{bin}", "reason": "r1"},
            {"pattern": r"(--port )5020", "with": "{m1}{port}", "reason": "r2"},
            {"lines": "--x", "pattern": "$", "with": " --y", "interrupt_after": "ready", "reason": "r3"},
            {"lines": "nothing here", "pattern": "$", "with": " --z", "reason": "r4"}]
    command = doc_blocks.substituted(item, subs, {"port": lambda m: "6000"})
    assert command.text == f"{doc_blocks.BIN}pneumad --port 6000 --x 5020 --y"
    assert command.reasons == ("r1", "r2", "r3") and command.interrupt_after == "ready"
    with pytest.raises(KeyError, match=r"pass port=\.\.\. to doc_blocks\.commands"):
        doc_blocks.substituted(item, subs, {})


def test_reading_lines_no_claim_gives_to_the_calling_file_is_refused():
    with pytest.raises(LookupError, match=r"README\.md:\d+ \(A short tour\): .*does not claim it: add a \[\[run\]\]"):
        doc_blocks.commands("README.md", "A short tour")


# ---- the data the documents show ------------------------------------------------------------------

def rig_with(fragment: str) -> str:
    """The built-in rig's text with ``fragment``'s tables in place of its own of the same names."""
    names = set(tomllib.loads(fragment))
    kept, keep = [], True
    for line in (ROOT / "hal" / "sim_2joint.toml").read_text().splitlines():
        header = re.match(r"^\[\[?([\w-]+)", line)
        if header:
            keep = header.group(1) not in names
        if keep:
            kept.append(line)
    return "\n".join(kept) + "\n" + fragment


def data_blocks(kind: str):
    for doc in doc_blocks.documents():
        for block in doc_blocks.blocks(doc):
            if block.kind == kind:
                yield pytest.param(block, id=f"{doc}:{block.line}")


RIG_TABLES = {"transport", "contact_sensor", "safety", "timing", "flight_recorder", "limits", "arm", "force_sensor",
              "models", "rig", "model_watch"}


@pytest.mark.parametrize("block", list(data_blocks("toml")))
def test_every_toml_block_parses_and_a_rig_files_tables_pass_its_checks(block, tmp_path, capsys, caplog):
    from controllers import lti_design
    from daemon.main import main
    data = tomllib.loads(block.text)  # a TOMLDecodeError names the line
    if set(data) <= RIG_TABLES:
        path = tmp_path / "rig.toml"
        path.write_text(rig_with(block.text))
        code, said = main(["--check", "--config", str(path)]), capsys.readouterr()
        assert code == 0 and "rig 'sim-2joint'" in said.out, f"{block.doc}:{block.line}: {caplog.text}{said.err}"
    elif set(data) == {"project"} and set(data["project"]) == {"entry-points"}:  # a plugin's pyproject.toml
        groups = data["project"]["entry-points"]
        assert set(groups) <= {"pneumad.devices", "pneumad.transports", "pneumad.controllers"}, (block.line, groups)
        assert all(re.fullmatch(r"[\w.]+:\w+", v) for g in groups.values() for v in g.values()), (block.line, groups)
    elif set(data) == {"joints"} and all(isinstance(v, dict) for v in data["joints"].values()):
        designs = lti_design.parse(data, tuple(data["joints"]), 0.001)  # an LTI design (docs/controllers.md)
        assert len(designs) == len(data["joints"])
    else:
        pytest.fail(f"{block.doc}:{block.line}: TOML that is neither a rig file's tables nor an LTI design: "
                    f"say here how to check it")


@pytest.mark.parametrize("block", list(data_blocks("json")))
def test_every_json_block_parses(block):
    assert json.loads(block.text) is not None


def test_the_documents_and_their_blocks_are_found():
    docs = doc_blocks.documents()
    assert {"README.md", "docs/protocol.md", "systemd/README.md"} <= set(docs)
    assert all((ROOT / d).exists() for d in docs)
    assert Path(doc_blocks.CLAIMS).exists()
