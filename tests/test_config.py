"""Rig configuration: the built-in rigs load; every kind of mistake names its key, before anything moves."""
import pytest

from hal import config
from hal.errors import ConfigError
from hal.rig import RigIO
from hal.transport import create_transport
from daemon.testing.drift import axis_rig, drifted_rig
from daemon.testing.simrig import make_rig, sim_of

BASE = config.load("sim").source


def parse_with(old: str, new: str):
    assert old in BASE, old
    return config.parse(BASE.replace(old, new, 1))


def test_builtin_rigs_load():
    two = config.load()
    assert [j.name for j in two.joints] == ["bottom", "middle"]
    three = config.load("sim-3joint")
    assert [j.name for j in three.joints] == ["bottom", "middle", "top"]
    assert two.origin == "builtin:sim" and len(two.hash) == 64


def test_file_round_trip(tmp_path):
    path = tmp_path / "rig.toml"
    path.write_text(BASE)
    assert config.load(path) == config.load()


@pytest.mark.parametrize("old, new, message", [
    ('channel = "ai0"', 'chanel = "ai0"', r"joints\[0\]\.sensor\.chanel: unknown key"),
    ("[arm]", "[arms]", r"arms: unknown key"),
    ('min_angle_deg = 85.0', '', r"joints\[0\]\.min_angle_deg: missing required key"),
    ('min_angle_deg = 85.0', 'min_angle_deg = "85"', r"joints\[0\]\.min_angle_deg: expected a number"),
    ('min_angle_deg = 85.0', 'min_angle_deg = 180.0', r"joints\[0\]\.max_angle_deg: limits inverted"),
    ('newtons_per_volt = 6.86', 'newtons_per_volt = 0.0', r"force_sensor\.newtons_per_volt: must not be zero"),
    ('deg_per_ratio = 333.3', 'deg_per_ratio = 0.0', r"joints\[0\]\.sensor\.deg_per_ratio: must be > 0"),
    ('direction = 1', 'direction = 2', r"joints\[0\]\.sensor\.direction: must be \+1 or -1"),
    ('channel = "ao2"', 'channel = "ao0"', r"joints\.middle\.head\.channel: channel 'ao0' is already mapped"),
    ('channel = "ai1"', 'channel = "ai0"', r"joints\.middle\.sensor\.channel: channel 'ai0' is already mapped"),
    ('channel = "ai7"', 'channel = "ai6"', r"both a supply and a signal"),
    ('safe_mpa = 0.001          # 0 V: vent', 'safe_mpa = 1.5', r"joints\[0\]\.head\.safe_mpa: must be within"),
    ('max_pressure_mpa = 0.9', 'max_pressure_mpa = 0.0001', r"safe_mpa.*exceeds limits\.max_pressure_mpa"),
    ('max_pressure_mpa = 0.9', 'max_pressure_mpa = nan', r"limits\.max_pressure_mpa: must be finite"),
    ('max_pressure_mpa = 0.9', 'max_pressure_mpa = 0.3',  # the 4 V bias is 0.361 MPa: V_MV could not be 0
     r"joints\[0\]\.head\.bias_volts: 4\.0 V is 0\.361 MPa, not below limits\.max_pressure_mpa 0\.3"),
    ('elbow = -1 ', 'elbow = 0 ', r"arm\.elbow: must be \+1 or -1"),
    ('link_lengths_mm = [150.0, 150.0]', 'link_lengths_mm = [150.0]', r"1 links given for 2 joints"),
    ('bias_volts = 4.0\nsafe_mpa = 0.001          # 0 V', 'bias_volts = 11.0\nsafe_mpa = 0.001 # 0 V',
     r"joints\[0\]\.head\.bias_volts: must be within 0.0-10.0 V"),
])
def test_bad_config_names_the_key(old, new, message):
    with pytest.raises(ConfigError, match=message):
        parse_with(old, new)


@pytest.mark.parametrize("line, message", [
    ("memory_ms = 0.0", r"contact_sensor\.memory_ms: must be within \(0, 1000\] ms"),
    ("beta_memory_ms = 2000.0", r"contact_sensor\.beta_memory_ms: must be within \(0, 1000\] ms"),
    ("rate_hz = 40000.0", r"contact_sensor\.rate_hz: must be within 100-10000 Hz"),
])
def test_bad_contact_sensor_settings_name_the_key(line, message):
    assert config.parse(BASE + "\n[contact_sensor]\n").contact_sensor is not None
    with pytest.raises(ConfigError, match=message):
        config.parse(BASE + f"\n[contact_sensor]\n{line}\n")


def test_duplicate_joint_name():
    with pytest.raises(ConfigError, match="joint name 'bottom' is used twice"):
        parse_with('name = "middle"', 'name = "bottom"')


def test_invalid_toml_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not valid TOML"):
        config.parse("[rig\nname=1")
    with pytest.raises(ConfigError, match="cannot read rig file"):
        config.load(tmp_path / "absent.toml")


def test_unknown_backend_is_refused():
    rig = parse_with('backend = "sim"', 'backend = "warp-drive"')
    with pytest.raises(ConfigError, match="unknown backend 'warp-drive'"):
        create_transport(rig, lambda: 0.0)


@pytest.mark.parametrize("options, message", [
    ("sead = 3", r"transport\.options\.sead: unknown key"),
    ("step_s = 0.5", r"transport\.options\.step_s: must be within"),
    ("[transport.options.joints.elbow]\nmodel = 'bottom'", r"joints\.elbow: no joint of that name"),
    ("[transport.options.joints.bottom]\nmodel = 'knee'", r"joints\.bottom\.model: no identified model 'knee'"),
    ("[transport.options.joints.bottom]\noverrides = {Jay = 1.0}", r"unknown joint parameter 'Jay'"),
    ("[transport.options.joints.bottom]\noverrides = {J = -1.0}", r"J must be finite and >= 0"),
])
def test_bad_sim_options_name_the_key(options, message):
    with pytest.raises(ConfigError, match=message):
        make_rig(options.replace("[transport.options.joints", "\n[transport.options.joints"))


@pytest.mark.parametrize("rig, drift, message", [
    ("sim", "sensor_offset_mm = 2.0", r"joints\.bottom\.sensor_offset_mm: a linear joint's option; bottom is a rotary"),
    ("sim", "initial_position_mm = 100.0", r"joints\.bottom\.initial_position_mm: a linear joint's option"),
    ("sim-axis", "sensor_offset_deg = 2.0", r"joints\.axis\.sensor_offset_deg: a rotary joint's option; axis is a linear"),
    ("sim-axis", 'leak = "head"', r"joints\.axis\.leak: a rotary joint's option"),
    ("sim-axis", "friction_scale = 1.5", r"joints\.axis\.friction_scale: a rotary joint's option"),
])
def test_a_drift_the_joints_kind_has_no_use_for_is_refused_not_ignored(rig, drift, message):
    """A drift that would do nothing (a linear axis's sensor offset in mm on a rotary joint, or a
    rotary joint's on the axis) is refused with the key, where it was silently accepted."""
    text = axis_rig(drift, 1.0) if rig == "sim-axis" else drifted_rig(drift, "bottom", 1.0)
    with pytest.raises(ConfigError, match=message):
        sim_of(config.parse(text))


def test_mapping_checked_against_the_transports_channels():
    sim = make_rig()
    other = parse_with('channel = "ai7"', 'channel = "ai5"')
    with pytest.raises(ConfigError, match="no input channel named 'ai5'"):
        RigIO(other, sim.transport)


def test_a_command_line_transport_keeps_the_rig_and_changes_its_hash():
    rig = config.load()
    wired = config.with_transport(rig, "serial", dict(map(config.parse_option, ["port=/dev/ttyACM0", "baudrate=115200"])))
    assert wired.transport.backend == "serial"
    assert wired.transport.options == {"port": "/dev/ttyACM0", "baudrate": 115200}
    assert wired.joints == rig.joints and wired.hash != rig.hash


@pytest.mark.parametrize("text", ["port", "=x", ""])
def test_a_transport_option_without_a_key_and_value_is_refused(text):
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        config.parse_option(text)


@pytest.mark.parametrize("section, cut, message", [
    ("transport", 'backend = "sim"', r"transport\.backend: missing: a rig file must name its transport backend"),
    ("safety", "[safety]", r"\[safety\]: missing: a rig file must state it"),
    ("arm", "[arm]", r"\[arm\]: missing: a rig file must state it"),
    ("limits", "[limits]", r"\[limits\]: missing: a rig file must state it \(only the built-in rigs have defaults; "
                           r"copy \[limits\] from hal/sim_2joint\.toml and set its max_pressure_mpa, "
                           r"max_pressure_rate_mpa_s, authority_fraction for this rig\)"),
])
def test_a_rig_file_states_its_transport_safety_arm_and_limits_itself(tmp_path, section, cut, message):
    """Defaults are the built-in rigs' alone: a real rig's file that left out its backend would
    otherwise run the simulator and show a moving arm that is not there, and one that left out
    its [limits] would run with the simulator's pressure limits, said nowhere."""
    text = BASE
    if cut.startswith("["):  # drop the whole table, up to the next one
        start = text.index(cut)
        end = text.find("\n[", start + 1)
        text = text[:start] + (text[end + 1:] if end >= 0 else "")
    else:
        text = text.replace(cut, "", 1)
    path = tmp_path / "rig.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        config.load(path)
    assert config.load("sim").transport.backend == "sim"  # the built-in keeps its defaults
