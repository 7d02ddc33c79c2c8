"""Made with main at 8baebb9 (before the cycle layout): legacy recordings for the reader's test."""
import io, sys, time
import msgpack
from daemon.testing.loop import make_loop, Captured
from daemon.recordings.mcap_log import McapRecording
from controllers.trajectory import JointMove
import math

def run(rig_name, path_mcap=None, path_pnrec=None, cycles=300, controller="pid"):
    from hal import config
    rig = config.load(rig_name)
    loop, cap, srv = make_loop(rig.source, server=True, controller=controller)
    loop.enable()
    loop.set_trajectory(JointMove(list(loop.reference[0]), [a + math.radians(2) for a in loop.reference[0]], 0.2), "move")
    loop.run(cycles)
    loop.disable()
    loop.run(20)
    describe = loop.server.commands.described
    controller = loop.server.commands.controller_get({})
    msgs = cap.messages
    if path_mcap:
        with open(path_mcap, "wb") as f:
            rec = McapRecording(f, describe, controller)
            for topic, m in msgs:
                rec.write(topic, m)
            rec.finish()
    if path_pnrec:
        with open(path_pnrec, "wb") as f:
            f.write(msgpack.packb({"format": "pneumad-recording/1", "software": describe["version"], "describe": describe,
                                   "rig": describe["rig"]["source"], "controller": controller, "started_unix_s": 0.0}))
            for topic, m in msgs:
                if topic in ("state", "event"):
                    f.write(msgpack.packb([topic, m]))
    srv.close()

run("sim-muscle", path_mcap="/tmp/core_legacy/muscle-before-layout.mcap", controller="muscle_eq")
run("sim", path_pnrec="/tmp/core_legacy/sim-before-layout.pnrec", cycles=200)
