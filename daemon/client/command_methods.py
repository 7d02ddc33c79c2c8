"""One method per catalog command (:mod:`daemon.wire.catalog`) for Python: each names and
documents the command's arguments and sends them through :meth:`daemon.client.client.Client.call`,
which :class:`~daemon.client.client.Client` brings (it is this class's one subclass)."""
from __future__ import annotations


class CommandMethods:
    """The commands as methods; ``call(cmd, args, control=False)`` is the client's."""

    def ping(self):
        return self.call("ping")

    def status(self):
        return self.call("status")

    def describe(self):
        return self.call("describe")

    def estop(self, who: str = "client"):
        """On the control socket: never queued behind other requests."""
        return self.call("estop", {"who": who}, control=True)

    def abort(self):
        return self.call("abort", control=True)

    def enable(self):
        return self.call("enable")

    def disable(self):
        return self.call("disable")

    def reset(self):
        return self.call("reset")

    def set(self, angles_deg=None, xy_mm=None, duration_s: float = 0.0, record: bool = False,
            stiffness_nm_deg=None, positions=None, angles_rad=None):
        """Move to joint positions (``positions``: deg on a rotary joint, mm on a linear one), joint
        angles (``angles_deg``, or ``angles_rad`` [rad]: rotary joints only) or a tip point
        (``xy_mm``); ``stiffness_nm_deg`` (one number, or one per joint) where the joints take a
        stiffness set-point."""
        args = {"duration_s": duration_s, **_record(record)}
        if positions is not None:
            args["positions"] = list(positions)
        if stiffness_nm_deg is not None:
            args["stiffness_nm_deg"] = stiffness_nm_deg
        if angles_deg is not None:
            args["angles_deg"] = list(angles_deg)
        if angles_rad is not None:
            args["angles_rad"] = list(angles_rad)
        if xy_mm is not None:
            args["xy_mm"] = list(xy_mm)
        return self.call("set", args)

    def path(self, name: str, duration_s: float | None = None, approach_s: float | None = None, record: bool = False):
        """A reference path; ``record``: the daemon records it, start to end (the reply's ``recording``)."""
        args = {"name": name, **_record(record)}
        if duration_s is not None:
            args["duration_s"] = duration_s
        if approach_s is not None:
            args["approach_s"] = approach_s
        return self.call("path", args)

    def controllers(self):
        return self.call("controller.list")

    def controller(self):
        return self.call("controller.get")

    def waypoints(self, angles_deg=None, xy_mm=None, durations_s=(), approach_s: float | None = None,
                  record: bool = False, positions=None):
        """A path through joint (``positions``: deg on a rotary joint, mm on a linear one;
        ``angles_deg``) or tip (``xy_mm``) waypoints; see read_waypoints."""
        args = {"durations_s": list(durations_s), **_record(record)}
        if positions is not None:
            args["positions"] = [list(p) for p in positions]
        if angles_deg is not None:
            args["angles_deg"] = [list(p) for p in angles_deg]
        if xy_mm is not None:
            args["xy_mm"] = [list(p) for p in xy_mm]
        if approach_s is not None:
            args["approach_s"] = approach_s
        return self.call("waypoints", args)

    def steps(self, angles_deg, hold_s, record: bool = False, key: str = "angles_deg"):
        """Step to each row of ``angles_deg`` in turn, holding it ``hold_s[i]`` seconds; ``key``
        "positions": the rows are positions, deg on a rotary joint and mm on a linear one."""
        return self.call("steps", {key: [list(p) for p in angles_deg], "hold_s": list(hold_s), **_record(record)})

    def excite(self, signal: str, joint: str, amplitude_deg: float, record: bool = False, **settings):
        """An identification signal (chirp: f0_hz, f1_hz, duration_s; prbs: order, bit_s, periods)."""
        return self.call("excite", {"signal": signal, "joint": joint, "amplitude_deg": amplitude_deg, **settings,
                                    **_record(record)})

    def excite_input(self, signal: str, joint: str, amplitude_v: float, record: bool = False, **settings):
        """An open-loop experiment: the signal on the joint's V_MV about the present set-point
        (chirp, prbs, multisine, steps; settle_s, band_deg and the signal's settings)."""
        return self.call("excite", {"side": "input", "signal": signal, "joint": joint, "amplitude_v": amplitude_v,
                                    **settings, **_record(record)})

    def record_start(self, name: str | None = None, seconds: float | None = None):
        """The daemon records its telemetry (MCAP, in its recording directory) until
        :meth:`record_stop` or for ``seconds``; nothing a slow network loses is lost to it."""
        args = {k: v for k, v in (("name", name), ("seconds", seconds)) if v is not None}
        return self.call("record.start", args)

    def record_stop(self, name: str | None = None):
        return self.call("record.stop", {"name": name} if name else {})

    def record_list(self):
        return self.call("record.list")

    def record_snapshot(self, name: str | None = None):
        """The flight recorder's last seconds (the rig file's ``[flight_recorder] seconds``) written
        to a file in the daemon's recording directory; a ``record`` event (``flight``) says when it is."""
        return self.call("record.snapshot", {"name": name} if name else {})

    @staticmethod
    def candidate(name: str, params: dict | None, design: str | None) -> dict:
        """A controller.switch/shadow request's arguments, the design file read (scipy: slow to
        import): make them before taking the lease, whose time to live may be shorter."""
        args = {"name": name, "params": params or {}}
        if design is not None:
            from controllers import lti_design  # here: it imports scipy (0.6 s), which pneumactl mostly needs not
            args["options"] = {"design": lti_design.read_file(design)}
        return args

    def switch_controller(self, name: str, params: dict | None = None, design: str | None = None):
        """Switch controllers (bumpless); ``design`` is an LTI design file (.toml or .npz)."""
        return self.call("controller.switch", self.candidate(name, params, design))

    def shadow(self, name: str, params: dict | None = None, design: str | None = None):
        """Run a candidate controller beside the active one, published but not applied."""
        return self.call("controller.shadow", self.candidate(name, params, design))

    def reload_controller(self, name: str):
        """Read controller ``name``'s plugin file again (the daemon's --controller-dir) and make
        its new version the one switch and shadow build; the running controller runs on."""
        return self.call("controller.reload", {"name": name})

    def commit(self, force: bool = False):
        return self.call("controller.commit", {"force": True} if force else None)

    def discard(self):
        return self.call("controller.discard")

    def set_params(self, **params):
        return self.call("controller.set", {"params": params})

    def set_load(self, mass_kg: float, com_mm=(0.0, 0.0)):
        """A known payload [kg] at ``com_mm`` (along, across the last link from the tip
        [mm]), its weight fed forward to every controller."""
        return self.call("load.set", {"mass_kg": mass_kg, "com_mm": list(com_mm)})

    def clear_load(self):
        return self.call("load.clear")


def _record(record: bool) -> dict:
    return {"record": True} if record else {}
