"""Recordings as MCAP (issue: recordings a lab already knows how to open): the mcap package's
own reader opens them with their schemas, attachment and metadata; one message per cycle
stamped with the daemon's clock; lost telemetry written where it happened; a file cut short
readable up to its last complete chunk; earlier .pnrec files still export; numpy loading and
the plots."""
import json
import math
import warnings
from pathlib import Path

import jsonschema
import msgpack
import numpy as np
import pytest
from mcap.reader import make_reader

from controllers.trajectory import JointMove
from daemon.client.client import Client
from daemon.client.ctl import main
from daemon.recordings import mcap_log, mcap_repair, reading as recording
from daemon.testing.daemons import STOP_WAIT_S
from daemon.testing.loop import dealer, make_loop, ok


@pytest.fixture(scope="module")
def session():
    """A short PID move on the in-process loop: its describe, controller and telemetry."""
    loop, captured, srv = make_loop(server=True)
    sock = dealer(srv)
    describe, controller = ok(loop, sock, "describe"), ok(loop, sock, "controller.get")
    start = len(captured.messages)
    loop.enable()
    loop.set_trajectory(JointMove(list(loop.angles), [loop.angles[0] + math.radians(4.0), loop.angles[1]], 1.0), "move")
    loop.run(3000)
    srv.close()
    return describe, controller, captured.messages[start:]


def write(path, session, skip_state_batch: int | range | None = None, plan=None):
    describe, controller, messages = session
    skip = skip_state_batch if isinstance(skip_state_batch, range) else [skip_state_batch]
    with open(path, "wb") as f:
        rec = mcap_log.McapRecording(f, describe, controller, plan=plan)
        batches = 0
        for topic, message in messages:
            if topic == "state":
                batches += 1
                if batches in skip:
                    continue
            rec.write(topic, message)
        rec.finish()
    return rec


@pytest.mark.slow  # long: kept out of the fast subset
def test_the_mcap_package_reads_a_recording_with_its_schemas_attachment_and_metadata(tmp_path, session):
    describe = session[0]
    path = tmp_path / "run.mcap"
    write(path, session)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic: c for c in summary.channels.values()}
        assert {"/pneumad/state", "/pneumad/event", "/pneumad/internals", "/pneumad/stats"} <= set(topics)
        state = topics["/pneumad/state"]
        assert state.message_encoding == "json" and summary.schemas[state.schema_id].encoding == "jsonschema"
        schema = json.loads(summary.schemas[state.schema_id].data)
        validator = jsonschema.validators.validator_for(schema)
        validator.check_schema(schema)
        validator = validator(schema)  # checked and built once: per message, that was 10 ms each
        cycles = []
        for _, channel, message in reader.iter_messages(topics=["/pneumad/state"]):
            sample = json.loads(message.data)
            validator.validate(sample)
            assert message.log_time == round(sample["t"] * 1e9) and message.sequence == sample["cycle"]
            cycles.append(sample["cycle"])
        assert cycles == list(range(cycles[0], cycles[0] + len(cycles))) and len(cycles) >= 3000
        attachments = {a.name: a for a in reader.iter_attachments()}
        assert attachments["rig.toml"].data.decode() == describe["rig"]["source"]
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert metadata["pneumad"]["rig_hash"] == describe["rig"]["hash"]
        assert metadata["pneumad"]["controller"] == "pid"
        assert json.loads(metadata["describe"]["json"]) == describe
    samples = recording.open_run(path).samples
    assert samples[-1]["bottom.position"] == pytest.approx(samples[-1]["bottom.setpoint"], abs=math.radians(1.0))
    layout = recording.open_run(path).layout
    assert set(schema["properties"]) == set(layout.names) == set(samples[-1]) and layout.id == describe["cycle_layout_id"]


def test_lost_telemetry_is_written_where_it_happened(tmp_path, session):
    path = tmp_path / "gap.mcap"
    rec = write(path, session, skip_state_batch=100)
    run = recording.open_run(path)
    assert rec.gaps == 1 and run.messages["gap"] == [{"topic": "state", "missing": 1, "after_seq": run.messages["gap"][0]["after_seq"]}]
    cycles = [s["cycle"] for s in run.samples]
    holes = [b - a for a, b in zip(cycles, cycles[1:]) if b - a != 1]
    assert holes == [11]  # the ten cycles of the missing batch


@pytest.mark.parametrize("keep", [0.3, 0.6, 0.95])
def test_a_recording_cut_short_reads_up_to_its_last_complete_chunk(tmp_path, session, keep):
    full = tmp_path / "full.mcap"
    write(full, session)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:int(len(data) * keep)])
    whole, part = recording.open_run(full), recording.open_run(cut)
    assert part.truncated
    assert 0 < len(part.samples) < len(whole.samples)
    assert same(part.samples, whole.samples[:len(part.samples)])  # what is there is right, in order
    assert recording.export_csv(cut, tmp_path / "cut.csv") == len(part.samples)


@pytest.mark.parametrize("keep", [0.5, 0.9])
def test_a_cut_recording_is_exported_plotted_and_loaded_saying_it_is_cut_and_how_much_is_missing(tmp_path, session,
                                                                                                   keep, capsys):
    """A real run's recording, cut at half or nine tenths: what is there is written, and export,
    plot (exit 3, and on every figure) and load (a warning, ``.cut``) say it is cut and how many
    seconds of its planned length are missing; the whole file exits 0 with no word."""
    state = [m for topic, m in session[2] if topic == "state"]
    first, last = state[0]["t"][0], state[-1]["t"][-1]
    full = tmp_path / "full.mcap"
    write(full, session, plan={"planned_end_t": last})
    data = full.read_bytes()
    cut = tmp_path / "run.mcap"
    cut.write_bytes(data[:int(len(data) * keep)])
    read_to = recording.open_run(cut).samples[-1]["t"]
    assert main(["export", str(cut), str(tmp_path / "run.csv")]) == 3
    out, err = capsys.readouterr()
    rows = len(recording.open_run(cut).samples)
    assert f"wrote {rows} rows" in out and 0 < rows < len(recording.open_run(full).samples)
    said = (f"warning: run.mcap is cut (no footer or index: the file ends inside a record): read {read_to - first:.1f} s "
            f"from its first sample of the {last - first:.1f} s planned: about {last - read_to:.1f} s missing at its end")
    assert err.startswith(said) and "the CSV holds what is there (exit 3)" in err, err
    assert main(["plot", str(cut), "--out", str(tmp_path / "plots")]) == 3
    out, err = capsys.readouterr()
    assert err.startswith(said) and "the figures show what is there" in err, err
    pictures = [line for line in out.splitlines() if line.endswith(".png")]
    assert len(pictures) >= 5
    figure_text = " ".join(plots_text(recording.open_run(cut), cut))
    assert f"about {last - read_to:.1f} s missing" in figure_text
    with pytest.warns(recording.CutRecording, match=r"run\.mcap is cut .* s missing at its end"):
        loaded = recording.load(cut)
    assert loaded.cut.startswith(said[len("warning: "):].replace("run.mcap", str(cut), 1)) and len(loaded["t"]) == rows
    assert main(["export", str(full), str(tmp_path / "full.csv")]) == 0 and capsys.readouterr().err == ""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert recording.load(full).cut == ""


def same(a: list[dict], b: list[dict]) -> bool:
    """Samples equal, NaN to NaN."""
    return msgpack.packb(a) == msgpack.packb(b)


def plots_text(run, path) -> list[str]:
    """Every text on the figures ``pneumactl plot`` draws of ``run`` (the file at ``path``)."""
    import matplotlib.pyplot as plt

    from daemon.client import plot_marks, plots
    texts = []
    for fig in plots.figures([("run", run)]).values():
        if fig is not None:
            plot_marks.say_cut(fig, [run.cut_notice(path.name)])
            texts += [t.get_text().replace("\n", " ") for t in fig.texts]
            plt.close(fig)
    return texts


def test_a_cut_file_finished_by_repair_opens_in_the_mcap_packages_default_reader_and_still_says_it_is_cut(tmp_path,
                                                                                                         session):
    """The `mcap` package's default reader reads nothing from a cut file (it looks for the footer);
    once finished up to its last complete chunk it reads every state sample ours does, and the
    file still says it was cut, and why."""
    full = tmp_path / "full.mcap"
    write(full, session)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:int(len(data) * 0.6)])
    ours = [s["cycle"] for s in recording.open_run(cut).samples]
    assert len(ours) > 100 and default_reader_cycles(cut) is None
    repaired = mcap_repair.repair(cut, "the test cut it")
    assert repaired is not None and 0 < repaired.dropped_bytes < len(data) * 0.6
    assert default_reader_cycles(cut) == ours == [s["cycle"] for s in recording.open_run(cut).samples]
    with open(cut, "rb") as f:  # its index counts what is there, channel by channel
        reader = make_reader(f)
        counted = {}
        for _, channel, _ in reader.iter_messages():
            counted[channel.id] = counted.get(channel.id, 0) + 1
        statistics = reader.get_summary().statistics
    assert dict(statistics.channel_message_counts) == counted and statistics.message_count == repaired.messages
    run = recording.open_run(cut)
    assert run.truncated.startswith("the test cut it; closed at its last complete chunk on ")
    assert mcap_repair.repair(cut, "again") is None and mcap_repair.repair(full, "whole") is None  # finished: untouched
    assert full.read_bytes() == data


def default_reader_cycles(path) -> list[int] | None:
    """The state samples' cycles as ``mcap.reader.make_reader(f).iter_messages()`` gives them; None if it cannot."""
    try:
        with open(path, "rb") as f:
            return [json.loads(m.data)["cycle"] for _, c, m in make_reader(f).iter_messages() if c.topic == "/pneumad/state"]
    except Exception:  # noqa: BLE001 (whatever the package raises at the cut)
        return None


def test_plot_says_where_a_recording_has_holes(tmp_path, session, capsys):
    """Telemetry lost on its way (0.3 s: 30 state batches) is said on stdout, with where and how
    long, beside the figures that draw it as a gap; a whole recording has no such line."""
    holed, whole = tmp_path / "holed.mcap", tmp_path / "whole.mcap"
    write(holed, session, skip_state_batch=range(100, 130))
    write(whole, session)
    assert main(["plot", str(holed), "--out", str(tmp_path / "plots")]) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if not line.endswith(".png")]
    assert len(said) == 1 and said[0].startswith("holed.mcap: no data in 1 hole, 0.30 s in all (0.30 s at 0.99 s; "
                                                 "300 cycles missing)"), said
    assert main(["plot", str(whole), "--out", str(tmp_path / "plots")]) == 0
    assert all(line.endswith(".png") for line in capsys.readouterr().out.splitlines())


def test_a_file_that_is_no_recording_is_refused_clearly(tmp_path):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + bytes(40))
    with pytest.raises(ValueError, match="not a pneumad MCAP recording"):
        recording.open_run(junk)
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    with pytest.raises(ValueError, match="not a pneumad recording"):
        recording.open_run(text)


DATA = Path(__file__).resolve().parent / "data"


@pytest.mark.parametrize("name, joint, commands", [
    ("sim-before-layout.pnrec", "middle", ["u.v_mv"]),
    ("muscle-before-layout.mcap", "elbow", ["u.pressure_a", "u.pressure_b", "u.brake"])])
def test_a_recording_made_before_the_cycle_layout_reads_into_the_same_flat_samples(tmp_path, name, joint, commands):
    """Files made by the daemon before the layout (tests/data/make_before_layout.py, run on
    that version): an earlier .pnrec's old columns and an MCAP's nested samples read as flat
    samples keyed by the layout their describe implies; their chamber pressures were the
    commanded ones, and say so; CSV and load give one column per field."""
    path = DATA / name
    run = recording.open_run(path)
    assert "cycle_layout" not in run.describe  # made before it
    assert set(run.samples[0]) == set(run.layout.names) and len(run.samples) >= 200
    assert [f.quantity for f in run.layout.of_joint(joint, "command")] == commands
    enabled = [s for s in run.samples if s["mode"] == "enabled"]
    assert enabled and all(isinstance(s[f"{joint}.position"], float) and math.isfinite(s[f"{joint}.position"])
                           for s in enabled)
    first = run.layout.of_joint(joint, "commanded")[0].name
    assert first.endswith("_cmd") and np.isfinite(run.column(first)).all()
    assert all(math.isnan(s[f"{joint}.shadow.{commands[0][2:]}"]) for s in run.samples)  # no candidate ran
    if "muscle" in name:  # the muscle's pressures commanded: u.pressure_a is what reached p_a_cmd when enabled
        assert enabled[-1]["elbow.u.pressure_a"] == pytest.approx(enabled[-1]["elbow.p_a_cmd"], rel=0.05)
    rows = recording.export_csv(path, tmp_path / "old.csv")
    lines = (tmp_path / "old.csv").read_text().splitlines()
    assert rows == len(lines) - 1 == len(run.samples)
    assert lines[0].split(",")[:3] == ["cycle [-]", "t [s]", f"{run.layout.names[2]} [rad]"]
    data = recording.load(path)
    assert data.layout.names == run.layout.names and set(run.layout.names) <= set(data)
    assert np.array_equal(data[f"{joint}.position"], run.column(f"{joint}.position"))


def test_an_mcap_from_before_the_foxglove_channels_reads_as_one_with_them(tmp_path, session, monkeypatch):
    """recording.load, export and the plots read the /pneumad/<topic> channels alone: a file
    written without the Foxglove channels (as earlier versions wrote it) gives the same."""
    new, old = tmp_path / "new.mcap", tmp_path / "old.mcap"
    write(new, session)
    monkeypatch.setattr(mcap_log, "json_schemas", lambda describe: {})
    monkeypatch.setattr(mcap_log, "protobuf_schemas", lambda: {})
    monkeypatch.setattr(mcap_log.Frames, "of", lambda self, topic, message: [])
    write(old, session)
    with open(old, "rb") as f:
        assert {c.topic for c in make_reader(f).get_summary().channels.values()} == {
            mcap_log.channel(t) for t in mcap_log.TOPICS}  # nothing but the earlier channels
    a, b = recording.load(old), recording.load(new)
    assert set(a) == set(b) and all(np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f") for k in a)
    assert recording.export_csv(old, tmp_path / "old.csv") == recording.export_csv(new, tmp_path / "new.csv")
    assert (tmp_path / "old.csv").read_text() == (tmp_path / "new.csv").read_text()


def test_load_gives_numpy_columns_one_per_field_with_the_layout(tmp_path, session):
    path = tmp_path / "run.mcap"
    write(path, session)
    data = recording.load(path)
    assert {"t", "cycle", "bottom.position", "middle.u.v_mv", "internals.t", "internals.p.bottom"} <= set(data)
    assert data.layout.names == tuple(f["name"] for f in session[0]["cycle_layout"])
    assert data.layout["bottom.position"].unit == "rad" and data["mode"][-1] == "enabled"
    assert np.isnan(data["bottom.shadow.v_mv"]).all()  # no candidate ran: nothing written
    recording.export_csv(path, tmp_path / "run.csv")
    header = (tmp_path / "run.csv").read_text().splitlines()[0].split(",")
    assert header == [f"{f.name} [{f.unit}]" for f in data.layout.fields]
    n = len(data["t"])
    assert all(len(data[k]) == n for k in data if not k.startswith("internals."))
    assert np.all(np.diff(data["t"]) > 0) and np.all(np.diff(data["cycle"]) == 1)


@pytest.mark.slow  # long: kept out of the fast subset
def test_plot_writes_the_figures_of_one_run_and_of_an_overlay(tmp_path, session):
    from daemon.client import plots
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    write(a, session)
    write(b, session)
    one = plots.plot_runs([a], tmp_path / "one")
    assert {p.name for p in one} >= {"a-joints.png", "a-errors.png", "a-output.png", "a-tip.png", "a-internals.png"}
    both = plots.plot_runs([a, b], tmp_path / "both")
    assert {p.name for p in both} >= {"compare-joints.png", "compare-tip.png", "compare-internals-2.png"}
    assert all(p.stat().st_size > 10_000 for p in one + both)


@pytest.mark.slow(seconds=16)
def test_the_example_step_experiment_records_and_plots_against_a_real_daemon(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from tests import doc_blocks
    from tests.daemons import endpoint_env, real_daemon, wait_for_own_daemon
    root = Path(__file__).resolve().parents[1]
    daemon, eps = real_daemon(tmp_path)
    try:
        with Client(**eps) as client:  # serving (the example, as a user would, runs against a daemon that is)
            wait_for_own_daemon(client, daemon)
        # the README's Python snippet first, as written (its client finds the daemon through the
        # environment): it leaves the arm enabled and the translation running, which a user stops
        snippet = doc_blocks.snippet("README.md", "A short tour", match=r"from daemon\.client import Client").text
        assert "c.enable()" in snippet and "Client()" in snippet
        done = subprocess.run([sys.executable, "-c", snippet], cwd=tmp_path, env=endpoint_env(eps),
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0 and "'cycle'" in done.stdout, (snippet, done.stderr)
        with Client(**eps) as client:
            assert client.status()["state"] == "enabled" and client.status()["reference"] == "translation"
            client.call("abort", control=True)
        out = subprocess.run([sys.executable, str(root / "examples" / "step_experiment.py"), "--out",
                              str(tmp_path / "step"), "--seconds", "6", *sum(([f"--{k}", v] for k, v in eps.items()), [])],
                             cwd=root, capture_output=True, text=True, timeout=120)
    finally:
        daemon.terminate()
        daemon.wait(STOP_WAIT_S)
    assert out.returncode == 0, out.stderr
    assert "bottom: step 5 deg, overshoot" in out.stdout
    data = recording.load(tmp_path / "step.mcap")
    moved = math.degrees(data["bottom.position"][-1] - data["bottom.position"][0])
    assert abs(moved - 5.0) < 0.5  # the step settled in the recording
    assert (tmp_path / "step-joints.png").stat().st_size > 10_000


def _strict(token: str):
    raise ValueError(f"{token} is not JSON (RFC 8259): a viewer's JSON.parse rejects it")


@pytest.mark.slow(seconds=3)  # a few seconds: kept out of the fast subset
def test_a_muscle_rigs_recording_is_strict_json_that_validates_and_reads_back_nan(tmp_path):
    """The muscle joint takes no V_MV and the rig has no force sensor: those numbers are NaN in
    telemetry. Every JSON message of the recording still parses strictly (Foxglove parses with
    JSON.parse: a NaN token made the whole channel unreadable) and validates against its
    channel's schema, and the readers get NaN back, not None."""
    from importlib import resources

    loop, captured, srv = make_loop(resources.files("hal").joinpath("sim_muscle.toml").read_text(), server=True,
                                    controller="muscle_eq")
    sock = dealer(srv)
    describe, controller = ok(loop, sock, "describe"), ok(loop, sock, "controller.get")
    start = len(captured.messages)
    loop.enable()
    loop.set_trajectory(JointMove(list(loop.angles), [loop.angles[0] + math.radians(10.0)], 0.5), "move")
    loop.run(1500)
    srv.close()
    path = tmp_path / "muscle.mcap"
    write(path, (describe, controller, captured.messages[start:]))
    checked = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            if channel.message_encoding != "json":
                continue
            decoded = json.loads(message.data, parse_constant=_strict)
            if channel.topic not in checked:
                checked[channel.topic] = jsonschema.validators.validator_for(json.loads(schema.data))(json.loads(schema.data))
            checked[channel.topic].validate(decoded)
    assert {"/pneumad/state", "/pneumad/commands", "/pneumad/tracking"} <= set(checked)
    samples = recording.open_run(path).samples
    assert len(samples) >= 1500
    assert all(math.isnan(s["elbow.shadow.pressure_a"]) for s in samples)  # no candidate: null in the file
    assert all(isinstance(s["elbow.position"], float) for s in samples)
    data = recording.load(path)
    assert np.isnan(data["elbow.shadow.brake"]).all() and np.isfinite(data["elbow.position"]).all()
    assert np.isfinite(data["elbow.p_a"]).all() and np.isfinite(data["elbow.p_a_cmd"]).all()  # measured, commanded


def test_a_json_channels_message_is_strict_json_with_null_for_what_is_not_a_finite_number():
    """What Foxglove's JSON.parse reads: no NaN or Infinity tokens (numpy's floats as floats);
    what orjson refuses written the standard way: an integer key as a string, an integer past
    64 bits whole."""
    from daemon.recordings.channels import json_bytes

    def strict(text: bytes):
        return json.loads(text, parse_constant=lambda token: pytest.fail(f"{token} in {text!r}"))
    message = {"t": 1.25, "q": [0.5, math.nan, -math.inf], "u": np.float64(math.nan), "v": np.float64(0.25),
               "mode": "enabled", "shadow": None}
    assert strict(json_bytes(message)) == {"t": 1.25, "q": [0.5, None, None], "u": None, "v": 0.25, "mode": "enabled",
                                           "shadow": None}
    assert strict(json_bytes({"seq": 2 ** 70, "x": math.inf, 3: "by an int key"})) == {"seq": 2 ** 70, "x": None,
                                                                                       "3": "by an int key"}
