"""The cycle record's layout is built from the interfaces a rig declares: every rig's fields
are named once, group by group in slices the loop writes, and read back from ``describe``."""
import math
import re
from pathlib import Path

import pytest

from daemon.wire.cycle_layout import MODES, CycleLayout
from hal import config
from hal.declare import declare
from hal.interfaces import LINEAR, ROTARY, CommandInterface, JointInterfaces, RigInterfaces, StateInterface


def layout_of(name: str) -> CycleLayout:
    """A built-in rig's layout (its outputs in every built-in transport's order)."""
    rig = config.load(name)
    return CycleLayout.of(declare(rig, [c for j in rig.joints for _, c in j.output_channels()]))


@pytest.mark.parametrize("name", ["sim", "sim-3joint", "sim-muscle"])
def test_each_built_in_rigs_layout_names_every_joints_state_reference_and_commands(name):
    rig = config.load(name)
    layout = layout_of(name)
    for j in rig.joints:
        for quantity in ("position", "velocity", "setpoint", "error"):
            assert f"{j.name}.{quantity}" in layout
        assert layout[f"{j.name}.position"].unit == "rad" and layout[f"{j.name}.position"].display == ("deg", 180 / math.pi)
    for group in ("command", "commanded", "output", "shadow"):
        start, stop = layout.span(group)
        assert stop > start
    assert [f.index for f in layout.fields] == list(range(layout.width))
    assert layout.names[:2] == ("cycle", "t") and layout.names[-1] == "mode"


def test_measured_and_commanded_pressures_have_distinct_names():
    muscle = layout_of("sim-muscle")
    assert muscle["elbow.p_a"].group == "measured" and muscle["elbow.p_a_cmd"].group == "commanded"
    assert muscle["elbow.u.pressure_a"].group == "command"
    assert "bottom.p_head" not in layout_of("sim")  # no transmitter wired on the built-in arm: nothing claims one


def test_a_layout_read_back_from_describe_is_the_same_and_decodes_a_batch():
    layout = layout_of("sim")
    again = CycleLayout.from_describe(layout.describe())
    assert again.names == layout.names and again.id == layout.id and again.row.format == layout.row.format
    record = layout.record()
    record[layout["cycle"].index], record[layout["t"].index] = 7.0, 0.007
    record[layout["mode"].index] = float(MODES.index("enabled"))
    cols = again.columns([record])
    assert cols["cycle"] == [7] and cols["mode"] == ["enabled"] and math.isnan(cols["bottom.position"][0])


@pytest.mark.parametrize("bad", ["out", "mode", "t", "a.b", "force"])
def test_a_joint_named_as_a_record_field_is_refused(bad):
    joint = JointInterfaces(bad, ROTARY, "cylinder", ("head", "rod"),
                            (StateInterface(bad, "position", "rad"), StateInterface(bad, "velocity", "rad/s")),
                            (CommandInterface(bad, "v_mv", "V", -4, 6),), ("head", "rod"))
    with pytest.raises(ValueError, match="may not"):
        CycleLayout.of(RigInterfaces((joint,), (StateInterface("", "force", "N"),), ("ao0",)))


DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"


def documented_fields() -> list[tuple[str, re.Pattern, set[str] | None, str]]:
    """docs/protocol.md's cycle-record table: (pattern, its regex, units (None: any), group)."""
    text = DOC.read_text()
    table = text[text.index("\n", text.index("<!-- cycle-record:begin")) + 1:text.index("<!-- cycle-record:end -->")]
    rows = []
    for line in table.strip().splitlines()[2:]:
        pattern, unit, group = (c.strip().strip("`") for c in line.strip().strip("|").split("|")[:3])
        regex = re.compile("^" + re.sub(r"<\w+>", "[^.]+", re.escape(pattern).replace(r"\<", "<").replace(r"\>", ">"))
                           + "$")
        rows.append((pattern, regex, None if unit == "any" else {u.strip() for u in unit.split(",")}, group))
    return rows


def rig_with_inputs() -> RigInterfaces:
    """A joint with a further input of its own and a rig-level one (no built-in rig has both)."""
    joint = JointInterfaces("slide", LINEAR, "cylinder", ("head", "rod"),
                            (StateInterface("slide", "position", "m"), StateInterface("slide", "velocity", "m/s"),
                             StateInterface("slide", "p_head", "Pa"), StateInterface("slide", "temperature", "K")),
                            (CommandInterface("slide", "v_mv", "V", -4, 6),), ("head", "rod"))
    return RigInterfaces((joint,), (StateInterface("", "supply_pressure", "Pa"), StateInterface("", "humidity", "%")),
                         ("ao0", "ao1"))


def test_the_protocol_documents_cycle_record_table_names_every_field_of_every_rig():
    """Each field of each built-in rig's layout (and of a rig with further inputs) matches one
    row of the table (a literal name first, then the patterns with the fewest placeholders, in
    the table's order), with that row's group and one of its units; every row is some rig's."""
    rows = sorted(documented_fields(), key=lambda r: r[0].count("<"))
    used = set()
    layouts = [layout_of(name) for name in ("sim", "sim-3joint", "sim-muscle", "sim-axis")]
    layouts.append(CycleLayout.of(rig_with_inputs()))
    for layout in layouts:
        for f in layout.fields:
            row = next((r for r in rows if r[0] == f.name), None) or next((r for r in rows if r[1].match(f.name)), None)
            assert row is not None, f"{f.name}: not in docs/protocol.md's cycle-record table"
            pattern, _, units, group = row
            assert f.group == group, (f.name, pattern, f.group, group)
            assert units is None or f.unit in units, (f.name, pattern, f.unit, units)
            used.add(pattern)
    assert used == {r[0] for r in rows}, {r[0] for r in rows} - used


def test_the_loop_refuses_a_layout_it_cannot_write_in_record_order():
    """The loop writes its record group by group (daemon/loop/record.py): a layout whose groups
    are out of that order, or of another size than the loop's lists, is refused before it runs."""
    from dataclasses import replace

    from daemon.loop.record import RecordSpans
    layout = layout_of("sim")
    args = (["bottom", "middle"], ["bottom.v_mv", "middle.v_mv"], [0, 1], ["force"], ["ao0", "ao1", "ao2", "ao3"])
    spans = RecordSpans.of(layout, *args)
    assert spans.pressure_joints is None and (spans.mode, spans.position) == (layout.width - 1, slice(2, 4))
    shuffled = [*layout.fields[:2], layout.fields[3], layout.fields[2], *layout.fields[4:]]  # middle before bottom
    moved = [*layout.fields[:2], *layout.fields[4:6], *layout.fields[2:4], *layout.fields[6:]]  # velocity first
    with pytest.raises(ValueError, match=r"holds \['middle', 'bottom'\], the loop writes \['bottom', 'middle'\]"):
        RecordSpans.of(CycleLayout([replace(f, index=i) for i, f in enumerate(shuffled)]), *args)
    with pytest.raises(ValueError, match="not in the order"):
        RecordSpans.of(CycleLayout([replace(f, index=i) for i, f in enumerate(moved)]), *args)
    with pytest.raises(ValueError, match="the snapshot measures"):
        RecordSpans.of(layout, *args[:3], ["force", "supply_pressure"], args[4])
