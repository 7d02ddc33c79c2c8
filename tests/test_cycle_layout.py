"""The cycle record's layout is built from the interfaces a rig declares: every rig's fields
are named once, group by group in slices the loop writes, and read back from ``describe``."""
import math

import pytest

from daemon.wire.cycle_layout import MODES, CycleLayout
from hal import config
from hal.declare import declare
from hal.interfaces import ROTARY, CommandInterface, JointInterfaces, RigInterfaces, StateInterface


def layout_of(name: str) -> CycleLayout:
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
