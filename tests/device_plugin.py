"""A sensor kind from outside pneumad's tree, installed as a lab installs its own: a package of
one module whose metadata registers the kind under the entry-point group ``pneumad.devices``,
made as a wheel under the test's directory and installed by pip (no network, no build backend:
a wheel is what a package's build makes) into a directory the test puts on the path
(``sys.path`` in the test's process, ``PYTHONPATH`` for a daemon's).

The kind, ``ad8495`` (docs/rigs.md, "Add a device kind", shows the same module): a type K thermocouple through an Analog Devices AD8495 amplifier, whose
output is 1.25 V + 5 mV/degC (its datasheet's reference-junction-compensated transfer), read in
K. ``broken=True`` makes a package whose module fails to import (an ImportError of a dependency
it lacks), as a half-installed plugin does.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests import wheels

NAME, VERSION = "lab_sensors", "0.1.0"
KIND = "ad8495"

MODULE = '''"""A lab's own sensor kinds for pneumad."""
import math
from dataclasses import dataclass

from hal.devices import Sensor
from hal.schema import require


@dataclass(frozen=True)
class AD8495Config:
    channel: str
    low_k: float = 253.15  # plausible range [K]: -20 to 150 degC
    high_k: float = 423.15
    device: str = "ad8495"

    def __post_init__(self):
        require(self.low_k < self.high_k, "high_k", "the plausible range is inverted")


class AD8495(Sensor):
    """Type K thermocouple amplifier: V = 1.25 V + 5 mV/degC (T - 0 degC)."""

    Config = AD8495Config
    unit = "K"

    def __init__(self, config):
        super().__init__(config)
        self.low, self.high = config.low_k, config.high_k

    def convert(self, volts):
        t = (volts - 1.25) / 0.005 + 273.15
        return t if self.low <= t <= self.high else math.nan

    def diagnose(self, volts):
        if self.convert(volts) == self.convert(volts):
            return None
        return f"{(volts - 1.25) / 0.005:.1f} degC is outside {self.low - 273.15:g}..{self.high - 273.15:g} degC"

    def volts_for(self, kelvin):
        return 1.25 + 0.005 * (kelvin - 273.15)
'''

BROKEN = '''import lab_sensors_missing_dependency  # noqa: F401  (a dependency that is not installed)
'''


def wheel(directory: Path, broken: bool = False, module: str = MODULE) -> Path:
    """The package (its module's text ``module``) as a wheel (PEP 427) in ``directory``."""
    dist = f"{NAME}-{VERSION}.dist-info"
    files = {
        f"{NAME}/__init__.py": BROKEN if broken else module,
        f"{dist}/METADATA": f"Metadata-Version: 2.1\nName: {NAME.replace('_', '-')}\nVersion: {VERSION}\n"
                            f"Summary: a lab's own sensor kinds for pneumad\n",
        f"{dist}/entry_points.txt": f"[pneumad.devices]\n{KIND} = {NAME}:AD8495\n",
    }
    return wheels.write(directory, NAME, VERSION, files, "tests/device_plugin.py")


def install(directory: Path, broken: bool = False, module: str = MODULE) -> Path:
    """The plugin installed by pip into ``directory/site`` (returned: put it on the path)."""
    site = Path(directory) / "site"
    made = wheel(Path(directory), broken, module)
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-index", "--no-deps", "--target",
                    str(site), str(made)], check=True, timeout=300, capture_output=True)
    return site


def rig_text(base: str) -> str:
    """A rig file (``base``'s text) with a thermocouple of the kind on a spare channel, ``ai5``,
    read as the rig-level input ``oil_temperature``."""
    return base + f'\n[[inputs]]\nname = "oil_temperature"\ndevice = "{KIND}"\nchannel = "ai5"\n'


