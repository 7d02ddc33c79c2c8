"""Device drivers: the conversions of rig-facts §1 and §5, their clamps and their plausibility
checks; sensor kinds found by name (hal.devices), each read from a sweep through its channels."""
import math

import pytest

from hal import linear_potentiometer
from hal.analog_input import AnalogInput, AnalogInputConfig
from hal.devices import Sensor, kinds, sensor_kind
from hal.directional_valve import DirectionalValve, DirectionalValveConfig
from hal.errors import CommandError
from hal.force_sensor import ASFS, ForceSensorConfig
from hal.linear_potentiometer import LinearPotentiometer, LinearPotentiometerConfig
from hal.potentiometer import RDC506, PotentiometerConfig, two_point_calibration
from hal.pressure_sensor import PressureSensor
from hal.regulator import ITV0051, RegulatorConfig

MPA = 1e6


class TestITV0051:
    reg = ITV0051(RegulatorConfig(channel="ao0"))

    @pytest.mark.parametrize("volts, mpa", [(0.0, 0.001), (4.0, 0.3606), (10.0, 0.9), (5.0, 0.4505)])
    def test_line_2_29(self, volts, mpa):
        assert self.reg.pressure(volts) == pytest.approx(mpa * MPA, rel=1e-9)
        assert self.reg.volts(mpa * MPA) == pytest.approx(volts, abs=1e-9)

    def test_commands_are_clamped_to_the_set_range(self):
        assert self.reg.volts(2.0 * MPA) == 10.0
        assert self.reg.volts(-1.0 * MPA) == 0.0
        assert self.reg.pressure(12.0) == pytest.approx(0.9 * MPA)
        assert self.reg.pressure(-3.0) == pytest.approx(0.001 * MPA)

    @pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
    def test_non_finite_command_is_refused_naming_the_channel(self, bad):
        with pytest.raises(CommandError, match="ao0.*non-finite"):
            self.reg.volts(bad)

    def test_safe_state_default_vents(self):
        assert self.reg.safe_volts == 0.0


class TestRDC506:
    cfg = PotentiometerConfig(channel="ai0", angle_at_zero_deg=0.0)
    pot = RDC506(cfg, math.radians(-150), math.radians(150))

    def test_nominal_ratiometric_reading(self):
        # (V/Vs - 0.5) * 333.3 deg: 3 V of 5 V is +33.33 deg, whatever the supply's exact value
        assert math.degrees(self.pot.convert(3.0, 5.0)) == pytest.approx(33.33, abs=1e-9)
        assert math.degrees(self.pot.convert(3.0 * 4.8 / 5.0, 4.8)) == pytest.approx(33.33, abs=1e-9)

    def test_two_point_calibration_fixes_zero_and_direction(self):
        # a sensor mounted reversed, reading 0.62 at 30 deg and 0.38 at 110 deg
        keys = two_point_calibration(0.62, 30.0, 0.38, 110.0)
        assert keys["direction"] == -1
        pot = RDC506(PotentiometerConfig(channel="ai0", **keys), math.radians(0), math.radians(140))
        assert math.degrees(pot.convert(0.62 * 5, 5.0)) == pytest.approx(30.0)
        assert math.degrees(pot.convert(0.38 * 5, 5.0)) == pytest.approx(110.0)
        assert math.degrees(pot.convert(0.50 * 5, 5.0)) == pytest.approx(70.0)
        assert pot.ratio_for(math.radians(70.0)) == pytest.approx(0.5)

    def test_two_point_calibration_rejects_degenerate_points(self):
        with pytest.raises(ValueError):
            two_point_calibration(0.5, 10.0, 0.5, 20.0)

    @pytest.mark.parametrize("volts, words", [(0.0, "rail"), (5.0, "rail"), (0.04, "rail"), (4.97, "rail")])
    def test_rail_readings_are_faults_not_angles(self, volts, words):
        assert math.isnan(self.pot.convert(volts, 5.0))
        assert words in self.pot.diagnose(volts, 5.0)

    def test_beyond_the_mechanical_range_is_implausible(self):
        pot = RDC506(self.cfg, math.radians(-20), math.radians(20))  # + 15 deg margin
        assert not math.isnan(pot.convert(5.0 * (0.5 + 34 / 333.3), 5.0))
        assert math.isnan(pot.convert(5.0 * (0.5 + 36 / 333.3), 5.0))
        assert "mechanical range" in pot.diagnose(5.0 * (0.5 + 36 / 333.3), 5.0)

    def test_outside_electrical_travel_is_implausible(self):
        pot = RDC506(PotentiometerConfig(channel="ai0", angle_at_zero_deg=0.0, rail_margin=0.005),
                     math.radians(-170), math.radians(170))
        v = 5.0 * (0.5 + 162 / 333.3)  # +162 deg: past the +-160 deg travel, not yet at the rail
        assert math.isnan(pot.convert(v, 5.0))
        assert "electrical travel" in pot.diagnose(v, 5.0)

    def test_implausible_supply(self):
        assert math.isnan(self.pot.convert(1.0, 1.0))
        assert "supply" in self.pot.diagnose(1.0, 1.0)

    def test_valid_reading_has_no_diagnosis(self):
        assert self.pot.diagnose(2.5, 5.0) is None


class TestASFS:
    def test_volts_to_newtons_and_tare(self):
        s = ASFS(ForceSensorConfig(channel="ai7", newtons_per_volt=6.86, offset_volts=0.5))
        assert s.convert(4.5) == pytest.approx(27.44)
        s.tare(0.8)  # 2.058 N of fixture weight
        assert s.convert(0.8) == pytest.approx(0.0)
        assert s.convert(1.8) == pytest.approx(6.86)
        assert s.volts_for(s.raw_force(2.2)) == pytest.approx(2.2)

    def test_over_range_and_below_zero_are_flagged(self):
        s = ASFS(ForceSensorConfig(channel="ai7"))
        assert "over" in s.diagnose(s.volts_for(30.0))
        assert "below zero" in s.diagnose(0.0)
        assert s.diagnose(s.volts_for(10.0)) is None
        with pytest.raises(ValueError, match="implausible"):
            s.tare(0.0)


class TestLinearPotentiometer:
    # a 225 mm track centred on a 200 mm stroke: -12.5 mm at ratio 0 (the built-in axis's)
    cfg = LinearPotentiometerConfig(channel="ai0", mm_per_ratio=225.0, position_at_zero_mm=-12.5)
    pot = LinearPotentiometer(cfg, 0.010, 0.190)  # + 5 mm margin

    def test_ratiometric_reading_in_metres(self):
        assert self.pot.convert(2.5, 5.0) == pytest.approx(0.1)  # mid-track: 100 mm
        assert self.pot.convert(2.5 * 4.8 / 5.0, 4.8) == pytest.approx(0.1)  # whatever the supply's exact value
        assert self.pot.volts_for(0.05, 5.0) == pytest.approx(5.0 * 62.5 / 225.0)
        assert self.pot.convert(self.pot.volts_for(0.17), 5.0) == pytest.approx(0.17)

    def test_two_point_calibration_fixes_zero_and_direction(self):
        keys = linear_potentiometer.two_point_calibration(0.9, 20.0, 0.1, 180.0)  # mounted reversed
        assert keys["direction"] == -1 and keys["mm_per_ratio"] == pytest.approx(200.0)
        pot = LinearPotentiometer(LinearPotentiometerConfig(channel="ai0", **keys), 0.0, 0.2)
        assert pot.convert(0.9 * 5, 5.0) == pytest.approx(0.020) and pot.convert(0.1 * 5, 5.0) == pytest.approx(0.180)
        with pytest.raises(ValueError):
            linear_potentiometer.two_point_calibration(0.5, 10.0, 0.5, 20.0)

    @pytest.mark.parametrize("volts, supply, words", [(0.0, 5.0, "rail"), (5.0, 5.0, "rail"), (0.03, 5.0, "rail"),
                                                      (2.5, 1.0, "supply"), (math.nan, 5.0, "not a number")])
    def test_a_broken_wire_or_supply_is_a_fault_not_a_position(self, volts, supply, words):
        assert math.isnan(self.pot.convert(volts, supply))
        assert words in self.pot.diagnose(volts, supply)

    def test_beyond_the_travel_and_its_margin_is_implausible(self):
        inside, outside = self.pot.volts_for(0.194), self.pot.volts_for(0.196)
        assert self.pot.convert(inside, 5.0) == pytest.approx(0.194) and self.pot.diagnose(inside, 5.0) is None
        assert math.isnan(self.pot.convert(outside, 5.0))
        assert "outside the travel 5.0..195.0 mm" in self.pot.diagnose(outside, 5.0)

    def test_read_from_a_sweep_through_its_signal_and_supply_channels(self):
        pot = LinearPotentiometer(self.cfg, 0.010, 0.190)
        pot.bind(2, 0)
        sweep = (4.8, 9.9, 2.4, 0.0)
        assert pot.read(sweep) == pytest.approx(0.1)
        pot.bind(2)  # no supply channel: the nominal supply_volts
        assert pot.read(sweep) == pytest.approx(-0.0125 + 0.225 * 2.4 / 5.0)
        assert "rail" in pot.fault((0.0, 0.0, 0.0))


class TestAnalogInput:
    cfg = AnalogInputConfig(channel="ai4", unit="K", per_volt=10.0, offset=-27.315, low=263.15, high=373.15)

    def test_a_linear_calibration_in_its_si_unit(self):
        s = AnalogInput(self.cfg)
        assert s.convert(2.0) == pytest.approx(293.15) and s.si_unit == "K"
        assert s.volts_for(313.15) == pytest.approx(4.0)
        assert (s.low, s.high) == (263.15, 373.15)

    def test_outside_its_plausible_range_is_a_fault(self):
        s = AnalogInput(self.cfg)
        assert math.isnan(s.convert(-5.0)) and "outside its plausible 263.15..373.15 K" in s.diagnose(-5.0)
        assert math.isnan(s.convert(math.nan)) and "not a number" in s.diagnose(math.nan)
        assert s.diagnose(3.0) is None


class TestPressureTransmitter:
    def test_a_chamber_transmitters_reading_and_its_range(self):
        s = PressureSensor(sensor_kind("pressure_transmitter").Config(channel="ai1"))
        assert s.convert(3.0) == pytest.approx(0.5e6) and s.diagnose(3.0) is None
        assert (s.low, s.high) == (0.0, 1.0e6) and s.unit == "Pa"
        assert math.isnan(s.convert(0.0)) and "below zero" in s.diagnose(0.0)


class TestDirectionalValve:
    valve = DirectionalValve(DirectionalValveConfig(channel="ao0"))

    def test_the_command_is_volts_about_the_centre_clamped_to_the_valves_span(self):
        assert (self.valve.low, self.valve.high) == (-5.0, 5.0)
        assert self.valve.volts(0.0) == 5.0 and self.valve.volts(1.25) == 6.25 and self.valve.volts(-2.0) == 3.0
        assert self.valve.volts(7.0) == 10.0 and self.valve.volts(-7.0) == 0.0

    @pytest.mark.parametrize("bad", [math.nan, math.inf])
    def test_a_non_finite_command_is_refused_naming_the_channel(self, bad):
        with pytest.raises(CommandError, match="valve ao0: non-finite"):
            self.valve.volts(bad)

    def test_its_safe_state_is_the_closed_centre_unless_the_file_says_otherwise(self):
        assert self.valve.safe_volts == 5.0
        offset = DirectionalValve(DirectionalValveConfig(channel="ao0", centre_volts=4.8, safe_volts=4.79))
        assert offset.safe_volts == 4.79 and (offset.low, offset.high) == pytest.approx((-4.8, 5.2))


class TestSensorKinds:
    def test_the_built_in_kinds_are_found_by_their_entry_points(self):
        assert kinds() == ["analog", "asfs", "linear_potentiometer", "pressure_transmitter", "rdc506"]
        assert sensor_kind("rdc506") is RDC506 and sensor_kind("linear_potentiometer") is LinearPotentiometer
        assert sensor_kind("hal.analog_input:AnalogInput") is AnalogInput  # a module:Class path

    @pytest.mark.parametrize("name, words", [
        ("lvdt9000", "unknown device kind 'lvdt9000' (installed: analog, asfs"),
        ("hal.analog_input:Nothing", "cannot load device kind 'hal.analog_input:Nothing'"),
        ("hal.regulator:ITV0051", "'hal.regulator:ITV0051' is not a Sensor"),
    ])
    def test_an_unknown_kind_or_one_that_is_no_sensor_is_refused(self, name, words):
        with pytest.raises(LookupError) as refused:
            sensor_kind(name)
        assert words in str(refused.value)
        assert issubclass(sensor_kind("asfs"), Sensor)
