"""The command catalog (daemon/wire/catalog.py) is the one place a command is declared:
the documents and schemas generated from it are up to date, the handlers of every process
match it, and its argument check refuses what docs/protocol.md says it refuses, with data."""
import ast
import json
from pathlib import Path

import jsonschema
import pytest

from daemon.client import ctl
from daemon.loop.commands import Commands
from daemon.wire import catalog, catalog_docs
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed
from daemon.wire.command_spec import check_args
from tests.schemas import schema

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def test_the_args_schema_and_the_protocol_documents_summary_are_generated_from_the_catalog():
    """Regenerated and compared: a command changed in the catalog and not in the documents fails."""
    assert json.loads((DOCS / "schemas" / "args.schema.json").read_text()) == catalog_docs.args_schema(), \
        "regenerate docs/schemas/args.schema.json from daemon.wire.catalog_docs.args_schema()"
    text = (DOCS / "protocol.md").read_text()
    begin = text.index("\n", text.index("<!-- catalog:begin")) + 1
    assert text[begin:text.index("<!-- catalog:end -->")].strip() == catalog_docs.summary_table(), \
        "regenerate docs/protocol.md's catalog summary from daemon.wire.catalog_docs.summary_table()"


def test_the_protocol_documents_tables_and_the_results_schema_follow_the_catalog():
    """The hand-written command table lists exactly the catalog's commands with their lease,
    every argument the catalog declares is named in its row, and results.schema.json defines
    exactly the keys the catalog says each result has."""
    text = (DOCS / "protocol.md").read_text()
    table = text.split("## Commands", 1)[1].split("\n\n", 2)[1]
    cells = [[c.strip() for c in line.strip().strip("|").split("|")] for line in table.splitlines()[2:]]
    documented = {row[0].strip("`"): row for row in cells}
    assert set(documented) == set(catalog.COMMANDS)
    for name, row in documented.items():
        command = catalog.COMMANDS[name]
        assert (row[1] == "yes") == command.lease, name
        for arg in command.args:
            if arg.name != "record":  # the motion commands' record: one paragraph below the table says it
                assert f"`{arg.name}`" in row[2], (name, arg.name)
    results = json.loads((DOCS / "schemas" / "results.schema.json").read_text())["$defs"]
    assert set(results) == set(catalog.COMMANDS)
    for name, command in catalog.COMMANDS.items():
        assert set(results[name]["properties"]) == set(command.result), name


def test_the_catalogs_error_codes_are_the_protocols():
    """(docs/protocol.md's table of codes is checked in tests/test_protocol.py.)"""
    for command in catalog.COMMANDS.values():
        assert set(command.error_codes) <= set(P.ERROR_CODES), command.name
    assert P.NO_LEASE in catalog.COMMANDS["set"].error_codes and P.BAD_ARGS not in catalog.COMMANDS["estop"].error_codes


def test_start_up_fails_when_a_handler_and_the_catalog_disagree():
    catalog.check_handlers(("loop", "planner"), Commands.HANDLERS)  # what the loop registers
    loop_side = dict(Commands.HANDLERS)
    del loop_side["ping"]
    with pytest.raises(RuntimeError, match=r"no handler for \['ping'\]"):
        catalog.check_handlers(("loop", "planner"), loop_side)
    with pytest.raises(RuntimeError, match=r"no catalog entry for \['record.erase'\]"):
        catalog.check_handlers(("recorder",), ("record.start", "record.stop", "record.list", "record.erase"))


def refusal(command: str, args: dict) -> CommandFailed:
    with pytest.raises(CommandFailed) as caught:
        check_args(catalog.COMMANDS[command], args)
    assert caught.value.code == P.BAD_ARGS
    schema("error-data").validate(caught.value.data)
    return caught.value


@pytest.mark.parametrize("name", sorted(catalog.COMMANDS))
def test_an_unknown_argument_is_refused_naming_it_for_every_command_but_estop(name):
    command = catalog.COMMANDS[name]
    if not command.strict:
        check_args(command, {"speed": 3, "who": {"not": "a string"}})
        return
    assert refusal(name, {"speed": 3}).data == {"argument": "speed"}


def test_bad_values_are_refused_with_the_argument_its_bounds_and_the_element_at_fault():
    assert refusal("lease.acquire", {"ttl_s": 100}).data == {"argument": "ttl_s", "low": 0.1, "high": 60.0}
    assert refusal("set", {"angles_deg": [1, 2], "duration_s": "slow"}).data == {"argument": "duration_s",
                                                                                 "expected": "number"}
    assert refusal("set", {"angles_deg": [1, 2], "stiffness_nm_deg": [1, 11]}).data == {
        "argument": "stiffness_nm_deg", "index": [1], "low": 0.0, "high": 10.0}
    assert refusal("path", {"name": "spiral"}).data == {"argument": "name", "allowed": ["translation", "circle"]}
    assert refusal("path", {}).data == {"argument": "name"}  # required
    assert refusal("load.set", {"mass_kg": 1.0, "com_mm": [1.0]}).data == {"argument": "com_mm", "low": 2, "high": 2}
    assert refusal("load.set", {"mass_kg": 1.0, "com_mm": [1.0, ""]}).data == {  # found by tests/test_fuzz.py
        "argument": "com_mm", "index": [1], "expected": "number"}
    assert refusal("controller.set", {"params": [1]}).data == {"argument": "params", "expected": "map"}
    assert refusal("record.start", {"seconds": 0}).data == {"argument": "seconds", "low": 0.001, "high": 86400.0}


def test_the_error_data_schema_accepts_no_key_it_does_not_name():
    data = schema("error-data")
    data.validate({"reason": "limits", "argument": "amplitude_deg", "joint": "bottom", "angle_deg": 160.0,
                   "limits_deg": [85.0, 155.0]})
    for extra in ({"reason": "limits", "joint": "bottom", "speed": 1.0}, {"argument": "hold_s", "row": 2},
                  {"reason": "authority", "shortest_s": None, "shortfalls": []}):  # the last: no shortest_for
        with pytest.raises(jsonschema.ValidationError):
            data.validate(extra)
    doc = json.loads((DOCS / "schemas" / "error-data.schema.json").read_text())
    assert all(branch["additionalProperties"] is False for branch in doc["anyOf"])


def test_unknown_command_messages_list_what_the_socket_serves():
    with pytest.raises(CommandFailed) as caught:
        catalog.find("fly", "command")
    assert caught.value.message.endswith(f"serves: {', '.join(sorted(catalog.COMMANDS))})")
    with pytest.raises(CommandFailed) as caught:
        catalog.find("record.stop", "control")
    assert "serves: abort, disable, estop, ping, status)" in caught.value.message
    assert catalog.served_on("control") == ("abort", "disable", "estop", "ping", "status")


def test_pneumactls_help_comes_from_the_catalog():
    sub = next(a for a in ctl.parser()._actions if a.dest == "what").choices
    helps = {a.dest: a.help for a in sub["excite"]._actions}
    assert helps["period"] == catalog.COMMANDS["excite"].arg("period_s").help()
    assert "1..600" in helps["period"] and "[s]" in helps["period"]
    helps = {a.dest: a.help for a in sub["set"]._actions}
    assert helps["stiffness"] == catalog.COMMANDS["set"].arg("stiffness_nm_deg").help()
    assert "0..10" in helps["stiffness"]


def test_the_excitation_planner_does_not_import_the_motion_planner():
    """planner.commands imports planner.excitation; what both use lives in planner.plans."""
    tree = ast.parse((ROOT / "daemon" / "planner" / "excitation.py").read_text())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)} | {
        a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert "daemon.planner.commands" not in imported and not any("planner.commands" in m for m in imported if m)


def test_the_key_files_server_key_field_is_the_one_the_document_names(tmp_path):
    """docs/protocol.md, "Keys": a client's key file carries the daemon's public key in its
    metadata's ``server-key`` field, which zmq.auth.load_certificate does not return."""
    import zmq.auth

    from daemon.wire import keys

    daemon_dir, out = tmp_path / "daemon", tmp_path / "out"
    daemon_dir.mkdir()
    out.mkdir()
    server_public, _ = keys.init_server(str(daemon_dir))
    secret_file = keys.make_client(str(daemon_dir), "alice", "operator", str(out))
    expected = zmq.auth.load_certificate(server_public)[0]
    assert keys.read_metadata(secret_file)["server-key"].encode() == expected
    assert expected not in zmq.auth.load_certificate(secret_file)
    assert "the `server-key` field of the file's `metadata` section" in (DOCS / "protocol.md").read_text()


def test_an_observer_may_read_and_list_but_not_record_reload_or_take_the_lease():
    """The roles the document states (Keys) are the catalog's; the messenger refuses by them
    (tests/test_security.py sends them with an observer's key)."""
    operators = {name for name, c in catalog.COMMANDS.items() if c.role == "operator"}
    assert operators == {"lease.acquire", "record.start", "record.stop", "record.snapshot", "keys.reload",
                         "controller.reload"}
    row = next(line for line in (DOCS / "protocol.md").read_text().splitlines() if "--role observer" in line)
    assert "lists the daemon's recordings" in row and "never takes the lease, starts or stops" in row
