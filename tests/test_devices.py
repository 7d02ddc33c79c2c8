"""Device drivers: the conversions of rig-facts §1, their clamps and their plausibility checks."""
import math

import pytest

from hal.errors import CommandError
from hal.force_sensor import ASFS, ForceSensorConfig
from hal.potentiometer import RDC506, PotentiometerConfig, two_point_calibration
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
