"""pneumad under Bluesky (daemon/client/bluesky, docs/bluesky.md): a RunEngine runs the plans
against a real daemon and their 1 kHz records read back from a real Tiled server; a refused
move and a trip fail their plans with the daemon's words. The tests with daemons of their own
(a queue across two rigs, a rig with an array sensor) are in test_bluesky_rigs.py: here the
module's daemon is stopped once its last test is done."""
from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from tests import extras

if extras.missing("bluesky"):
    pytest.skip(extras.reason("bluesky"), allow_module_level=True)

import bluesky.plan_stubs as bps  # noqa: E402
import bluesky.preprocessors as bpp  # noqa: E402
from bluesky import RunEngine  # noqa: E402
from bluesky.callbacks.tiled_writer import TiledWriter  # noqa: E402
from bluesky.utils import FailedStatus  # noqa: E402
from tiled.client import from_uri  # noqa: E402
from tiled.server import SimpleTiledServer  # noqa: E402

from daemon.client.bluesky import plans  # noqa: E402
from daemon.client.bluesky.device import PneumadRig  # noqa: E402
from daemon.client.client import Client, RemoteError  # noqa: E402
from daemon.testing.daemons import STOP_WAIT_S
from tests.daemons import real_daemon, wait_for_own_daemon  # noqa: E402

# slow: each test's share of the file's ~160 s on a 2-core machine (tests/conftest.py orders files by the sum)
pytestmark = [pytest.mark.slow(seconds=32), pytest.mark.bluesky]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """One daemon, one Tiled server reading the plans' HDF5, one RunEngine writing to it."""
    tmp = tmp_path_factory.mktemp("bluesky")
    daemon, eps = real_daemon(tmp)
    with Client(**eps, timeout=5.0) as client:
        wait_for_own_daemon(client, daemon)
    (tmp / "h5").mkdir()
    server = SimpleTiledServer(directory=tmp / "tiled", readable_storage=[tmp / "h5"])
    tiled = from_uri(server.uri)
    engine = RunEngine({})
    engine.subscribe(TiledWriter(tiled))
    rig = PneumadRig.connect_to("arm", hdf5_directory=str(tmp / "h5"), **eps)
    try:
        yield rig, engine, tiled, eps
    finally:
        rig.close()
        server.close()
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)


@pytest.fixture(autouse=True)
def a_clear_daemon_after(request):
    """A test that leaves the module's daemon tripped (a plan failed on a lost lease, say) does not
    fail the tests after it: the daemon is reset, and that test's own failure says why."""
    yield
    if "setup" in request.fixturenames:
        with Client(**request.getfixturevalue("setup")[3], timeout=5.0) as client:
            if client.status()["state"] in ("fault", "estop"):
                client.acquire_lease()
                client.reset()
                client.release_lease()


def test_a_step_response_runs_as_a_plan_and_its_1khz_record_reads_back_from_tiled(setup):
    rig, engine, tiled, _ = setup
    (uid,) = engine(plans.step_response(rig, "bottom", 3.0, md={"sample": "none"}))
    run = tiled[uid]
    start = run.metadata["start"]
    assert start["rig_hash"] == rig.link.describe["rig"]["hash"] and start["controller"] == "pid"
    assert start["plan_name"] == "step_response" and start["sample"] == "none"
    record = run["record"]
    cycle = np.asarray(record["arm_record_cycle"].read())
    t = np.asarray(record["arm_record_t"].read())
    angle = np.degrees(np.asarray(record["arm_record_bottom_position"].read()))
    setpoint = np.degrees(np.asarray(record["arm_record_bottom_setpoint"].read()))
    # every cycle the loop ran (not a scan's points), from before the step to 3 s after it settled
    assert np.all(np.diff(cycle) == 1) and t[-1] - t[0] > 3.0
    changes = np.diff(setpoint)
    assert changes[np.flatnonzero(np.abs(changes) > 1.0)[-1]] == pytest.approx(3.0, abs=1e-3)  # a step, in one cycle
    assert angle[-1] == pytest.approx(setpoint[-1], abs=0.5)  # the run ended settled, as the plan waits for
    primary = run["primary"]
    before, after = np.asarray(primary["arm-joints-0-setpoint"].read())
    assert after - before == pytest.approx(3.0, abs=1e-3) and setpoint[-1] == pytest.approx(after, abs=1e-3)
    before, after = np.asarray(primary["arm-joints-0-position"].read())
    assert after - before == pytest.approx(3.0, abs=0.6)


def test_the_identification_plan_records_each_experiment_and_the_whole_in_a_file_identify_fits(setup, tmp_path):
    """Two short experiments (the plan takes a user's own list): each a stream of the run with the
    excitation in it, and the plan's daemon recording, named in the start document, fitted by
    ``pneumactl identify --from`` as a recording of its own."""
    rig, engine, tiled, _ = setup
    short = [{"signal": "prbs", "order": 5, "bit_s": 0.1}, {"signal": "prbs", "order": 4, "bit_s": 0.2}]
    (uid,) = engine(plans.identification(rig, "bottom", experiments=short))
    run = tiled[uid]
    start = run.metadata["start"]
    assert start["plan_name"] == "identification" and start["plan_args"]["experiments"] == short
    for stream, bits in (("record", 31), ("record_1", 15)):
        cycle = np.asarray(run[stream]["arm_record_cycle"].read())
        u = np.asarray(run[stream]["arm_record_bottom_u_v_mv"].read())
        switches = np.count_nonzero(np.abs(np.diff(u)) > 0.5)  # the PRBS's level changes, each in a cycle
        assert np.all(np.diff(cycle) == 1) and 0.25 * bits < switches <= bits, (stream, switches)
    assert rig.link.client.record_list()["active"] == []  # the plan's own recording has ended with it
    out = tmp_path / "fit"
    fitted = subprocess.run([sys.executable, "-m", "daemon.client.ctl", "identify", "bottom", "--from", start["recording"],
                             "--out", str(out), "--generations", "5"], capture_output=True, text=True, timeout=300)
    assert fitted.returncode == 0, fitted.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert [e["signal"] for e in report["experiments"]] == ["prbs", "prbs"] and (out / "rig.toml").exists()


def test_the_payload_plan_dithers_each_joint_about_the_balance_the_model_predicts(setup):
    """One of the routine's postures, each joint's dither three periods long (the routine's are
    21): a stream per reference (the move, then each joint's dither), the dithered joint's V_MV
    swinging by the dither's amplitude open loop, and its mean over whole periods (what the
    routine's estimate is made of) at the V_MV the model says holds the joint where it was
    (and moves it at its drift): the built-in rig carries no payload."""
    from controllers.nominal import NominalJoint
    from daemon.client import payload_routine
    from hal import config
    rig, engine, tiled, _ = setup
    rig_config = config.parse(rig.link.describe["rig"]["source"])
    names = [j.name for j in rig_config.joints]
    posture = max(payload_routine.postures(rig_config))  # one posture whatever ran before (156.6, -109.2 deg)
    (uid,) = engine(plans.payload_dithers(rig, postures=[posture], periods=3))
    run = tiled[uid]
    assert run.metadata["start"]["plan_args"] == {"postures": [posture], "periods": 3}
    setpoint = np.degrees(np.asarray(run["record"][f"arm_record_{names[-1]}_setpoint"].read()))
    assert setpoint[-1] == pytest.approx(posture[-1], abs=1e-3)  # the move's stream ends at the posture
    for k, name in enumerate(names, start=1):
        record = run[f"record_{k}"]
        assert np.all(np.diff(np.asarray(record["arm_record_cycle"].read())) == 1)
        u = np.asarray(record[f"arm_record_{name}_u_v_mv"].read())
        t = np.asarray(record["arm_record_t"].read())  # [s]: a loaded machine's loop runs late cycles
        args = payload_routine.dither_args(rig_config, name)
        period_s = args["period_s"]
        period = round(period_s * 1000)  # samples at least as long as a period, at most one a cycle of 1 ms
        swing = np.ptp(np.lib.stride_tricks.sliding_window_view(u, period), axis=1)
        dithering = np.flatnonzero(swing > 1.6 * args["amplitude_v"])  # windows holding a whole swing of it
        assert dithering.size, f"{name}: no dither in its stream (largest swing {swing.max():.2f} V)"
        begins = t[dithering[0]] + period_s / 2  # half a period in from either end: the dither alone
        whole = int((t[min(dithering[-1] + period, t.size - 1)] - period_s / 2 - begins) // period_s)
        assert whole >= 2, f"{name}: {whole} whole periods of dither"
        inside = (t >= begins) & (t < begins + whole * period_s)
        amplitude = 2.0 * abs(np.mean(u[inside] * np.exp(-2j * np.pi * t[inside] / period_s)))
        balance = u[inside].mean()
        # The model's balance where the joint was over those periods [V] (rig-facts [2-50] in steady
        # state: kt u = K (angle - neutral) - bias + D velocity; over whole periods the dither's own
        # motion averages out, the centring PI's slow drift does not: 3.4 deg in 6 s is 0.14 V here)
        angle = np.asarray(record[f"arm_record_{name}_position"].read())[inside]  # [rad]
        drift = (angle[-1] - angle[0]) / (t[inside][-1] - t[inside][0])  # [rad/s]
        joint = next(j for j in rig_config.joints if j.name == name)
        model = NominalJoint.from_rig(joint, rig_config.joint_params(joint))
        held = model.static_volts(float(angle.mean()), 0.0, 0.0) + model.D / model.kt * drift
        assert abs(math.degrees(angle.mean()) - posture[k - 1]) < args["band_deg"]  # centred on the posture
        assert amplitude == pytest.approx(args["amplitude_v"], rel=0.2), (name, amplitude)  # open loop: the signal's
        # three periods average less of the friction away than the routine's twelve: 0.04 V seen
        assert balance == pytest.approx(held, abs=0.12), (name, balance, held)


def test_a_joint_is_a_movable_and_a_refused_move_fails_with_the_daemons_data(setup):
    rig, engine, _, _ = setup
    joint = rig.joints[1]
    here = math.degrees(rig.link.client.sample()["middle.setpoint"])

    @bpp.stage_decorator([rig])
    def move(target):
        yield from bps.mv(joint, target)
    engine(move(here - 2.0))
    assert math.degrees(rig.link.client.sample()["middle.position"]) == pytest.approx(here - 2.0, abs=0.5)
    with pytest.raises(FailedStatus) as failed:
        engine(move(here + 200.0))  # far outside the joint's range
    refusal = failed.value.args[0].exception()
    assert isinstance(refusal, RemoteError) and refusal.code == "refused"
    assert refusal.data and refusal.data.get("joint") == "middle", refusal.data


def test_a_trip_fails_the_plan_with_the_daemons_cause(setup):
    rig, engine, _, eps = setup
    stopper = Client(**eps, timeout=5.0)

    def estop_once_the_path_runs():
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            status = stopper.status()
            if status["state"] == "enabled" and status["reference_remaining_s"] > 0.0:
                time.sleep(1.0)
                stopper.estop("a test's e-stop")
                return
            time.sleep(0.05)
    thread = threading.Thread(target=estop_once_the_path_runs, daemon=True)
    thread.start()
    try:
        with pytest.raises(FailedStatus) as failed:
            engine(plans.path_run(rig, "translation"))
        cause = failed.value.args[0].exception()
        assert isinstance(cause, RuntimeError) and "estop" in str(cause) and "a test's e-stop" in str(cause), cause
    finally:
        thread.join(130.0)
        stopper.acquire_lease()  # the run handed its lease back as it failed
        stopper.reset()
        stopper.release_lease()
        stopper.close()
