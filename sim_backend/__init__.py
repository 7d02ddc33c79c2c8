"""The simulated rig: identified plant models behind the same transport contract as hal/.

The simulator speaks volts on named channels, so the device drivers, the rig I/O and the
daemon run exactly the code they run on hardware.
"""
