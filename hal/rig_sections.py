"""The rig file's small tables, each a frozen dataclass checked when it is built: ``[rig]``,
``[transport]``, ``[arm]``, ``[limits]``, ``[safety]``, ``[timing]``, ``[flight_recorder]`` and
``[model_watch]`` (docs/rigs.md: every key). :class:`hal.config.RigConfig` holds them with the
joints and devices; the processes beside the loop are handed the table they need."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hal.schema import require


@dataclass(frozen=True)
class ArmConfig:
    """Planar arm geometry (rig-facts §1; link lengths are an interpretation, default 100 mm):
    one link per joint of a rig of rotary joints; a rig with a linear joint has none."""

    link_lengths_mm: tuple[float, ...] = (100.0, 100.0)
    elbow: int = -1  # IK branch: sign of the second joint angle
    # gravity in the arm's plane (x, y) [m/s^2]: what a payload's weight pulls along
    # (**interpretation**: the source does not say how the arm stands; a vertical plane, y up)
    gravity_m_s2: tuple[float, ...] = (0.0, -9.81)

    def __post_init__(self):
        require(all(l > 0 for l in self.link_lengths_mm), "link_lengths_mm", "every link must be > 0 mm")
        require(self.elbow in (1, -1), "elbow", f"must be +1 or -1, got {self.elbow}")
        require(len(self.gravity_m_s2) == 2 and math.hypot(*self.gravity_m_s2) <= 20.0, "gravity_m_s2",
                f"two numbers (x, y) in the arm's plane, at most 20 m/s^2 long; got {list(self.gravity_m_s2)}")

    @property
    def link_lengths_m(self) -> tuple[float, ...]:
        return tuple(l * 1e-3 for l in self.link_lengths_mm)


@dataclass(frozen=True)
class LimitsConfig:
    """Rig-wide pressure limits, tighter than or equal to the regulators' own range."""

    max_pressure_mpa: float = 0.9
    max_pressure_rate_mpa_s: float = 50.0  # slew limit on each chamber command [MPa/s]
    # of the V_MV range a reference may need along its path (the rest is left to feedback):
    # at 0.8 the built-in controllers spend under 2 % of an accepted path at an output limit
    # on the nominal plant, at 1.0 up to 23 % (docs/controllers.md, "Robustness")
    authority_fraction: float = 0.8

    def __post_init__(self):
        require(0 < self.max_pressure_mpa <= 0.9, "max_pressure_mpa",
                f"must be within (0, 0.9] MPa (the ITV0051 range), got {self.max_pressure_mpa}")
        require(self.max_pressure_rate_mpa_s > 0, "max_pressure_rate_mpa_s", "must be > 0")
        require(0 < self.authority_fraction <= 1, "authority_fraction", "must be within (0, 1]")


@dataclass(frozen=True)
class SafetyConfig:
    """When the supervisor trips to the safe state."""

    bad_samples_to_trip: int = 3  # implausible samples in a row before a sensor fault trips
    stale_after_s: float = 0.005  # input older than this is stale [s]
    stall_after_s: float = 0.05  # a cycle woken this late trips [s]
    velocity_filter_hz: float = 10.0  # low-pass on the differenced angle [Hz]
    lease_ttl_s: float = 2.0  # default lease life without a renewal [s]
    # An arm left enabled with no client holding the lease (one that enabled and let go):
    # "disable" it once it has held position that long, or "hold" it until a client comes.
    unleased_action: str = "disable"
    unleased_grace_s: float = 60.0  # [s] of holding with no lease holder before the action
    # A controller that has lost a joint: its tracking error outside this band [deg; mm on a
    # linear joint] for the window [s] without closing in. "trip" to the safe state, or
    # "fallback": the configured fallback controller takes over and holds the arm where it is.
    # 0 turns the rule off.
    tracking_error_deg: float = 10.0
    tracking_error_mm: float = 10.0
    # A set-point (set, steps, waypoints) closer than this to a joint's limit is refused: a
    # controller's overshoot past a set-point at the limit would trip the arm [deg; mm on a linear joint]:
    # docs/rigs.md says what the built-in controllers overshoot (pid: 2.4 deg; the axis's: 2.7 mm)
    setpoint_margin_deg: float = 3.0
    setpoint_margin_mm: float = 5.0
    tracking_window_s: float = 2.0
    tracking_action: str = "trip"
    fallback_controller: str = "pid"

    def __post_init__(self):
        require(1 <= self.bad_samples_to_trip <= 1000, "bad_samples_to_trip", "must be within 1-1000")
        require(0 < self.stale_after_s <= 1.0, "stale_after_s", "must be within (0, 1] s")
        require(0 < self.stall_after_s <= 10.0, "stall_after_s", "must be within (0, 10] s")
        require(0 < self.velocity_filter_hz <= 500, "velocity_filter_hz", "must be within (0, 500] Hz")
        require(0.1 <= self.lease_ttl_s <= 60, "lease_ttl_s", "must be within 0.1-60 s")
        require(self.unleased_action in ("disable", "hold"), "unleased_action", 'must be "disable" or "hold"')
        require(1.0 <= self.unleased_grace_s <= 3600, "unleased_grace_s", "must be within 1-3600 s")
        require(0 <= self.tracking_error_deg <= 180, "tracking_error_deg", "must be within 0-180 deg (0: off)")
        require(0 <= self.tracking_error_mm <= 5000, "tracking_error_mm", "must be within 0-5000 mm (0: off)")
        require(0 <= self.setpoint_margin_deg <= 45, "setpoint_margin_deg", "must be within 0-45 deg (0: none)")
        require(0 <= self.setpoint_margin_mm <= 500, "setpoint_margin_mm", "must be within 0-500 mm (0: none)")
        require(0.01 <= self.tracking_window_s <= 60, "tracking_window_s", "must be within 0.01-60 s")
        require(self.tracking_action in ("trip", "fallback"), "tracking_action", 'must be "trip" or "fallback"')
        require(isinstance(self.fallback_controller, str) and bool(self.fallback_controller), "fallback_controller",
                "must name a registered controller")


@dataclass(frozen=True)
class TimingConfig:
    """When the loop's timing is degraded, and what then (the messenger judges it beside the
    loop from its stats windows: docs/faults.md, "the loop is degraded"). Over the last
    ``window_s``: the achieved rate below ``min_rate_fraction`` of 1/period, or more than
    ``max_overrun_fraction`` of the deadlines missed (overruns), or the control stage's median
    time in the last stats window (the controller's step, chiefly) above
    ``step_budget_fraction`` of the period. ``policy``: ``"warn"`` (an event, a log line and
    the status field), ``"hold"`` (also: a controller over its step budget replaced by the
    fallback controller, a running reference stopped and the arm held, motion commands refused
    while it lasts) or ``"trip"`` (also: an enabled arm trips)."""

    window_s: float = 5.0  # the sliding window judged [s]
    min_rate_fraction: float = 0.9  # of the loop's rate (1/period)
    max_overrun_fraction: float = 0.02  # of the deadlines in the window
    step_budget_fraction: float = 0.5  # of the period, for the control stage's median time
    policy: str = "warn"

    def __post_init__(self):
        require(1.0 <= self.window_s <= 600.0, "window_s", "must be within 1-600 s")
        require(0.0 <= self.min_rate_fraction <= 1.0, "min_rate_fraction", "must be within 0-1 (0: not judged)")
        require(0.0 <= self.max_overrun_fraction <= 1.0, "max_overrun_fraction", "must be within 0-1 (1: not judged)")
        require(0.0 < self.step_budget_fraction <= 100.0, "step_budget_fraction",
                "must be above 0, at most 100 (periods)")
        require(self.policy in ("warn", "hold", "trip"), "policy", 'must be "warn", "hold" or "trip"')


@dataclass(frozen=True)
class FlightRecorderConfig:
    """The flight recorder beside the loop (the recorder process; docs/recordings.md, "The flight
    recorder"): the last ``seconds`` of every telemetry topic held in memory as published, and
    written to an MCAP file on each trip, e-stop and stalled loop, from ``seconds`` before the
    event to ``after_s`` after it. Only a daemon that records (``--record-dir``) has one."""

    seconds: float = 30.0  # [s] of telemetry before the event each file holds
    after_s: float = 3.0  # [s] after it: what the safe state did

    def __post_init__(self):
        require(1.0 <= self.seconds <= 600.0, "seconds", "must be within 1-600 s")
        require(0.0 <= self.after_s <= 60.0, "after_s", "must be within 0-60 s")


@dataclass(frozen=True)
class ModelWatchConfig:
    """The rig's model beside the arm (docs/model.md): each cylinder joint's identified model
    is run on the commands the loop wrote, and the residual (measured minus predicted position)
    judged. Its RMS over the last ``window_s`` above ``band_deg`` for ``hold_s`` is drift: a
    ``model`` event naming the joint and the likely cause. ``band_deg`` is the rig's own: what
    its model's error is on the arm (the simulator's is its noise, about 0.05 deg); ``band_mm``
    a linear axis's."""

    enabled: bool = True  # run the model beside the loop (a process of its own)
    band_deg: float = 1.0  # the residual's RMS over window_s beyond this is drift [deg]
    band_mm: float = 1.0  # ... on a linear axis [mm]
    window_s: float = 2.0  # the residual's statistics are over this window [s]
    hold_s: float = 0.5  # outside the band this long before the event [s]
    recover_s: float = 10.0  # back inside the band this long after a drift before the event saying so [s]
    history_s: float = 30.0  # commands and residuals kept to name a cause from [s]
    publish_hz: float = 10.0  # the ``model`` topic's rate [Hz]

    def __post_init__(self):
        require(self.band_deg > 0, "band_deg", "must be > 0")
        require(self.band_mm > 0, "band_mm", "must be > 0")
        require(0.1 <= self.window_s <= 60.0, "window_s", "must be within 0.1-60 s")
        require(0.0 <= self.hold_s <= 60.0, "hold_s", "must be within 0-60 s")
        require(0.0 <= self.recover_s <= 3600.0, "recover_s", "must be within 0-3600 s")
        require(self.window_s <= self.history_s <= 600.0, "history_s", "must be within window_s-600 s")
        require(0.1 <= self.publish_hz <= 100.0, "publish_hz", "must be within 0.1-100 Hz")


@dataclass(frozen=True)
class TransportConfig:
    """Which backend moves the raw values; ``options`` are validated by that backend."""

    backend: str = "sim"
    options: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RigInfo:
    name: str
    description: str = ""
    controller: str = ""  # the controller the daemon starts with unless told otherwise (default: pid)
    controller_dirs: tuple[str, ...] = ()  # directories of controller plugin files, relative to the rig file

    def __post_init__(self):
        require(all(isinstance(d, str) and d for d in self.controller_dirs), "controller_dirs",
                "must be a list of directory paths (relative to the rig file)")
