"""How tests/data's recordings from before the cycle layout were made (test_recordings reads
them): on the version before it, commit 8baebb9, e.g. ``git worktree add /tmp/old 8baebb9 &&
PYTHONPATH=/tmp/old python tests/data/make_before_layout.py``. A short move on the muscle rig
recorded as MCAP (nested samples) and on the built-in rig as an earlier ``.pnrec``."""
import math
from pathlib import Path

import msgpack

from controllers.trajectory import JointMove
from daemon.recordings.mcap_log import McapRecording
from daemon.testing.loop import make_loop

HERE = Path(__file__).resolve().parent


def run(rig_name, path_mcap=None, path_pnrec=None, cycles=300, controller="pid"):
    """A 2 deg move of every joint in 0.2 s, enabled ``cycles`` cycles, then 20 idle ones."""
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

if __name__ == "__main__":
    run("sim-muscle", path_mcap=HERE / "muscle-before-layout.mcap", controller="muscle_eq")
    run("sim", path_pnrec=HERE / "sim-before-layout.pnrec", cycles=200)
