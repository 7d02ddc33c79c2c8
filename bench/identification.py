"""Identification validated on the simulator (issue: "Honest validation on the simulator").

    python -m bench.identification [--quick] [--generations N] [--out DIR] [--cases NAME ...]

Each case perturbs the simulated plant of one joint (its ``transport.options`` overrides: the
rig file's ``[[joints]] model``, the identifier's prior, stays the nominal one), runs the
``pneumactl identify`` workflow through the real loop on a virtual clock (the planner, the
open-loop experiments, the telemetry, an MCAP recording, :func:`daemon.client.identify.analyse`), and
compares the identified parameters with the perturbed truth. Then it runs the translation path
with a model-based controller on the perturbed plant twice: designed on the stale nominal
model, and on the identified one.

**Torque scale.** From V_MV to the angle, scaling every torque of the model (the gain K_mdl
and J, D, K, Fs, Fc together) changes nothing, so the identifier holds K_mdl at the prior's
value and the truth is compared in those terms: a gain perturbed by g reads as J, D, K, Fs, Fc
divided by g. The "gain" row is the joint's velocity gain K_mdl L A_H K_ep / D [deg/s per V].
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from bench import scenarios
from controllers.identification.simulate import FITTED
from daemon.client import identify
from daemon.recordings import mcap_log
from daemon.client.client import RemoteError
from hal import config
from hal.identified import JointParams

CONTROLLERS = ("smc", "smc_dob")  # model-based: SMC's design (and the DOB's observer) use the nominal model


@dataclass(frozen=True)
class Case:
    name: str
    joint: str
    factors: dict  # parameter -> factor on the built-in value (the perturbed truth)


CASES = [
    Case("bottom-seed", "bottom", {}),
    Case("middle-seed", "middle", {}),
    Case("bottom-a", "bottom", {"K_mdl": 1.3, "J": 1.3, "Fs": 0.7, "Fc": 0.7, "T_dly": 1.3}),
    Case("bottom-b", "bottom", {"K_mdl": 0.75, "D": 1.3, "Fs": 1.3, "Fc": 1.3, "T_dly": 0.7}),
    Case("middle-a", "middle", {"K_mdl": 1.3, "D": 0.75, "Fs": 0.8, "T_dly": 1.3}),
    Case("middle-b", "middle", {"K_mdl": 0.8, "J": 0.7, "Fs": 1.25, "Fc": 1.3, "T_dly": 0.75}),
]
TOLERANCE = {"gain": 0.05, "D": 0.05, "T_dly": 0.05, "Fs": 0.15, "Fc": 0.15}  # the goals
NOISE = "adc_noise_volts = 0.0005"  # the rig's sensor noise (the built-in rig's own)


def nominal(joint: str) -> JointParams:
    """The built-in rig's model of ``joint`` (the identifier's prior)."""
    rig = config.load()
    return rig.joint_params(next(j for j in rig.joints if j.name == joint))


def truth(case: Case) -> JointParams:
    base = nominal(case.joint)
    return base.replace({k: getattr(base, k) * f for k, f in case.factors.items()})


def comparable(params: JointParams, prior: JointParams) -> dict:
    """The identifiable figures: torques scaled to the prior's K_mdl (see the module's note)."""
    s = prior.K_mdl / params.K_mdl
    out = {n: getattr(params, n) * (s if n in ("J", "D", "K", "Fs", "Fc") else 1.0) for n in FITTED if n != "K_mdl"}
    out["gain"] = params.torque_per_volt / params.D  # [deg/s per V]
    return out


def rig_text(case: Case) -> str:
    text = resources.files("hal").joinpath("sim_2joint.toml").read_text()
    assert NOISE in text
    overrides = ", ".join(f"{k} = {v!r}" for k, v in
                          {k: getattr(truth(case), k) for k in case.factors}.items())
    return text + f"\n[transport.options.joints.{case.joint}]\noverrides = {{{overrides}}}\n" if overrides else text


def record(case: Case, plan: identify.Plan, path: Path) -> None:
    """The open-loop experiments through the real loop (virtual clock), recorded as MCAP."""
    from daemon.testing.loop import call, dealer, make_loop, ok, run_seconds  # the in-process daemon
    loop, captured, srv = make_loop(rig_text(case), server=True)
    try:
        sock = dealer(srv)
        lease = ok(loop, sock, "lease.acquire", {"ttl_s": 60.0})["lease"]
        ok(loop, sock, "enable", lease=lease)
        run_seconds(loop, 3.0)
        describe, controller = ok(loop, sock, "describe"), ok(loop, sock, "controller.get")
        j = [d["name"] for d in describe["joints"]].index(case.joint)
        rig = loop.rig
        prior = rig.joint_params(rig.joints[j])
        here = [math.degrees(a) for a in loop.reference[0]]
        target = identify.operating_point(rig, j, here, 10.0)
        reply = ok(loop, sock, "set", {"angles_deg": target, "duration_s": identify.move_duration(target, here)},
                   lease)
        run_seconds(loop, reply["duration_s"])
        _rest(loop, j, run_seconds)
        u_range = (describe["joints"][j]["u_min_volts"], describe["joints"][j]["u_max_volts"])
        for signal, settings in plan.experiments:
            ok(loop, sock, "lease.renew", lease=lease)  # the clock is virtual: the lease counts its seconds
            u_op = identify.holding_volts(rig, case.joint, math.degrees(loop.reference[0][j]))
            args = {"side": "input", "signal": signal, "joint": case.joint, "settle_s": plan.settle_s,
                    "centre_hz": identify.CENTRE_HZ, **settings}
            reply = identify.excite_fitting(lambda v: _result(call(loop, sock, "excite", {**args, "amplitude_v": v},
                                                                   lease)),
                                            signal, identify.default_amplitude(prior, u_op, u_range), fixed=False)
            run_seconds(loop, reply["duration_s"] + 0.05)
            _rest(loop, j, run_seconds)
        with open(path, "wb") as f:
            rec = mcap_log.McapRecording(f, describe, controller)
            for topic, message in captured.messages:
                rec.write(topic, message)
            rec.finish()
    finally:
        srv.close()


def _result(reply: dict) -> dict:
    """A reply's result, or its error raised as the client would."""
    if reply["ok"]:
        return reply["result"]
    error = reply["error"]
    raise RemoteError(error["code"], error["message"], error.get("data"))


def _rest(loop, j: int, run_seconds, timeout_s: float = 30.0) -> None:
    """As :func:`daemon.client.identify._wait_for_rest`, on the loop's own angles."""
    window = []
    for _ in range(int(timeout_s / 0.05)):
        run_seconds(loop, 0.05)
        window = (window + [math.degrees(loop.angles[j])])[-10:]
        ref = math.degrees(loop.reference[0][j])
        if len(window) == 10 and max(window) - min(window) < identify.REST_SPREAD_DEG and \
                all(abs(a - ref) < identify.REST_DEG for a in window):
            return


def tracking(case: Case, rig_path: str | None, controller: str) -> float:
    """RMS joint error [deg] of ``controller`` on the translation path, on the perturbed plant,
    designed on the rig file's model (None: the built-in, stale one)."""
    pinned = {case.joint: {"model": config.load().joints[[j.name for j in config.load().joints].index(case.joint)]
                           .model_name, "overrides": {k: getattr(truth(case), k) for k in case.factors}}}
    loop = scenarios.make_loop(controller, rig=rig_path or "sim", options=scenarios.example_options(controller),
                               plant={"joints": pinned}, replace=scenarios.NO_TRACKING_RULE)
    path = scenarios.make_path(loop, "translation", 20.0)
    result = scenarios.run_path(loop, path)
    return result.joint_rms[[j.name for j in loop.rig.joints].index(case.joint)]


def run_case(case: Case, plan: identify.Plan, generations: int, out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "experiments.mcap"
    started = time.perf_counter()
    record(case, plan, path)
    recorded_s = time.perf_counter() - started
    report = identify.analyse(path, case.joint, out, 40, generations)
    prior = nominal(case.joint)
    want, got = comparable(truth(case), prior), comparable(JointParams(**{**vars(prior), **report["params"]}), prior)
    errors = {k: got[k] / want[k] - 1.0 for k in want}
    covered = coverage(want, got, report["stated_std"])
    stale = {c: tracking(case, None, c) for c in CONTROLLERS}
    rebuilt = {c: tracking(case, report["rig_file"], c) for c in CONTROLLERS}
    return {"case": case, "want": want, "got": got, "errors": errors, "fit": report["fit_percent"],
            "heldout": report["heldout_fit_percent"][0], "fit_s": report["wall_s"],
            "generations": report["generations"], "recorded_s": recorded_s, "stale_rms": stale,
            "rebuilt_rms": rebuilt, "out": out, "covered": covered, "prior_heldout": report["prior_heldout_fit_percent"]}


COVERED = ("D", "K", "T_ep", "T_dly", "Fs", "Fc")  # the fitted parameters with a stated uncertainty


def coverage(want: dict, got: dict, stated: dict) -> dict[str, bool]:
    """Per fitted parameter, whether its error is within 2 stated sigma: relative for the log
    parameters, in seconds for T_dly, in Fc/Fs for Fc (the fit's search coordinates)."""
    out = {}
    for name in COVERED:
        if name == "T_dly":
            error, sigma = got[name] - want[name], stated["T_dly"]
        elif name == "Fc":
            error, sigma = got["Fc"] / got["Fs"] - want["Fc"] / want["Fs"], stated["Fc_ratio"]
        else:
            error, sigma = math.log(got[name] / want[name]), stated[name]
        out[name] = bool(abs(error) <= 2.0 * sigma) if sigma == sigma else False  # nan: nothing stated
    return out


def table(rows: list[dict]) -> str:
    keys = ("gain", "D", "K", "T_ep", "T_dly", "Fs", "Fc")
    head = ("| case | perturbed (x built-in) | " + " | ".join(f"{k} err" for k in keys)
            + " | within 2 sigma | Fit fitted / held out (prior held out) | fit time | " + " | ".join(f"{c} RMS stale -> rebuilt" for c in CONTROLLERS)
            + " |")
    lines = [head, "|" + "---|" * (len(keys) + 5 + len(CONTROLLERS))]
    for r in rows:
        def cell(k):
            e = r["errors"][k] * 100
            mark = " **x**" if k in TOLERANCE and abs(e) > TOLERANCE[k] * 100 else ""
            return f"{e:+.1f} %{mark}"
        perturbed = ", ".join(f"{k} {v:g}" for k, v in r["case"].factors.items()) or "none (the seed's values)"
        lines.append(f"| {r['case'].name} | {perturbed} | " + " | ".join(cell(k) for k in keys)
                     + f" | {sum(r['covered'].values())} of {len(r['covered'])}"
                     + (f" (not: {', '.join(k for k, v in r['covered'].items() if not v)})"
                        if not all(r["covered"].values()) else "")
                     + f" | {' / '.join(f'{v:.1f}' for v in r['fit'])} / {r['heldout']:.1f} % "
                     f"({r['prior_heldout']:.1f} %) | "
                     f"{r['fit_s']:.0f} s ({r['generations']} gen.) | "
                     + " | ".join(f"{r['stale_rms'][c]:.2f} -> {r['rebuilt_rms'][c]:.2f} deg" for c in CONTROLLERS) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.identification", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the quick experiments (pneumactl identify --quick)")
    ap.add_argument("--generations", type=int, default=1500)
    ap.add_argument("--out", default="bench-identification")
    ap.add_argument("--cases", nargs="*", default=None, help=f"of {', '.join(c.name for c in CASES)}")
    args = ap.parse_args(argv)
    cases = [c for c in CASES if not args.cases or c.name in args.cases]
    plan = identify.Plan.of(args.quick)
    rows = []
    for case in cases:
        print(f"--- {case.name}", file=sys.stderr, flush=True)
        rows.append(run_case(case, plan, args.generations, Path(args.out) / case.name))
    print(f"python -m bench.identification {' '.join(argv if argv is not None else sys.argv[1:])}  "
          f"({os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d')})")
    print(table(rows))
    hits = [v for r in rows for v in r["covered"].values()]
    print(f"\ncoverage: {sum(hits)} of {len(hits)} fitted parameters ({sum(hits) / max(len(hits), 1):.0%}) within "
          f"2 stated sigma of the truth")
    return 0


if __name__ == "__main__":
    sys.exit(main())
