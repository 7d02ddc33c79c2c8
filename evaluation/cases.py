"""What an evaluation runs: plant variations and references on a rig.

Plants perturb the true plant (the simulator's per-joint ``overrides``) about the rig's own
model sets; the controllers keep their nominal models. The sets:
- ``nominal``: the rig's model with its sensor noise;
- ``thesis``: the nominal plant and the corners of the thesis's gain uncertainty set (rig-facts §1,
  "Robust-control view": K_unc in [K_min, K_max] times the nominal plant, 0.41..1.41 bottom,
  0.59..1.41 middle);
- ``grid``: the robustness grid (bench/robustness.py): nominal with and without noise, then
  the corners of gain x0.41..x1.41 per joint, friction and viscous terms (Fs, Fc, D) x0.7..x1.5,
  dead time x0.8..x1.2 (16 corners);
- a TOML file of ``[[plants]]`` tables (name, gain = [per joint], friction, delay, damping, noise).

References (a trajectory each, on the rig's arm): the thesis's translation (15 s) and circle (at
the shortest period the rig's authority allows), the unseen paths (a vertical line, a
figure-eight, a square) each at the fastest the rig's feasibility check accepts, ``steps``
(+5 deg on every joint from the translation's start, held 3 s, and back), or a waypoint CSV file
(``pneumactl waypoints``' format).
"""
from __future__ import annotations

import itertools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from controllers import trajectory
from controllers.base import ControllerContext
from controllers.feasibility import Authority
from daemon.client.client import read_waypoints
from hal import config
from hal.config import RigConfig
from hal.errors import ConfigError
from hal.interfaces import ROTARY
from hal.joints import CYLINDER

BUILTINS = ["pid", "smc", "smc_dob", "sac", "lti", "lti_dob"]  # the cylinder rig's (--all; the robustness bench's)
PLANT_SETS = ("nominal", "thesis", "grid")
PATHS = ("translation", "circle", "line", "figure-eight", "square", "steps")
THESIS_GAIN = {"bottom": (0.41, 1.41), "middle": (0.59, 1.41)}  # K_min, K_max (rig-facts §1)
SQUARE_MM = [(20.0, 125.0), (40.0, 125.0), (40.0, 145.0), (20.0, 145.0), (20.0, 125.0)]  # 20 mm sides about (30, 135)
STEP_DEG, STEP_HOLD_S = 5.0, 3.0


def check_rig(rig: RigConfig) -> None:
    """Refuse a rig the evaluation has no model for: the references are the planar arm's paths
    and the plant variations perturb the cylinder joint's identified model (K_mdl, Fs, Fc, D,
    T_dly), so its joints must be rotary cylinder joints with models and a simulated transport."""
    odd = [j.name for j in rig.joints if (j.kind, j.actuation) != (ROTARY, CYLINDER)]
    if odd:
        raise ConfigError(f"joint(s) {', '.join(odd)} are not rotary cylinder joints; the evaluation's "
                          "paths and plant variations are the planar cylinder arm's (rig-facts §1)")
    missing = [j.name for j in rig.joints if rig.joint_params(j) is None]
    if missing:
        raise ConfigError(f"joint(s) {', '.join(missing)} have no identified model to simulate")
    if rig.transport.backend != "sim":
        raise ConfigError(f"runs on the rig's model (transport 'sim'); this rig names "
                          f"{rig.transport.backend!r}: give a copy with [transport] backend = \"sim\"")


@dataclass(frozen=True)
class Plant:
    name: str
    gain: tuple[float, ...] = ()  # K_mdl factor per joint (none given: 1)
    friction: float = 1.0  # Fs, Fc factor
    delay: float = 1.0  # T_dly factor
    noise: bool = True
    damping: float | None = None  # D factor; None: the friction factor (Fs, Fc and D together)

    def sim_options(self, rig: RigConfig | None = None) -> dict:
        """The simulator's options for this plant: overrides about the rig's own models (default:
        the built-in simulated rig's)."""
        rig = rig or config.load()
        joints = {}
        damping = self.friction if self.damping is None else self.damping
        for j, joint in enumerate(rig.joints):
            n = rig.joint_params(joint)
            gain = self.gain[j] if j < len(self.gain) else 1.0
            joints[joint.name] = {"overrides": {"K_mdl": n.K_mdl * gain, "Fs": n.Fs * self.friction,
                                                "Fc": n.Fc * self.friction, "D": n.D * damping,
                                                "T_dly": n.T_dly * self.delay}}
        return {"joints": joints, **({} if self.noise else {"adc_noise_volts": 0.0})}


def grid(quick: bool = False) -> list[Plant]:
    """The robustness grid: nominal without and with noise, then the corners."""
    out = [Plant("nominal, no noise", noise=False), Plant("nominal")]
    gains = [(0.41, 0.41), (1.41, 1.41)] if quick else list(itertools.product((0.41, 1.41), repeat=2))
    for g, f, d in itertools.product(gains, (0.7, 1.5), (0.8, 1.2)):
        out.append(Plant(f"gain {g[0]:g}/{g[1]:g}, friction x{f:g}, delay x{d:g}", g, f, d))
    return out


def thesis(rig: RigConfig) -> list[Plant]:
    """The nominal plant and the corners of the thesis's gain set (joints it gives no range: x1)."""
    ranges = [THESIS_GAIN.get(j.name, (1.0, 1.0)) for j in rig.joints]
    corners = sorted(set(itertools.product(*ranges)))
    return [Plant("nominal")] + [Plant("gain " + "/".join(f"{g:g}" for g in c), c) for c in corners]


def plants(spec: str, rig: RigConfig) -> list[Plant]:
    if spec == "nominal":
        return [Plant("nominal")]
    if spec == "thesis":
        return thesis(rig)
    if spec == "grid":
        return grid()
    return plants_file(spec, len(rig.joints))


def plants_file(path: str, n: int) -> list[Plant]:
    """``[[plants]]`` tables of a TOML file; a clear error for anything else."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except FileNotFoundError:
        raise ConfigError(f"--plants {path!r}: neither {', '.join(PLANT_SETS)} nor a file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    rows = data.get("plants")
    if not isinstance(rows, list) or not rows:
        raise ConfigError(f"{path}: expected [[plants]] tables")
    out = []
    known = {"name", "gain", "friction", "delay", "damping", "noise"}
    for i, row in enumerate(rows):
        where = f"{path}: plants[{i}]"
        unknown = sorted(set(row) - known)
        if unknown:
            raise ConfigError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})")
        gain = row.get("gain", [1.0] * n)
        gain = [gain] * n if isinstance(gain, (int, float)) else gain
        factors = [*gain, row.get("friction", 1.0), row.get("delay", 1.0), row.get("damping", 1.0)]
        if len(gain) != n or not all(isinstance(x, (int, float)) and math.isfinite(x) and x > 0 for x in factors):
            raise ConfigError(f"{where}: gain (one per joint, or one for all), friction, delay and damping "
                              "must be positive numbers")
        out.append(Plant(str(row.get("name", f"plant {i + 1}")), tuple(float(g) for g in gain),
                         float(row.get("friction", 1.0)), float(row.get("delay", 1.0)),
                         bool(row.get("noise", True)), row.get("damping")))
    return out


def authority(rig: RigConfig, context: ControllerContext, fraction: float | None = None) -> Authority:
    return Authority.of(rig, context, rig.limits.authority_fraction if fraction is None else fraction)


def _shape(rig: RigConfig, name: str, scale: float) -> trajectory.Trajectory:
    lengths, elbow, n = rig.arm.link_lengths_m, rig.arm.elbow, len(rig.joints)
    if name == "line":
        return trajectory.line(lengths, elbow, n, 10.0 * scale, (30.0, 110.0), (30.0, 160.0))
    if name == "figure-eight":
        return trajectory.figure_eight(lengths, elbow, n, 20.0 * scale, (30.0, 135.0), 20.0, 20.0)
    return trajectory.cartesian_waypoints(lengths, elbow, n, SQUARE_MM, [5.0 * scale] * 4)


def reference(rig: RigConfig, context: ControllerContext, name: str) -> trajectory.Trajectory:
    """A named reference (module docstring) or a waypoint CSV file's path; ValueError when it
    cannot run on this rig (outside the workspace, or no time the rig's authority allows)."""
    lengths, elbow, n = rig.arm.link_lengths_m, rig.arm.elbow, len(rig.joints)
    if name == "translation":
        return trajectory.translation(lengths, elbow, n, 15.0)
    if name == "circle":  # the lab comparison's: the whole of V_MV's range, the rig's physical limit
        shortest = authority(rig, context, 1.0).shortest(trajectory.circle(lengths, elbow, n, 1.0))
        return trajectory.circle(lengths, elbow, n, _tenths(shortest, "circle"))
    if name in ("line", "figure-eight", "square"):
        shortest = authority(rig, context).shortest(_shape(rig, name, 1.0))
        return _shape(rig, name, _tenths(shortest, name) / _shape(rig, name, 1.0).duration)
    if name == "steps":
        q0 = trajectory.translation(lengths, elbow, n, 15.0).sample(0.0)[0]
        up = [q + math.radians(STEP_DEG) for q in q0]
        return trajectory.Steps([list(q0), up, list(q0)], [STEP_HOLD_S] * 3)
    return waypoints_file(rig, name)


def _tenths(shortest: float | None, name: str) -> float:
    if shortest is None:
        raise ValueError(f"{name}: no duration this rig's authority allows")
    return math.ceil(shortest * 10.0) / 10.0


def waypoints_file(rig: RigConfig, path: str) -> trajectory.Trajectory:
    if not Path(path).is_file():
        raise ValueError(f"--reference {path!r}: neither {', '.join(PATHS)} nor a waypoint file")
    args = read_waypoints(path, [(j.name, "deg") for j in rig.joints])  # rotary joints only: check_rig
    if "xy_mm" in args:
        return trajectory.cartesian_waypoints(rig.arm.link_lengths_m, rig.arm.elbow, len(rig.joints),
                                              args["xy_mm"], args["durations_s"])
    points = args["positions"]
    return trajectory.joint_waypoints([[math.radians(a) for a in p] for p in points], args["durations_s"])


def default_references(plant: Plant) -> list[str]:
    """The robustness grid's paths: the circle on the nominal plants only."""
    return [p for p in PATHS if p != "steps" and (p != "circle" or plant.name.startswith("nominal"))]
