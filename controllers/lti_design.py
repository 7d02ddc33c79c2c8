"""LTI controller designs: the file format, its checks, and the continuous-to-discrete helper.

A design is one SISO state-space controller per joint, made elsewhere (a model-reduced
mu-synthesis design of rig-facts §1, a loop-shaping design, a PI written as matrices):

    x[k+1] = A x[k] + B e[k],   u[k] = C x[k] + D e[k]

with e = r - th the joint's tracking error (in rad or deg, as the design says) and u = V_MV
[V]. A continuous design (dt = 0: x' = A x + B e) is discretised at the loop period by
scipy.signal.cont2discrete (default Tustin, ``method`` in the file); a discrete one must
have been made at the loop period. Files are TOML or numpy .npz:

TOML::

    [joints.bottom]
    input = "error_deg"      # or "error_rad"
    dt = 0.0                 # 0: continuous; else the sampling period [s] it was made for
    method = "bilinear"      # for continuous designs: zoh, foh, bilinear, backward_diff, euler
    A = [[0.0]]
    B = [[1.0]]
    C = [[0.623]]
    D = [[0.81]]

.npz: arrays ``<joint>.A``, ``<joint>.B``, ``<joint>.C``, ``<joint>.D`` and optionally
``<joint>.dt``, ``<joint>.input``, ``<joint>.method`` (0-d arrays).

On the wire (``controller.switch`` with ``options.design``) a design is the same map as the
TOML file, ``{"joints": {name: {...}}}``: the client reads the file, the daemon checks it.
``python -m controllers.lti_design FILE [--dt 0.001] [--out FILE.npz]`` prints what the
daemon would run (discrete matrices, poles, static gain) and can save it.
"""
from __future__ import annotations

import argparse
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controllers.base import ParamError

EXAMPLE = Path(__file__).resolve().parent / "designs" / "pi_thesis.toml"  # the thesis's PI as matrices
MAX_ORDER = 32  # states per joint: a model-reduced design is far smaller; bounds a hostile message
INPUTS = {"error_rad": 1.0, "error_deg": 180.0 / math.pi}  # scale from rad to the design's input unit
METHODS = ("zoh", "foh", "bilinear", "backward_diff", "euler")
FIELDS = {"A", "B", "C", "D", "dt", "input", "method"}


@dataclass(frozen=True)
class DiscreteDesign:
    """One joint's controller at the loop period; e in rad (scaled in), u in V."""

    a: np.ndarray  # (n, n)
    b: np.ndarray  # (n, 1), per rad of error
    c: np.ndarray  # (1, n) [V]
    d: float  # [V/rad]

    @property
    def order(self) -> int:
        return self.a.shape[0]

    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.a) if self.order else np.zeros(0)

    def static_gain(self) -> float:
        """u/e at steady state [V/rad]; inf for a design with an integrator."""
        i_a = np.eye(self.order) - self.a
        if self.order and abs(np.linalg.det(i_a)) < 1e-12:
            return math.inf
        return float((self.c @ np.linalg.solve(i_a, self.b))[0, 0] + self.d) if self.order else self.d


def discretise(a, b, c, d, dt: float, method: str = "bilinear"):
    """(A, B, C, D) of x' = A x + B e, u = C x + D e sampled at dt [s] by ``method``."""
    from scipy.signal import cont2discrete  # here, off the loop: at module level it cost
    # the loop's process 1-2 s of every daemon start
    ad, bd, cd, dd, _ = cont2discrete((a, b, c, d), dt, method=method)
    return ad, bd, cd, dd


def read_file(path: str | Path) -> dict:
    """A design file (TOML or .npz) as the wire map ``{"joints": {name: {...}}}``, lists and numbers."""
    path = Path(path)
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as data:
            joints: dict[str, dict] = {}
            for key in data.files:
                joint, _, field = key.rpartition(".")
                if not joint or field not in FIELDS:
                    raise ParamError(f"{path}: array {key!r} is not <joint>.<{'|'.join(sorted(FIELDS))}>")
                value = data[key]
                joints.setdefault(joint, {})[field] = value.item() if value.ndim == 0 else value.tolist()
        return {"joints": joints}
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ParamError(f"{path}: not a TOML design: {exc}") from None


def parse(design: object, joint_names: tuple[str, ...], dt: float) -> list[DiscreteDesign]:
    """Check a design map and make it run at the loop period; ParamError says what is wrong."""
    if not isinstance(design, dict) or not isinstance(design.get("joints"), dict):
        raise ParamError("the design must be a map with a 'joints' map (one entry per joint)")
    joints = design["joints"]
    unknown = sorted(map(str, set(joints) - set(joint_names)))
    if unknown:
        raise ParamError(f"the design names joint {unknown[0]!r}, which this rig does not have "
                         f"(joints: {', '.join(joint_names)})")
    missing = [n for n in joint_names if n not in joints]
    if missing:
        raise ParamError(f"the design has no controller for joint(s) {', '.join(missing)}")
    return [_joint(name, joints[name], dt) for name in joint_names]


def _joint(name: str, raw: object, dt: float) -> DiscreteDesign:
    if not isinstance(raw, dict):
        raise ParamError(f"design for {name}: expected a map of A, B, C, D")
    extra = sorted(map(str, set(raw) - FIELDS))
    if extra:
        raise ParamError(f"design for {name}: unknown field {extra[0]!r} (known: {', '.join(sorted(FIELDS))})")
    unit = raw.get("input", "error_rad")
    if unit not in INPUTS:
        raise ParamError(f"design for {name}: input must be one of {', '.join(INPUTS)}, got {unit!r}")
    method = raw.get("method", "bilinear")
    if method not in METHODS:
        raise ParamError(f"design for {name}: method must be one of {', '.join(METHODS)}, got {method!r}")
    design_dt = raw.get("dt", 0.0)
    if isinstance(design_dt, bool) or not isinstance(design_dt, (int, float)) or not design_dt >= 0:
        raise ParamError(f"design for {name}: dt must be 0 (continuous) or a sampling period in s, got {design_dt!r}")
    a, b, c, d = (_matrix(name, key, raw.get(key)) for key in "ABCD")
    n = a.shape[0]
    if n > MAX_ORDER:
        raise ParamError(f"design for {name}: order {n} exceeds {MAX_ORDER}; reduce the model first")
    if a.shape != (n, n) or b.shape != (n, 1) or c.shape != (1, n) or d.shape != (1, 1):
        raise ParamError(f"design for {name}: a SISO controller needs A n x n, B n x 1, C 1 x n, D 1 x 1; got "
                         f"A {a.shape[0]}x{a.shape[1]}, B {b.shape[0]}x{b.shape[1]}, "
                         f"C {c.shape[0]}x{c.shape[1]}, D {d.shape[0]}x{d.shape[1]}")
    if design_dt == 0.0:
        if n:
            a, b, c, d = discretise(a, b, c, d, dt, method)
    elif not math.isclose(design_dt, dt, rel_tol=1e-9):
        raise ParamError(f"design for {name}: made for dt = {design_dt} s but the loop runs at {dt} s; "
                         "give the continuous design (dt = 0) or discretise it at the loop period")
    scale = INPUTS[unit]
    return DiscreteDesign(np.asarray(a, float), np.asarray(b, float) * scale, np.asarray(c, float),
                          float(np.asarray(d)[0, 0]) * scale)


def _matrix(name: str, key: str, raw: object) -> np.ndarray:
    if raw is None:
        raise ParamError(f"design for {name}: matrix {key} is missing")
    rows = raw if isinstance(raw, list) else None
    if rows is not None and rows and not isinstance(rows[0], list):
        rows = [rows]  # a row vector written flat
    if rows is None or any(not isinstance(r, list) for r in rows):
        raise ParamError(f"design for {name}: {key} must be a list of rows")
    if rows and len({len(r) for r in rows}) != 1:
        raise ParamError(f"design for {name}: the rows of {key} differ in length")
    for r in rows:
        for v in r:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ParamError(f"design for {name}: {key} must hold finite numbers, got {v!r}")
    return np.array(rows, dtype=float).reshape(len(rows), len(rows[0]) if rows else 0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m controllers.lti_design", description=__doc__.splitlines()[0])
    ap.add_argument("file", help="design file, .toml or .npz")
    ap.add_argument("--dt", type=float, default=0.001, help="loop period [s] (default 0.001)")
    ap.add_argument("--out", help="save the discrete design here (.npz, dt = the loop period, input in rad)")
    args = ap.parse_args(argv)
    raw = read_file(args.file)
    names = tuple(raw.get("joints", {}))
    designs = parse(raw, names, args.dt)
    arrays = {}
    np.set_printoptions(precision=6, suppress=False)
    for name, d in zip(names, designs):
        gain = d.static_gain()
        print(f"{name}: order {d.order}, poles |z| max {max(abs(d.poles()), default=0.0):.6f}, "
              f"static gain {'integrating' if math.isinf(gain) else f'{gain:.4g} V/rad'}")
        print(f"  A =\n{d.a}\n  B =\n{d.b}\n  C =\n{d.c}\n  D = {d.d}")
        arrays.update({f"{name}.A": d.a, f"{name}.B": d.b, f"{name}.C": d.c, f"{name}.D": np.array([[d.d]]),
                       f"{name}.dt": np.array(args.dt), f"{name}.input": np.array("error_rad")})
    if args.out:
        np.savez(args.out, **arrays)
        print(f"saved the discrete design at dt = {args.dt} s to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
