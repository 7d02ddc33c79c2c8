"""Hardware abstraction: transports move raw channel values, device drivers convert them.

The split follows python-can's bus/interface model: :mod:`hal.transport` is the one small
contract every DAQ backend implements; :mod:`hal.rig` joins a transport to the device
drivers named by the rig configuration and turns a raw sweep into SI quantities. Device kinds
and transports are plugins found by name (:mod:`hal.plugins`); what a rig declares, the
interfaces everything downstream follows, is :mod:`hal.declare`'s.
"""
