"""``pneumactl evaluate``: its fast engine gives the daemon's own loop's numbers on the same case,
its compiled plant the Python plant's, and the command writes its table and figures for a
plugin controller beside a built-in, refusing what it cannot run with a clear error."""
from __future__ import annotations

import csv
import math
import os
import random
import subprocess
import sys

import numpy as np
import pytest

from controllers import registry
from controllers.base import ControllerContext
from daemon.testing.loop import virtual_loop
from evaluation import cases, runner
from hal import config
from hal.actuation import RigActuation
from hal.schema import build
from sim_backend.compiled_plant import CompiledArm
from sim_backend.options import SimOptions
from sim_backend.plant import SimArm
from tests import controller_plugin, doc_blocks, doc_runs
from tests.doc_blocks import ROOT

RIG = config.load()
CONTEXT = ControllerContext.for_rig(RIG, RigActuation(RIG), 0.001)


@pytest.mark.parametrize("options", [{}, {"dead_time": False}, {"friction": False}, {"adc_noise_volts": 0.0}])
def test_the_compiled_plant_steps_as_the_python_plant(options):
    """Random command volts (both rails, end stops reached) for 20 s: every state equal."""
    sim = {**RIG.transport.options, **options}
    python = SimArm(RIG, build(SimOptions, sim, "o"))
    compiled = CompiledArm(RIG, build(SimOptions, {**sim, "compiled": True}, "o"))
    rng = random.Random(7)
    worst = 0.0
    for k in range(20000):
        if k % 400 == 0:
            volts = [rng.choice([0.0, 10.0, rng.uniform(0.0, 10.0)]) for _ in range(4)]
        python.step(volts)
        compiled.step(volts)
        for joint, row in zip(python.joints, compiled.state_deg()):
            worst = max(worst, abs(joint.th - row[0]), abs(joint.w - row[1]),
                        abs(joint.p_head - row[2]) * 1e-6, abs(joint.p_rod - row[3]) * 1e-6)
    assert worst <= 1e-9


def test_the_compiled_plant_refuses_what_it_does_not_model():
    with pytest.raises(config.ConfigError, match="Stribeck"):
        CompiledArm(RIG, build(SimOptions, {"friction_model": "karnopp", "compiled": True}, "o"))


@pytest.mark.parametrize("rig_file", ["hal/sim_2joint.toml", "examples/rigs/one_joint.toml"])
def test_the_daemons_loop_follows_a_step_on_the_compiled_plant_as_on_the_python_one(rig_file):
    """The loop closed through the simulated transport (its sensors read the plant's state:
    potentiometers, and chamber transmitters where the rig wires them) on the compiled plant
    and on the Python one: the same step response, to float rounding. The compiled plant's
    state is its own (arrays), so every sensor must read it, not the Python joints it was
    built from (they stood still: a step never moved)."""
    rig = config.load(str(ROOT / rig_file))
    angles = {}
    for compiled in (False, True):
        rig_c = config.with_transport(rig, "sim", {**rig.transport.options, "compiled": compiled})
        loop = virtual_loop(rig_c, "pid")
        loop.start()
        loop.enable()
        target = [a + math.radians(5.0) for a in loop.reference[0]]
        from controllers.trajectory import JointMove
        loop.set_trajectory(JointMove(list(loop.reference[0]), target, 1.0), "step")
        loop.run(3000)
        assert loop.state.value == "enabled", loop.supervisor.cause
        angles[compiled] = list(loop.angles)
        assert all(abs(a - t) < math.radians(1.0) for a, t in zip(loop.angles, target)), (compiled, loop.angles, target)
    assert angles[True] == pytest.approx(angles[False], abs=1e-9)


def test_the_compiled_plant_refuses_the_injected_faults():
    with pytest.raises(config.ConfigError, match="no injected faults"):
        CompiledArm(RIG, build(SimOptions, {**RIG.transport.options, "compiled": True,
                                            "joints": {"bottom": {"leak": "head"}}}, "o"))


def daemon_loop_log(controller: str, plant: cases.Plant, path) -> tuple[np.ndarray, str]:
    """The case as the daemon's loop runs it (daemon/testing's virtual loop, driven here a cycle at
    a time): approach, settle, the path and its hold, each cycle's reference, angles and output."""
    loop = virtual_loop(runner.evaluation_rig(RIG, plant, compiled=False), "hold")
    loop.start()
    loop.switch(registry.build(controller, loop.context, None, runner.construction_options(controller)))
    loop.enable()
    start = path.sample(0.0)[0]
    move_s = runner.approach_duration(loop, start)
    from controllers.trajectory import JointMove
    loop.set_trajectory(JointMove(list(loop.reference[0]), start, move_s), "approach")
    loop.run(round((move_s + runner.SETTLE_S) / loop.period))
    loop.set_trajectory(path, "path")
    rows = []
    for _ in range(round((path.duration + runner.HOLD_S) / loop.period)):
        loop.run(1)
        if loop.state.value != "enabled":
            return np.array(rows), loop.supervisor.cause
        rows.append([*loop.reference[0], *loop.angles, *loop.u])
    return np.array(rows), ""


@pytest.mark.slow(seconds=8)
@pytest.mark.parametrize("controller", cases.BUILTINS)
def test_the_fast_engine_gives_the_daemons_loop_numbers(controller):
    """One case (the steps, the nominal plant with the rig's sensor noise) through the fast engine
    (every built-in's step compiled from its second cycle on, evaluation/twin_steps.py) and
    through the daemon's own loop on its virtual clock: the same reference, angles and output
    every cycle, to the last bit, hence the same figures."""
    path = cases.reference(RIG, CONTEXT, "steps")
    expected, cause = daemon_loop_log(controller, cases.Plant("nominal"), path)
    logs = []
    options = runner.construction_options(controller)
    case = runner.run_case(RIG, controller, cases.Plant("nominal"), "steps", path, options=options, engine="fast",
                           log_out=logs)
    assert cause == case.tripped == ""
    assert logs[0].shape == expected.shape
    assert np.array_equal(logs[0], expected)
    reference = runner.run_case(RIG, controller, cases.Plant("nominal"), "steps", path, options=options, engine="loop")
    for field in ("tip_max_mm", "tip_rms_mm", "joint_max_deg", "joint_rms_deg", "at_limit_pct", "motion_v_s",
                  "sign_changes_per_s", "settle_s", "final_deg"):
        assert getattr(case, field) == pytest.approx(getattr(reference, field), rel=1e-12, nan_ok=True), field
    assert 0.0 < case.tip_max_mm < 50.0


@pytest.mark.slow(seconds=4)
@pytest.mark.parametrize("plugin, cause", [
    ("tests.plugins:Raising", "controller raising failed: RuntimeError: controller bug"),
    ("tests.plugins:Contrary", "before the reference: joint bottom at 175.0 deg is outside its limits 85.0..175.0 deg"),
])
def test_a_trip_ends_the_case_in_both_engines_with_the_loops_cause(plugin, cause):
    """A controller that raises, and one that drives a joint into its limit: both engines trip
    in the same cycle with the supervisor's own words."""
    path = cases.reference(RIG, CONTEXT, "steps")
    fast = runner.run_case(RIG, plugin, cases.Plant("nominal"), "steps", path, engine="fast")
    loop = runner.run_case(RIG, plugin, cases.Plant("nominal"), "steps", path, engine="loop")
    assert fast.tripped == loop.tripped
    assert cause in fast.tripped
    assert math.isnan(fast.tip_max_mm)


@pytest.mark.slow(seconds=6)
def test_a_builtin_that_trips_on_its_compiled_step_trips_as_in_the_loop():
    """A PID tuned far too hard (Kp 10000 V/rad, Ti 0.05 s) on a plant with 1.41x the gain and
    three times the dead time: both engines trip on the same joint, speed and cycle."""
    path = cases.reference(RIG, CONTEXT, "steps")
    params, plant = {"Kp": [1e4, 1e4], "Ti": [0.05, 0.05]}, cases.Plant("unstable", (1.41, 1.41), 0.7, 3.0)
    fast = runner.run_case(RIG, "pid", plant, "steps", path, params, engine="fast")
    loop = runner.run_case(RIG, "pid", plant, "steps", path, params, engine="loop")
    assert "deg/s, over its 60.0 deg/s limit" in fast.tripped
    assert fast.tripped == loop.tripped


@pytest.mark.slow(seconds=8)
def test_a_subclass_of_a_builtin_runs_its_own_step_in_the_fast_engine():
    """A lab's PID variant (0.2 V added to each output) is not taken for the built-in's compiled
    twin: its case equals the daemon's loop's to the last bit, and differs from the PID's."""
    path = cases.reference(RIG, CONTEXT, "steps")
    mine, pid = [], []
    runner.run_case(RIG, "tests.plugins:BiasedPID", cases.Plant("nominal"), "steps", path, engine="fast",
                    log_out=mine)
    expected, cause = daemon_loop_log("tests.plugins:BiasedPID", cases.Plant("nominal"), path)
    runner.run_case(RIG, "pid", cases.Plant("nominal"), "steps", path, engine="fast", log_out=pid)
    assert cause == ""
    assert np.array_equal(mine[0], expected)
    assert not np.array_equal(mine[0], pid[0])


def evaluate(*args, cwd, path=()):
    """``pneumactl evaluate`` in ``cwd``, the checkout on the path (its test plugins load by module
    path), and ``path``'s directories (an installed package's) before it."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [*map(str, path), str(ROOT),
                                                                      os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "daemon.client.ctl", "evaluate", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.slow(seconds=30)
def test_evaluate_writes_a_plugins_table_and_figures_beside_a_builtin_over_the_thesis_set(tmp_path):
    """A plugin by module path with a parameter changed, beside the PID at its defaults, over the
    thesis's uncertainty set (the nominal plant and its four gain corners), on the steps."""
    out = tmp_path / "out"
    done = evaluate("tests.plugins:LabPDFF", "pid", "--param", "Ti=[2.0, 3.0]", "--plants", "thesis",
                    "--reference", "steps", "--out", str(out), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    with open(out / "cases.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 5
    assert {r["plant"] for r in rows} == {"nominal", "gain 0.41/0.59", "gain 0.41/1.41", "gain 1.41/0.59",
                                          "gain 1.41/1.41"}
    assert {r["controller"] for r in rows} == {"tests.plugins:LabPDFF", "pid"}
    table = (out / "table.md").read_text()
    assert "| tests.plugins:LabPDFF | steps 9.0 s |" in table and "| pid | steps 9.0 s |" in table
    for png in ("summary.png", "steps.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    mine = [r for r in rows if r["controller"] != "pid" and r["plant"] == "nominal"][0]
    pid = [r for r in rows if r["controller"] == "pid" and r["plant"] == "nominal"][0]
    assert mine["joint_max_deg"] != pid["joint_max_deg"]  # its parameter took effect


@pytest.mark.slow(seconds=20)
def test_evaluate_runs_a_controller_directorys_plugin_by_its_name(tmp_path):
    """A lab's file in a controller directory, as the daemon's --controller-dir takes it: named
    by its controller's name alone (no module path, nothing on PYTHONPATH), built in every
    worker; a file that does not import is said, the others still run."""
    lab = tmp_path / "lab-controllers"
    lab.mkdir()
    (lab / "lab_pd.py").write_text('"""A lab PD."""\nfrom controllers.pid import PID\n\n\nclass LabPD(PID):\n'
                                   '    """Lab PD."""\n\n    name = "lab_pd"\n')
    (lab / "broken.py").write_text("import lab_missing_dependency\n")
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "daemon.client.ctl", "evaluate", "lab_pd", "--controller-dir", str(lab),
                           "--plants", "thesis", "--reference", "steps", "--out", str(out)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"controller file {lab / 'broken.py'} refused" in done.stderr
    with open(out / "cases.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 5 and {r["controller"] for r in rows} == {"lab_pd"}
    assert all(r["tripped"] == "" for r in rows), rows
    assert "| lab_pd | steps 9.0 s |" in (out / "table.md").read_text()


@pytest.mark.slow(seconds=30)
def test_evaluate_runs_an_installed_plugin_found_by_its_entry_point(tmp_path):
    """The worked example package (examples/controller_plugin) pip-installed as its wheel into a
    directory of the test's, named by its entry point alone, over the thesis's uncertainty set
    on the steps: a row per plant, its table and figures written."""
    site, out = tmp_path / "site", tmp_path / "out"
    install = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
                              "--target", str(site), str(controller_plugin.wheel(tmp_path))],
                             capture_output=True, text=True, timeout=300)
    assert install.returncode == 0, install.stderr
    done = evaluate("mylab_pdff", "--plants", "thesis", "--reference", "steps", "--out", str(out), cwd=tmp_path,
                    path=[site])
    assert done.returncode == 0, done.stderr
    with open(out / "cases.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["controller"] for r in rows] == ["mylab_pdff"] * 5
    nominal, = [r for r in rows if r["plant"] == "nominal"]
    assert nominal["tripped"] == "" and 0.0 < float(nominal["joint_max_deg"]) < 10.0, nominal
    assert "| mylab_pdff | steps 9.0 s |" in (out / "table.md").read_text()
    for png in ("summary.png", "steps.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("args, says", [
    (["nosuch"], "unknown controller 'nosuch'"),
    (["pid", "--param", "Kp=-1"], "Kp"),
    (["pid", "--param", "nosuch=1"], "nosuch"),
    (["pid", "--plants", "nosuch"], "neither nominal, thesis, grid nor a file"),
    (["pid", "--reference", "nosuch"], "neither translation"),
    (["pid", "--config", "sim-muscle"], "not rotary cylinder joints"),
    (["axis_pid", "--config", "sim-axis"], "not rotary cylinder joints"),
    ([], "name a controller, or --all"),
])
def test_evaluate_refuses_bad_input_with_a_clear_error(args, says, tmp_path):
    done = evaluate(*args, "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert done.returncode == 2
    assert says in done.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.slow(seconds=20)
def test_evaluate_says_when_it_runs_the_daemons_loop_instead_of_the_fast_engine(tmp_path):
    """A rig the fast engine does not run (here: two plant steps a period) is evaluated on the
    daemon's loop, and the output says so and why; asked for the fast engine, it refuses."""
    rig = tmp_path / "rig.toml"
    rig.write_text((ROOT / "hal" / "sim_2joint.toml").read_text().replace("[transport.options]\n",
                                                                           "[transport.options]\nstep_s = 0.0005\n"))
    common = ["pid", "--config", str(rig), "--reference", "steps", "--out", str(tmp_path / "out")]
    done = evaluate(*common, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "on the daemon's loop (the fast engine needs one plant step a period)" in done.stdout
    assert "| pid | steps 9.0 s |" in (tmp_path / "out" / "table.md").read_text()
    refused = evaluate(*common, "--engine", "fast", cwd=tmp_path)
    assert refused.returncode == 2 and "--engine fast needs one plant step a period" in refused.stderr


def test_a_plant_file_is_read_strictly(tmp_path):
    good = tmp_path / "plants.toml"
    good.write_text('[[plants]]\nname = "weak"\ngain = [0.5, 0.7]\nfriction = 1.2\n\n[[plants]]\ngain = 1.3\nnoise = false\n')
    plants = cases.plants(str(good), RIG)
    assert plants[0] == cases.Plant("weak", (0.5, 0.7), 1.2)
    assert plants[1] == cases.Plant("plant 2", (1.3, 1.3), noise=False)
    bad = tmp_path / "bad.toml"
    bad.write_text('[[plants]]\ngain = [0.5]\n')
    with pytest.raises(config.ConfigError, match="one per joint"):
        cases.plants(str(bad), RIG)
    bad.write_text('[[plants]]\ngian = 2\n')
    with pytest.raises(config.ConfigError, match="unknown key 'gian'"):
        cases.plants(str(bad), RIG)


@pytest.mark.slow(seconds=60)
def test_the_documents_evaluate_lines_run(tmp_path):
    """docs/controllers.md's and docs/benchmarks.md's ``pneumactl evaluate`` lines, on the steps
    (tests/doc_claims.toml), from a scratch directory: each writes its table and figures."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    lines = {}
    for doc, section in (("docs/controllers.md", "Judging a controller before it touches the arm: `pneumactl evaluate`"),
                         ("docs/benchmarks.md", "Evaluations: `pneumactl evaluate` (the loop's cycle and the "
                                                "built-ins' steps compiled)")):
        for command in doc_blocks.commands(doc, section, match="^pneumactl evaluate "):
            lines.setdefault(command.text, command)
    assert len(lines) >= 3
    for command in lines.values():
        done = doc_runs.run(command, tmp_path, env=env, timeout=600)
        assert done.returncode == 0, done.explain()
        out = tmp_path / command.text.split("--out ")[1].split()[0]
        assert "| steps 9.0 s |" in (out / "table.md").read_text(), done.explain()
        assert (out / "summary.png").stat().st_size > 0 and (out / "cases.csv").stat().st_size > 0
