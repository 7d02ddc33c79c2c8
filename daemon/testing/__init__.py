"""The harness the tests and the benches share, shipped with the project (as ophyd-async ships
``ophyd_async.testing``): the real loop in-process on a virtual clock with the simulated rig
(:mod:`daemon.testing.loop`), the simulated rig alone in lockstep (:mod:`daemon.testing.simrig`),
and real daemons on private endpoints (:mod:`daemon.testing.daemons`). It builds through
:mod:`daemon.assembly`, like ``pneumad`` itself; it never talks to the default endpoints."""
