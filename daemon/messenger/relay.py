"""The messenger process's work (:mod:`daemon.messenger.process`): requests from the ROUTER sockets
into the loop's rings, each with who sent it; replies from the loop's rings onto the sockets,
and its telemetry published (:mod:`daemon.messenger.publisher`); the loop's heartbeat watched, and answered for while it is stalled; the
keys' allow-list reloaded (SIGHUP, ``keys.reload``), and the loop told of each key it lost
(:mod:`daemon.messenger.revocation`); every event published written to the daemon's log (this
process's stderr, the daemon's journal: :mod:`daemon.messenger.journal`), so the loop never logs
from its cycle; the loop's timing judged from its stats windows, and the verdict told to the loop
(:mod:`daemon.messenger.timing`)."""
from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING

import zmq

from daemon.wire import catalog, protocol
from daemon.wire.arguments import CommandFailed
from daemon.wire.command_spec import Command, check_args, lenient_args
from daemon.messenger.guard import Guard
from daemon.wire import routed
from daemon.wire.keys import ANONYMOUS, OPERATOR, Identity
from daemon.messenger.shared import IDLE_POLL_MS, OWED_LIMIT_S, STALL_S, Heartbeat, open_socket, reloads, ring_entry
from daemon.messenger.model_link import ModelLink
from daemon.messenger.recorder_link import Recorder, send_reply
from daemon.messenger.revocation import Revocations
from daemon.messenger.journal import Journal
from daemon.messenger.publisher import Publisher
from daemon.messenger.timing import TimingJudge
from daemon.wire.flight import FlightNames
from daemon.wire.ring import Ring
from daemon.wire.watchdog_link import NONE, WatchdogLink
from daemon.messenger.plotjuggler import PlotJugglerFeed
from daemon.wire.loop_stats import StatsBanks
from daemon.wire.cycle_layout import CycleLayout
from hal.rig_sections import FlightRecorderConfig, TimingConfig


if TYPE_CHECKING:  # imported where the stream is asked for (daemon.messenger.process): the SDK costs start-up time
    from daemon.messenger.foxglove_stream import FoxgloveStream

SIGNALLED = Identity("SIGHUP", OPERATOR)  # who reloads the keys on a signal (systemctl reload), in events


class Relay:
    """Moves requests from the ROUTER sockets into the loop's rings, and replies from the loop's
    rings onto the sockets; its :class:`Publisher` passes the telemetry on in between."""

    def __init__(self, sockets: dict[str, zmq.Socket], rings: dict[str, Ring], doorbell: int, heartbeat: Heartbeat,
                 stats: StatsBanks, layout: CycleLayout, stall_s: float = STALL_S, guard: Guard | None = None, recorder: Recorder | None = None,
                 plotjuggler: PlotJugglerFeed | None = None, foxglove: FoxgloveStream | None = None,
                 timing: TimingConfig | None = None, flight: FlightRecorderConfig | None = None,
                 model: ModelLink | None = None, watchdog: WatchdogLink | None = None):
        self.watchdog = watchdog  # the loop's cycle watchdog: told of e-stops, its writes of the safe state published
        self._watchdog_seen = watchdog.report() if watchdog is not None else NONE
        self._owed_estops: set[int] = set()  # tokens of e-stops the loop has not answered: the watchdog's write does
        self.sockets, self.rings, self.doorbell, self.heartbeat = sockets, rings, doorbell, heartbeat
        self.recorder = recorder
        self.model = model  # the model process's feed and what it sends back (daemon.messenger.model_link)
        self.foxglove = foxglove  # the live Foxglove stream (daemon.messenger.foxglove_stream)
        self.stall_s = stall_s
        self.guard = guard
        self.owed: dict[int, tuple[zmq.Socket, list, float, object]] = {}  # token -> (socket, envelope, when, id)
        self._cycle, self._cycle_seen = heartbeat.read(), time.monotonic()  # the loop's count and when it moved
        self.stalled_since: float | None = None
        self._tokens = iter(range(1, 1 << 62))
        self.revocations = Revocations(rings, heartbeat, self._tokens)  # keys a reload removed, told to the loop
        self.journal = Journal()  # every event published, a line of the daemon's log
        self.timing = TimingJudge(timing or TimingConfig(), rings, self._tokens)  # the rig file's [timing]
        # a trip's flight file, named as its event goes out (daemon.wire.flight); only where the recorder writes it
        flights = FlightNames(flight.after_s) if flight is not None and recorder is not None else None
        self.publisher = Publisher(sockets, rings["telemetry"], layout, stats, self.timing.take, self.journal, flights,
                                   recorder, model, plotjuggler, foxglove)
        self.poller = zmq.Poller()
        for name in ("control", "command"):
            self.poller.register(sockets[name], zmq.POLLIN)
        self.poller.register(doorbell, zmq.POLLIN)
        if recorder is not None:
            self.poller.register(recorder.control, zmq.POLLIN)
        if model is not None:
            self.poller.register(model.out, zmq.POLLIN)
        self._served = {"keys.reload": self._answer_reload}  # the commands this process answers itself
        catalog.check_handlers(("messenger",), self._served)

    def run(self, parent_alive) -> None:
        """Until the telemetry ring's END, or until the parent is gone."""
        last_check = time.monotonic()
        while True:
            stream_busy = self.foxglove is not None and self.foxglove.busy
            ready = dict(self.poller.poll(0 if stream_busy else IDLE_POLL_MS))
            for name in ("control", "command"):  # control first: an e-stop overtakes a flood
                if self.sockets[name] in ready:
                    self._take_requests(name)
            if self.recorder is not None and self.recorder.control in ready:
                self.recorder.take_answers(self._event)
            if self.model is not None and self.model.out in ready:
                self.model.take(self.publisher.model_message, lambda event: self._event(event, "model"))
            if self.doorbell in ready:
                os.read(self.doorbell, 4096)  # the rings say what there is; the bytes only woke us
            self._send_replies()
            rebind = self.revocations.rebind_due(time.monotonic())  # before the drain: the loop's say is in the ring
            if not self.publisher.drain():
                self._send_replies()  # the loop's last answers, then stop
                return
            if rebind:
                self._rebind_telemetry()
            if self.foxglove is not None:
                self.foxglove.work()  # a slice of the Foxglove stream's encoding, then the sockets again
            if reloads:
                reloads.clear()
                self._reload_keys(SIGNALLED)
            now = time.monotonic()
            self._watch_loop(now)
            if now - last_check > 0.5:
                last_check = now
                if not parent_alive():
                    return
                self.owed = {t: o for t, o in self.owed.items() if now - o[2] < OWED_LIMIT_S}
                self._owed_estops.intersection_update(self.owed)
                self.revocations.expire(now)
                self.timing.expire()
                self.journal.flush()
                if self.recorder is not None:
                    self.recorder.expire(now)

    def _take_requests(self, name: str) -> None:
        """Every waiting request that fits in the loop's ring; the rest stay queued in ZeroMQ.
        While the loop is stalled, command-socket requests are refused here instead."""
        sock, ring = self.sockets[name], self.rings[name]
        while ring.free() >= protocol.MAX_MESSAGE_BYTES + 512:
            try:
                frames = sock.recv_multipart(zmq.NOBLOCK, copy=False)
            except zmq.Again:
                return
            envelope, body = [f.bytes for f in frames[:-1]], frames[-1].bytes
            identity = self.guard.identify(frames[-1]) if self.guard is not None else ANONYMOUS
            if identity is None:
                self._refuse(sock, envelope, body, "your key has been revoked: ask the lab for a new one",
                             {"reason": "revoked", "key": frames[-1].get("User-Id")})
                continue
            if len(body) > protocol.MAX_MESSAGE_BYTES:  # answered, not dropped: the client learns why
                self._send(sock, envelope, protocol.too_large(body))
                continue
            try:
                request = protocol.decode_request(body)
                command, request = self._admit(name, request, identity)
            except protocol.ProtocolError as exc:
                self._send(sock, envelope, protocol.encode_error(exc.request_id, exc.code, exc.message))
                continue
            except CommandFailed as exc:
                self._send(sock, envelope, protocol.encode_error(request["id"], exc.code, exc.message, exc.data))
                continue
            if command.server == "messenger":
                self._served[command.name](sock, envelope, request["id"], identity)
                continue
            if command.server == "recorder":
                self._to_recorder(sock, envelope, body, request["id"], identity)
                continue
            if self.stalled_since is not None and name == "command":
                self._answer_stalled(sock, envelope, request["id"], "refused without reaching the loop: nothing was done")
                continue
            token = next(self._tokens)
            if command.name == "estop" and self.watchdog is not None:
                self.watchdog.pass_estop()  # written safe by the watchdog if the loop does not take it at once
                if self.stalled_since is None:
                    self._owed_estops.add(token)
            ring.put(token, routed.pack(identity, request))
            if self.stalled_since is not None:  # a control request: kept for the loop, answered now
                self._answer_stalled(sock, envelope, request["id"], "queued: it takes effect if the loop resumes")
            else:
                self.owed[token] = (sock, envelope, time.monotonic(), request["id"])

    @staticmethod
    def _admit(socket: str, request: dict, identity) -> tuple[Command, dict]:
        """The request's catalog entry and the request to pass on, checked in the documented
        order after its envelope: the command (on this socket), its arguments, the key's role; a
        refusal raises CommandFailed (or ProtocolError for arguments that cannot be read). An
        e-stop, never refused for its arguments, is passed on with only what the loop reads of
        them (:func:`~daemon.wire.command_spec.lenient_args`): a few bytes, whatever was sent."""
        command = catalog.find(request["cmd"], socket)
        args = protocol.decode_args(request)
        check_args(command, args)
        if command.role == OPERATOR and identity.role != OPERATOR:
            raise CommandFailed(protocol.FORBIDDEN, f"key {identity.name!r} is an {identity.role}: only an operator "
                                                    f"may send {command.name}",
                                {"reason": "role", "role": identity.role})
        if not command.strict:
            request = protocol.decode_request(protocol.encode_request(
                request["id"], command.name, lenient_args(command, args), request["lease"]))
        return command, request

    # -- keys ------------------------------------------------------------------------------
    def _refuse(self, sock: zmq.Socket, envelope: list, body: bytes, message: str, data: dict) -> None:
        self._send(sock, envelope, protocol.encode_error(protocol.request_id_of(body), protocol.FORBIDDEN, message, data))

    def _answer_reload(self, sock: zmq.Socket, envelope: list, request_id, identity: Identity) -> None:
        """``keys.reload``, answered here: the allow-list is this process's (the role was
        checked in :meth:`_admit`)."""
        if self.guard is None:
            reply = protocol.encode_error(request_id, protocol.BAD_STATE, "this daemon runs without keys (pneumad run "
                                          "--keys DIR): there is no allow-list to reload", {"reason": "no_keys"})
        else:
            reply = protocol.encode_result(request_id, self._reload_keys(identity))
        self._send(sock, envelope, reply)

    def _reload_keys(self, who: Identity) -> dict:
        """Read the allow-list again, as ``who`` asked (its ``keys`` event names them); if a
        key was removed or changed (another key or role for the name), the loop ends a lease it holds, and the telemetry socket is bound
        again once the loop has said so, so that its subscribers must be admitted again (a
        revoked one is not)."""
        if self.guard is None:
            return {}
        changes = self.guard.reload(who.name)
        self._event({"kind": "keys", "cycle": self._cycle, "who": who.name,
                     "cause": f"keys reloaded by {who.name}: added {changes['added'] or 'none'}, "
                              f"removed {changes['removed'] or 'none'}, changed {changes['changed'] or 'none'}",
                     **changes})
        ended = {**{key: "removed" for key in changes["removed"]}, **{key: "changed" for key in changes["changed"]}}
        if ended:
            self.revocations.revoke(ended, who, time.monotonic())
        return changes

    def _rebind_telemetry(self) -> None:
        old = self.sockets["telemetry"]
        endpoint = old.getsockopt_string(zmq.LAST_ENDPOINT)
        old.close()
        self.sockets["telemetry"] = _rebind(old.context, endpoint, self.guard)

    _send = staticmethod(send_reply)

    # -- the recorder ----------------------------------------------------------------------
    def _to_recorder(self, sock: zmq.Socket, envelope: list, body: bytes, request_id, identity) -> None:
        """``record.*``: passed to the recorder process (its answer comes back through
        :meth:`Recorder.take_answers`), never to the loop."""
        if self.recorder is None:
            self._send(sock, envelope, protocol.encode_error(
                request_id, protocol.BAD_STATE, "this daemon records nothing: start it with --record-dir DIR",
                {"reason": "no_recorder"}))
        elif not self.recorder.ask(next(self._tokens), sock, envelope, body, request_id, str(identity)):
            self._send(sock, envelope, protocol.encode_error(
                request_id, protocol.BAD_STATE, "the recorder is not taking requests just now (restarting?): ask again",
                {"reason": "recorder_unavailable"}))

    # -- the loop's heartbeat --------------------------------------------------------------
    def _watch_loop(self, now: float) -> None:
        cycle = self.heartbeat.read()
        if cycle != self._cycle:
            self._cycle, self._cycle_seen = cycle, now
            if self.stalled_since is not None:
                self._event({"kind": "loop_resumed", "cycle": cycle, "stalled_s": now - self.stalled_since})
                self.stalled_since = None
        elif cycle and self.stalled_since is None and now - self._cycle_seen > self.stall_s:
            self.stalled_since = self._cycle_seen
            self._event({"kind": "loop_stalled", "cycle": cycle,
                         "cause": f"the loop has not cycled for {(now - self._cycle_seen) * 1e3:.0f} ms"})
            for token, (sock, envelope, _, request_id) in list(self.owed.items()):  # taken before the stall
                del self.owed[token]
                self._answer_stalled(sock, envelope, request_id, "taken before the stall: it runs if the loop resumes, "
                                                           "and its own reply is lost")
        if self.watchdog is not None:
            self._watch_watchdog()

    def _watch_watchdog(self) -> None:
        """Publish the cycle watchdog's act (a ``watchdog`` event, a log line). The e-stops that
        came before its write of the safe state are done: answered so now, whether the loop is
        late or stuck in a step (a stall is for the messenger's own watch to say, at
        ``stall_s``); the loop latches them when it cycles, and its own replies are dropped."""
        report = self.watchdog.report()
        if report.count == self._watchdog_seen.count:
            return
        self._watchdog_seen = report
        self._event({"kind": "watchdog", "cycle": report.cycle, "cause": report.cause, "t_loop": report.t})
        if not report.written:  # not done: the loop's own reply says when it is
            return
        for token in list(self._owed_estops):
            owed = self.owed.get(token)
            if owed is None:
                self._owed_estops.discard(token)
            elif owed[2] <= report.t:  # came before the write
                del self.owed[token]
                self._owed_estops.discard(token)
                self._send(owed[0], owed[1], protocol.encode_result(owed[3], {"state": "estop",
                                                                              "written_by": "watchdog"}))

    def _answer_stalled(self, sock: zmq.Socket, envelope: list, request_id, what: str) -> None:
        since = time.monotonic() - self._cycle_seen
        report = self._watchdog_seen
        during = report.count > 0 and report.cycle >= self._cycle and report.t >= self._cycle_seen - 1.0
        safe = during and report.written
        said = f"; {report.cause}" if during else ""
        reply = protocol.encode_error(request_id, protocol.LOOP_STALLED,
                                      f"the control loop has not cycled for {since:.1f} s (last cycle {self._cycle}); "
                                      f"this request was {what}{said}",
                                      {"reason": "loop_stalled", "stalled_s": since, "cycle": self._cycle,
                                       "safe_state_written": safe})
        self._send(sock, envelope, reply)

    def _event(self, event: dict, source: str = "messenger") -> None:
        """Publish an event of this process's own (or the recorder's, or the model process's)."""
        self.publisher.event(event, source, self._cycle)

    def _send_replies(self) -> None:
        ring = self.rings["replies"]
        while (entry := ring_entry(ring)) is not None:
            token, reply = entry
            owed = self.owed.pop(token, None)
            if owed is not None:
                send_reply(owed[0], owed[1], reply)
            elif not self.revocations.answer(token, reply):
                self.timing.answer(token, reply)



def _rebind(ctx: zmq.Context, endpoint: str, guard: Guard) -> zmq.Socket:
    """The telemetry socket again on ``endpoint``: ZeroMQ closes the old listener in its own
    thread, so the port may take a moment to be free."""
    for _ in range(50):
        try:
            return open_socket(ctx, "telemetry", endpoint, guard)
        except zmq.ZMQError as exc:
            if exc.errno != zmq.EADDRINUSE:
                raise
            time.sleep(0.02)
    return open_socket(ctx, "telemetry", endpoint, guard)
