"""The contact sensor's frames come from a named source, as transports are named: the rig
file's ``contact_sensor.source`` picks it, an unknown one is refused when the file is read,
and the sensor's process loads it by name (the simulated pad, or any module:Class)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from daemon.contact.process import ContactSensor
from hal import config
from hal.errors import ConfigError
from hal.taxel_array import TAXELS, ContactSensorConfig, FrameSource, load_frame_source
from sim_backend.contact_patch import ImpactReplay


class UntouchedPad(FrameSource):
    """Every frame 0.02 V on every taxel: a pad nobody presses (run in the sensor's process)."""

    @classmethod
    def from_config(cls, config):
        return cls()

    def frame(self, k: int) -> np.ndarray:
        return np.full(TAXELS * TAXELS, 0.02)


def test_a_rig_file_naming_an_unknown_source_is_refused_naming_the_key(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text(config.load().source + '\n[contact_sensor]\nsource = "usb-pad"\n')
    with pytest.raises(ConfigError, match=r"contact_sensor\.source: unknown contact sensor source 'usb-pad'"):
        config.load(rig)
    rig.write_text(config.load().source + '\n[contact_sensor]\nsource = "hal.taxel_array:TaxelArray"\n')
    with pytest.raises(ConfigError, match=r"contact_sensor\.source: .* is not a FrameSource"):
        config.load(rig)


def test_the_simulated_pad_is_the_source_named_sim_and_the_default(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_text(config.load().source + "\n[contact_sensor]\nrate_hz = 1000.0\n")
    sensor = config.load(rig).contact_sensor
    assert sensor.source == "sim" and load_frame_source(sensor.source) is ImpactReplay
    source = ImpactReplay.from_config(sensor)
    assert source.frame(0).shape == (TAXELS, TAXELS) and source.rate_hz == 1000.0


def test_the_sensor_process_reads_frames_from_a_source_named_by_module_path():
    sensor = ContactSensor(ContactSensorConfig(source=f"{__name__}:UntouchedPad", rate_hz=500.0,
                                                   open_timeout_s=60.0), time.monotonic)
    sensor.open()
    try:
        end = time.monotonic() + 60.0  # the frames are waited for; the bound only ends a hang
        while (sensor.latest() or {}).get("frames", 0) < 50 and time.monotonic() < end:
            time.sleep(0.02)
        latest = sensor.latest()
        assert latest["frames"] >= 50 and latest["bad_frames"] == 0
        assert latest["contact"] is None and latest["contact_frames"] == 0  # 2 kPa on every taxel: no contact
    finally:
        sensor.close()
