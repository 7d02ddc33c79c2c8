"""``pneumactl payload identify``'s routine (rig-facts §4), beside the loop: postures chosen for
identifiability, each joint's balance torque measured there with its friction dithered out,
an unloaded reference stored once, and the payload fitted by controllers.payload.

**Balance torque** [N m]: tau = K_mdl L (A_H P_H - A_L P_L) (rig-facts §1, the model's torque
scale K_mdl included), with P_H, P_L the pressures the loop commands through the ITV0051s
for the mean V_MV (after their lag they are the chambers').

**Static friction** holds a joint anywhere within +-Fs of its balance, so a torque read at rest
is ambiguous by up to Fs (on the middle joint as large as the heaviest payload's moment).
So each joint is **dithered** open loop at each posture: an input-side ``excite`` whose V_MV
is a sine of ``DITHER_FS`` times the joint's breakaway (Fs over its volts-to-torque, from
the model; at most ``DITHER_MAX_V``) at ``DITHER_HZ``, which keeps it sliding both ways,
about a centring PI that holds it at the posture; the mean V_MV over ``AVERAGED_S`` that end
a period before the dither does is the balance: inertia, damping and friction (odd in the
velocity of a symmetric motion) average out, and the centring PI has settled on what holds
the joint there. The window is placed on the dither's own clock (the daemon's
``reference_remaining_s``), never on the client's: a client's clock starts late by the
request's round trip, and a window ending on it took in the holding controller's V_MV after
the dither's end (up to 50 ms of samples a volt off: 5 mN m on the bottom joint, 5 g of mass,
which was the rounds' scatter; see :func:`window_mean`). (Tried first and
left behind: approaching each posture from both sides and averaging, and a 0.5 deg dither on
the set-point under the holding PID: the middle joint stuck through them, its torque off by
+-0.1 N m.) The unloaded reference is measured the same way, so the arm's own gravity,
spring and bias cancel in loaded minus unloaded.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from controllers.payload import PayloadEstimate, Posture, identify
from daemon.client.client import Interrupted, abort_started
from daemon.client.routine_lease import routine_lease
from hal import config
from hal.config import RigConfig
from hal.regulator import ITV0051

DITHER_FS = 2.0  # the dither's V_MV amplitude over the joint's breakaway V_MV (Fs / kt) ...
DITHER_MAX_V = 2.2  # ... and at most this [V]: the middle joint's range keeps room for its load
DITHER_HZ = 0.5
DITHER_BAND_DEG = 8.0  # the excursion the daemon allows the dither: the middle joint moves 5.7 deg at 2.2 V, 0.5 Hz
DITHER_S = 42.0  # the dither's length after its settling [s]
REST_S = 2.0  # what coming to rest after a move adds, in the routine's estimate [s]
AVERAGED_S = 24.0  # the mean is taken over this [s] (whole periods) ending END_GUARD_S before the
#                    dither does; the bottom joint's balance (0.85 N m per volt) then matches the
#                    payload's moment to about 0.2 mN m (the mass hangs on it: 1 mN m is about 1 g)
END_GUARD_S = 1.0 / DITHER_HZ  # the window ends this long (a period) before the dither does [s]
SAMPLE_GAP_S = 0.25  # a window is whole when samples reach within this of both its ends [s]
LEAD_S = 1.0  # sampling starts this long before the window opens, whatever the client's lag [s]
CENTRE_HZ = 0.1  # the centring PI's crossover: settled well within DITHER_S - AVERAGED_S - END_GUARD_S
MARGIN_DEG = DITHER_BAND_DEG + 2.0  # postures this far inside the joint limits: the dither's band and 2 deg more
HOLD_V = 0.75  # postures whose spring needs at most this V_MV (nominal model) [V]
REFERENCE_FORMAT = "pneumad-payload-reference/1"


@dataclass
class Arm:
    """What the routine needs of a daemon (a client's, or a loop's in a bench): move to angles
    [deg] and wait for rest; dither a joint (``excite`` with ``dither_args``) and return its
    mean V_MV [V] and mean angle [deg] over the dither's last ``seconds``."""

    move: Callable[[list[float]], None]
    dithered: Callable[[str, float], tuple[float, float]]


def window_mean(samples: Sequence[tuple[float, float, float]], seconds: float, joint: str) -> tuple[float, float]:
    """The mean V_MV [V] and angle [deg] over the dither's window from samples
    ``(remaining_s, u_volts, angle_deg)`` taken while it ran (``remaining_s``: how long the
    dither runs on, by the daemon's clock): those with ``END_GUARD_S < remaining_s <=
    END_GUARD_S + seconds``. RuntimeError unless samples reach both ends of the window (within
    ``SAMPLE_GAP_S``): a dither cut short (the joint left its band, the arm tripped) jumps to
    0 s remaining and leaves its window's end unseen."""
    inside = [row for row in samples if END_GUARD_S < row[0] <= END_GUARD_S + seconds]
    if (not inside or max(row[0] for row in inside) < END_GUARD_S + seconds - SAMPLE_GAP_S
            or min(row[0] for row in inside) > END_GUARD_S + SAMPLE_GAP_S):
        raise RuntimeError(f"the dither on joint {joint} did not run through its averaging window (cut by the "
                           f"daemon? see its events); nothing was measured")
    _, volts, angles = zip(*inside)
    return sum(volts) / len(volts), sum(angles) / len(angles)


def sampling_starts_s(duration_s: float, seconds: float) -> float:
    """How long after the ``excite`` reply (the dither lasting ``duration_s``) a client starts
    sampling for a window of ``seconds``: ``LEAD_S`` before it opens."""
    return max(duration_s - seconds - END_GUARD_S - LEAD_S, 0.0)


@dataclass
class Reading:
    """One posture's measurement: each joint's mean angle [deg] and balance torque [N m]."""

    angles_deg: list[float]
    torques_nm: list[float]


def dither_args(rig: RigConfig, joint: str) -> dict:
    """The input-side ``excite`` request that dithers ``joint`` (see the module)."""
    params = rig.joint_params(next(j for j in rig.joints if j.name == joint))
    return {"side": "input", "signal": "multisine", "joint": joint,
            "amplitude_v": round(min(DITHER_FS * params.Fs / params.torque_per_volt, DITHER_MAX_V), 3),
            "f0_hz": DITHER_HZ, "f1_hz": 2 * DITHER_HZ, "components": 1, "period_s": 1.0 / DITHER_HZ,
            "periods": int(DITHER_S * DITHER_HZ), "settle_s": 2.0, "band_deg": DITHER_BAND_DEG, "centre_hz": CENTRE_HZ}


def dither_s(rig: RigConfig, joint: str) -> float:
    """How long the daemon runs ``joint``'s dither [s]: its settling and its whole periods."""
    args = dither_args(rig, joint)
    return args["settle_s"] + args["periods"] * args["period_s"]


def posture_estimates_s(rig: RigConfig, targets: list[list[float]], here_deg: list[float]) -> list[float]:
    """What each posture should take [s] through :func:`client_arm`: its unhurried move (the
    pace ``identify`` moves at), ``REST_S`` to come to rest, and a dither per joint. A move the
    daemon slows, or a joint slow to rest, takes longer."""
    from daemon.client.identify import move_duration

    out = []
    for target in targets:
        out.append(move_duration(target, here_deg) + REST_S + sum(dither_s(rig, j.name) for j in rig.joints))
        here_deg = target
    return out


def postures(rig: RigConfig) -> list[list[float]]:
    """Postures [deg] the joints can hold with V_MV to spare (within ``HOLD_V`` of what their
    springs need at the neutral angle, by the joint's model, and ``MARGIN_DEG`` inside its
    limits: the rest is for the payload and the dither): the first joint at the low end,
    middle and high end of that span, each other joint at both ends. That turns the last link
    as far as the joints allow (the centre of mass needs it turned; the paper's 90 deg steps
    where the limits allow) and swings the links about gravity's line (the mass needs a
    moment arm). Ordered so the outer joints, the slow ones, move as seldom as they can."""
    spans = []
    for j in rig.joints:
        params = rig.joint_params(j)
        reach = HOLD_V * params.torque_per_volt / params.K if params is not None else math.inf  # [deg]
        spans.append((max(j.min_angle_deg + MARGIN_DEG, j.neutral_deg - reach),
                      min(j.max_angle_deg - MARGIN_DEG, j.neutral_deg + reach)))
    levels = [[lo, hi] for lo, hi in spans[1:]] + [[spans[0][0], sum(spans[0]) / 2, spans[0][1]]]
    grid = [[p[-1], *p[:-1]] for p in itertools.product(*levels)]  # the first joint varies fastest
    rows = [grid[i:i + 3] for i in range(0, len(grid), 3)]
    return [q for k, row in enumerate(rows) for q in (row if k % 2 == 0 else row[::-1])]  # back and forth


def joint_torques(rig: RigConfig, volts: Sequence[float]) -> list[float]:
    """Each joint's pneumatic torque [N m] for its V_MV [V] at rest (see the module)."""
    out = []
    for jc, u in zip(rig.joints, volts):
        p = rig.joint_params(jc)
        head = ITV0051(jc.head).pressure(jc.head.bias_volts + u)
        rod = ITV0051(jc.rod).pressure(jc.rod.bias_volts)
        out.append(p.K_mdl * p.L * (p.area_head * head - p.area_rod * rod))
    return out


def measure(arm: Arm, rig: RigConfig, targets: list[list[float]], progress=None) -> list[Reading]:
    """Per posture, each joint's balance torque [N m], its mean while dithered (see the
    module), and its mean angle then (a held joint stops short of its set-point by what its
    friction allows: the estimate corrects for it)."""
    out = []
    for k, target in enumerate(targets):
        arm.move(list(target))
        volts, angles = zip(*(arm.dithered(j.name, AVERAGED_S) for j in rig.joints))
        out.append(Reading(list(angles), joint_torques(rig, volts)))
        if progress is not None:
            progress(k + 1, len(targets), target, out[-1].torques_nm)
    return out


def save_reference(path: Path, rig: RigConfig, targets: list[list[float]], readings: list[Reading]) -> None:
    path.write_text(json.dumps({"format": REFERENCE_FORMAT, "arm_hash": arm_hash(rig), "postures_deg": targets,
                                "angles_deg": [r.angles_deg for r in readings],
                                "torques_nm": [r.torques_nm for r in readings]}, indent=1))


def arm_hash(rig: RigConfig) -> str:
    """What an unloaded reference depends on: the arm's geometry and its joints with their
    models (not the transport, nor a simulated payload's options)."""
    described = repr((rig.arm, rig.joints, [rig.joint_params(j) for j in rig.joints]))
    return hashlib.sha256(described.encode()).hexdigest()


def load_reference(path: Path, rig: RigConfig) -> tuple[list[list[float]], list[Reading]]:
    """The stored unloaded run; ValueError if it is not one, or was made on another rig file."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable payload reference: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != REFERENCE_FORMAT:
        raise ValueError(f"{path}: not a payload reference ({REFERENCE_FORMAT})")
    if data.get("arm_hash") != arm_hash(rig):
        raise ValueError(f"{path}: measured on another arm (its joints, models or geometry differ: hash "
                         f"{str(data.get('arm_hash'))[:12]}, the daemon's {arm_hash(rig)[:12]}): measure the "
                         f"unloaded reference again")
    columns = [data.get(k) for k in ("postures_deg", "angles_deg", "torques_nm")]
    n = len(rig.joints)
    if (not all(isinstance(c, list) and len(c) == len(columns[0]) for c in columns) or
            any(not isinstance(row, list) or len(row) != n or not all(isinstance(v, (int, float)) for v in row)
                for c in columns for row in c)):
        raise ValueError(f"{path}: postures, angles and torques do not match the rig's {n} joints")
    return columns[0], [Reading(a, t) for a, t in zip(columns[1], columns[2])]


def estimate(rig: RigConfig, unloaded: list[Reading], loaded: list[Reading]) -> PayloadEstimate:
    """The payload from the loaded run against the unloaded reference at the same postures.
    At rest the cylinders balance the payload's moment, so their torque changes by minus it;
    where a joint stood a little apart in the two runs, its spring's share (the model's K,
    N m/deg) is taken out."""
    springs = [rig.joint_params(j).K for j in rig.joints]
    rows = []
    for before, after in zip(unloaded, loaded):
        moved = [b - a for a, b in zip(before.angles_deg, after.angles_deg)]
        rows.append(Posture(tuple(math.radians(a) for a in after.angles_deg),
                            tuple(-(t1 - t0 - k * d) for t0, t1, k, d in
                                  zip(before.torques_nm, after.torques_nm, springs, moved))))
    return identify(rows, rig.arm.link_lengths_m, rig.arm.gravity_m_s2)


def client_arm(client, rig: RigConfig) -> Arm:
    """The routine's Arm through a daemon's client (it holds the lease): unhurried moves
    (refused ones slowed as the daemon says), rest judged joint by joint, V_MV and the angle
    from the latest cycle record beside the dither's time left from status (about 50 samples a
    second: plenty for a mean over whole periods)."""
    from daemon.client.identify import _move, setpoints_deg, _wait_for_rest

    names = [j.name for j in rig.joints]

    def move(target: list[float]) -> None:
        reply = _move(client, target, setpoints_deg(client, names))
        time.sleep(reply.get("duration_s", 0.0))
        for name in names:
            _wait_for_rest(client, name)

    def dithered(joint: str, seconds: float) -> tuple[float, float]:
        reply = client.call("excite", dither_args(rig, joint))
        time.sleep(sampling_starts_s(reply["duration_s"], seconds))
        rows = []
        with client.latest() as feed:
            while not rows or rows[-1][0] > END_GUARD_S:  # to the window's end, by the dither's clock
                s = client.status()
                row = feed.row()
                if s["state"] != "enabled":  # the safe state is written: no V_MV to balance
                    raise SystemExit(f"the arm left enabled during the dither ({s['state']}: {s['cause']}): no balance")
                rows.append((s["reference_remaining_s"], row[f"{joint}.u.v_mv"], math.degrees(row[f"{joint}.position"])))
                time.sleep(0.02)
        time.sleep(END_GUARD_S)  # the dither's end
        return window_mean(rows, seconds, joint)

    return Arm(move, dithered)


def run(client, reference: Path, unloaded: bool, apply: bool = False) -> dict:
    """``pneumactl payload identify``: the unloaded reference (``unloaded``), stored in
    ``reference``; or the loaded run against it, and the payload, given to the controllers
    as a known load (``load.set``) with ``apply``."""
    rig = config.parse(client.describe()["rig"]["source"], "<daemon>")
    if client.status()["state"] != "enabled":
        raise SystemExit("the arm is not enabled: `pneumactl enable` first (the routine moves it)")
    targets, before = (postures(rig), None) if unloaded else load_reference(reference, rig)
    from daemon.client.identify import setpoints_deg

    names = [j.name for j in rig.joints]
    here = setpoints_deg(client, names)
    estimates = posture_estimates_s(rig, targets, here)
    print(f"payload identify: {len(targets)} postures, each a move and a {dither_s(rig, names[0]):.0f} s dither per "
          f"joint: about {sum(estimates) / 60:.0f} min (Ctrl-C stops it)", file=sys.stderr, flush=True)
    started = time.monotonic()

    def show(k, n, target, torques):
        left = sum(estimates[k:])
        print(f"posture {k} of {n} at {', '.join(f'{a:.1f}' for a in target)} deg: torques "
              f"{', '.join(f'{t:.3f}' for t in torques)} N m ({(time.monotonic() - started) / 60:.1f} min in, "
              f"about {left / 60:.1f} min left)", file=sys.stderr, flush=True)

    with routine_lease(client):  # handed back at the end, Ctrl-C included (a lapsed one trips the enabled arm)
        try:
            readings = measure(client_arm(client, rig), rig, targets, show)
        except (KeyboardInterrupt, Interrupted):  # it stops what it started: the move or dither running
            raise Interrupted(f"interrupted: the payload routine stopped; "
                              f"{abort_started(client, 'its move or dither')}; nothing was stored or applied") from None
        if unloaded:
            save_reference(reference, rig, targets, readings)
            return {"reference": str(reference), "postures_deg": targets,
                    "torques_nm": [r.torques_nm for r in readings]}
        found = estimate(rig, before, readings).as_dict()
        if apply:
            found["applied"] = client.set_load(found["mass_kg"], found["com_mm"])
        return found
