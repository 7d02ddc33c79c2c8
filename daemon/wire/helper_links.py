"""The private ipc sockets between the messenger and the helper processes beside it (the
recorder, the model process): their names in the rings' directory, their queues, and the
frames they carry. The messenger binds each; the helper connects. Both sides read them here,
so neither imports the other's folder."""
from __future__ import annotations

import os

MESSENGER_ID = b"messenger"  # the messenger's routing id on the recorder's control socket
EVENT = b"event"  # a helper's event: [EVENT, body] (the recorder's JSON, the model's msgpack)
REPLY = b"reply"  # the recorder's answer to a request: [REPLY, token, answer]
MARK = b"mark"  # on the recorder's feed just before a request: [MARK, the request's token]

RECORDER_FEED = "recorder-feed"  # telemetry to the recorder (PUSH -> PULL)
RECORDER_CONTROL = "recorder-control"  # record.* requests and their answers, its events (DEALER <-> ROUTER)
RECORDER_FEED_HWM = 200_000  # messages the feed may queue (about 10 minutes of telemetry)

MODEL_FEED = "model-feed"  # ``state`` messages to the model process (PUSH -> PULL)
MODEL_OUT = "model-out"  # the model topic and its events back (PUSH -> PULL)
MODEL_FEED_HWM = 6000  # state messages the feed may queue (about 60 s of telemetry: a model process starved that long)
MODEL_TOPIC = b"model"  # the model process's statistics, published as they come
HELPER_TOPICS = (MODEL_TOPIC,)  # topics the messenger publishes from a helper, not from the loop's ring


def endpoint(rings_dir: str, name: str) -> str:
    """The ipc address of socket ``name`` in the rings' directory."""
    return f"ipc://{os.path.join(rings_dir, name)}"
