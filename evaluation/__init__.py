"""Controllers judged on the rig's model before they touch the arm (``pneumactl evaluate``):
the daemon's own loop on a virtual clock, over references and plant variations, in a pool of
processes beside the caller."""
