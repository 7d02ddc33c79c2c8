"""Plant identification from experiments (rig-facts §1 "Experiments", "Identified joint model").

- :mod:`.data`: one joint's experiment, read from a recording (signal, operating point, rig hash);
- :mod:`.frf`: frequency response with coherence, open and closed loop;
- :mod:`.simulate`: the joint model [2-36..2-45] simulated for many parameter sets at once;
- :mod:`.fit`: the differential-evolution fit, the [2-49] Fit %, confidence;
- :mod:`.plots`: Bode and time-domain figures;
- :mod:`.rigfile`: the identified model written as a ``[models.NAME]`` table of a rig file.

Everything here runs in the client (``pneumactl identify``) or a notebook, never in the daemon.
"""
