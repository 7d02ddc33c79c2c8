"""``pneumactl``: drive pneumad from a terminal (a thin layer over daemon.client.client)."""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys

from daemon.wire import keys
from daemon.wire.catalog import COMMANDS

from daemon.client import doctor
from daemon.client.client import ENDPOINT_VARIABLES, Client, Interrupted, KeyRefused, RemoteError, RequestTooLarge
from daemon.client.controller_cli import key_values
from daemon.client import motion_cli
from daemon.client.motion_cli import MOTION, NOT_ENDED, motion, option_help, with_lease
from daemon.wire.protocol import DEFAULT_COMMAND, DEFAULT_CONTROL, DEFAULT_TELEMETRY

EXIT_STATUS = ("exit status: 0 done; 1 the daemon refused the request (the error said), or a file could not be "
               "read or written; 2 no reply, or the key refused; 3 export/plot written from a cut recording; "
               f"{NOT_ENDED} --wait: the reference did not end, the arm left enabled (a trip, an e-stop, a disable: "
               "its cause said); 130 Ctrl-C (what runs on said)")


def record(client: Client, path: str, seconds: float) -> int:
    """Record the telemetry to ``path`` as MCAP (:mod:`daemon.recordings.mcap_log`); a disk that fills or
    fails ends it with a clear error (exit 1), the file finished up to its last complete chunk."""
    from daemon.client.progress import recording_bar  # rich: only for the progress display
    from daemon.recordings import mcap_log  # mcap and numpy: only for a recording
    try:
        with recording_bar(path, seconds) as progress:
            written, lost = mcap_log.record(client, path, seconds, progress)
    except KeyboardInterrupt:
        raise Interrupted(f"interrupted: the recording to {path} ended at Ctrl-C, whole up to there "
                          f"(it was made here: nothing runs on in the daemon)") from None
    except OSError as exc:
        print(f"error: recording to {path} stopped: {exc.strerror or exc} ({finish_cut(path, exc)})", file=sys.stderr)
        return 1
    print(f"recorded {written} messages to {path} (lost {lost}, marked in the file)")
    return 0


def finish_cut(path: str, exc: OSError) -> str:
    """Finish a recording a write error cut (:mod:`daemon.recordings.mcap_repair`), so every MCAP
    reader opens it; what became of it, in words."""
    from daemon.recordings import mcap_repair
    if not os.path.isfile(path):
        return "nothing was kept"
    try:
        mcap_repair.repair(path, f"pneumactl record: write error: {exc.strerror or exc}")
        return "the file is finished up to its last complete chunk"
    except (OSError, ValueError) as err:
        return f"the file could not be finished ({getattr(err, 'strerror', None) or err}); pneumactl export and plot " \
               f"read it up to its last complete chunk"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pneumactl", description="Drive a pneumad daemon.", epilog=EXIT_STATUS)
    for name, default in (("command", DEFAULT_COMMAND), ("control", DEFAULT_CONTROL), ("telemetry", DEFAULT_TELEMETRY)):
        p.add_argument(f"--{name}", default=None, metavar="ENDPOINT",
                       help=f"the daemon's {name} endpoint (else {ENDPOINT_VARIABLES[name]}, else {default})")
    p.add_argument("--timeout", type=float, default=2.0)
    p.add_argument("--key", default=None, metavar="FILE",
                   help="your key (NAME.key_secret) for a daemon with keys (or PNEUMAD_KEY)")
    p.add_argument("--server-key", default=None, metavar="FILE",
                   help="the daemon's public key (server.key), if your key file does not hold it (or PNEUMAD_SERVER_KEY)")
    sub = p.add_subparsers(dest="what", required=True)
    for name in ("ping", "status", "describe", "enable", "disable", "estop", "reset", "abort"):
        sub.add_parser(name, help=COMMANDS[name].doc)
    w = sub.add_parser("watch", help="live text view")
    w.add_argument("--seconds", type=float, default=None)
    motion_cli.add_parsers(sub)
    pay = sub.add_parser("payload", help="identify a payload at the tip by torque balance (docs/estimation.md)")
    pay.add_argument("action", choices=("identify",))
    pay.add_argument("--unloaded", action="store_true",
                     help="measure the unloaded arm and store it as the reference (do this once, without a payload)")
    pay.add_argument("--reference", default="payload-reference.json", help="the unloaded reference's file")
    pay.add_argument("--apply", action="store_true",
                     help="give the identified payload to the controllers as a known load (load.set)")
    ld = sub.add_parser("load", help="a known payload at the tip, fed forward to every controller (gravity)")
    ld.add_argument("action", choices=("set", "clear"))
    ld.add_argument("mass_kg", nargs="?", type=float, help="set: the payload's mass [kg]")
    ld.add_argument("--com", default="0,0", metavar="ALONG,ACROSS",
                    help="its centre of mass from the tip, along and across the last link [mm] (default 0,0; "
                         "--com=-5,3 when the first is negative)")
    idp = sub.add_parser("identify", help="identify a joint's model: excite, record, fit, plot, write a rig file")
    idp.add_argument("joint")
    idp.add_argument("--out", default=None, help="directory for the rig file, figures and report "
                                                 "(default identify-JOINT-DATE-TIME)")
    idp.add_argument("--from", dest="source", default=None, metavar="RECORDING",
                     help="analyse this recording's experiments instead of running them (no daemon needed)")
    idp.add_argument("--amplitude", type=float, default=None, help="V_MV amplitude [V] (default: from the model)")
    idp.add_argument("--at", type=float, nargs="+", default=None, metavar="DEG",
                     help="move to these joint angles first [deg] (default: the experiments run where the arm is)")
    idp.add_argument("--band", type=float, default=10.0, help="stop if the joint leaves +- this [deg] (default 10)")
    idp.add_argument("--quick", action="store_true", help="experiments half as long (a first look)")
    idp.add_argument("--population", type=int, default=40, help="differential evolution (default 40, the thesis's)")
    idp.add_argument("--generations", type=int, default=1500, help="at most (default 1500, the thesis's)")
    c = sub.add_parser("controller", help="list, get, switch, set, shadow, commit, discard, reload")
    c.add_argument("action", choices=["list", "get", "switch", "set", "shadow", "commit", "discard", "reload"])
    c.add_argument("args", nargs="*", help="switch / shadow: NAME [KEY=VALUE ...]; set: KEY=VALUE ...; reload: NAME "
                                           "(a controller from the daemon's --controller-dir)")
    c.add_argument("--design", default=None, help="LTI design file (.toml or .npz) for lti and lti_dob")
    c.add_argument("--force", action="store_true", help=f"commit: {option_help('controller.commit', 'force')}")
    r = sub.add_parser("record", help="record telemetry to an MCAP file (Foxglove, PlotJuggler open it)")
    r.add_argument("file")
    r.add_argument("--seconds", type=float, default=10.0)
    rs = sub.add_parser("record.start", help="the daemon records telemetry (MCAP, in its recording directory)")
    rs.add_argument("--name", default=None, help=option_help("record.start", "name"))
    rs.add_argument("--seconds", type=float, default=None, help=option_help("record.start", "seconds"))
    rt = sub.add_parser("record.stop", help="end a recording the daemon is making")
    rt.add_argument("--name", default=None, help=option_help("record.stop", "name"))
    sub.add_parser("record.list", help=COMMANDS["record.list"].doc)
    rn = sub.add_parser("record.snapshot", help=COMMANDS["record.snapshot"].doc)
    rn.add_argument("--name", default=None, help=option_help("record.snapshot", "name"))
    e = sub.add_parser("export", help="export a recording (MCAP, or .pnrec of earlier versions) to CSV")
    e.add_argument("file")
    e.add_argument("csv")
    pl = sub.add_parser("plot", help="PNG figures of recordings; several files overlay their runs, each from its path's start")
    pl.add_argument("files", nargs="+")
    pl.add_argument("--out", default=".", help="directory for the PNGs (default: here)")
    rp = sub.add_parser("replay", help="a recorded run again on the rig's model: measured against simulated (docs/model.md)")
    rp.add_argument("file", help="the recording (MCAP)")
    rp.add_argument("--config", default=None, help="replay on this rig file's model (default: the recording's own)")
    rp.add_argument("--out", default=None, help="directory for the PNGs and report.json (default: FILE-replay)")
    rp.add_argument("--part", type=float, default=None,
                    help="the difference beyond which measured and simulated have parted [deg or mm] (default 1)")
    k = sub.add_parser("keys", help="new: make your own key pair; reload: have the daemon read its allow-list again")
    k.add_argument("action", choices=["new", "reload"])
    k.add_argument("name", nargs="?", help="new: your key's name (e.g. your login)")
    k.add_argument("--dir", default=os.path.expanduser("~/.config/pneumad"), help="new: where (default ~/.config/pneumad)")
    doctor.add_parser(sub)
    ev = sub.add_parser("evaluate", add_help=False, help="controllers on the rig's model over references and plant "
                        "variations, faster than real time (pneumactl evaluate --help)")
    return p


def export_or_plot(args) -> int:
    """``export`` and ``plot``: 0 when written from whole recordings, 1 on an error (nothing
    written), 3 when written from a recording that is cut (each said on stderr, with how much is
    missing): a script does not take a cut run for a whole one (docs/recordings.md)."""
    from daemon.recordings import reading  # mcap and numpy: only for a recording
    try:
        if args.what == "plot":
            from daemon.client import plots  # matplotlib: only when asked for pictures
            runs = plots.open_runs(args.files)
            for written in plots.plot_runs(args.files, args.out, runs):
                print(written)
            for path, run in zip(args.files, runs):
                for note in plots.hole_notes(os.path.basename(path), run):
                    print(note)
        else:
            runs = [reading.open_run(args.file)]
            rows = reading.export_csv(args.file, args.csv, runs[0])
            print(f"wrote {rows} rows to {args.csv}")
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    paths = args.files if args.what == "plot" else [args.file]
    cut = [run.cut_notice(os.path.basename(p)) for p, run in zip(paths, runs) if run.truncated]
    for notice in cut:
        print(f"warning: {notice}; {'the figures show' if args.what == 'plot' else 'the CSV holds'} what is there "
              f"(exit 3)", file=sys.stderr)
    return 3 if cut else 0


def replay(args) -> int:
    """``pneumactl replay``: the daemon's loop on the rig's model, in a process of its own
    (``python -m daemon.replay``: the client never imports the loop's side, :func:`child`). Its exit status:
    0 replayed, 1 refused (what the recording lacks, said), 2 the file cannot be read."""
    import subprocess

    options = [f"--{k}={v}" for k in ("config", "out", "part") if (v := getattr(args, k)) is not None]
    return child([sys.executable, "-m", "daemon.replay", args.file, *options])


def child(argv: list[str]) -> int:
    """Run a process of its own to its end: its exit status. A Ctrl-C reaches it too (the
    terminal's process group), and it says what it stopped; one sent to this process alone is
    passed on after a moment."""
    import subprocess

    proc = subprocess.Popen(argv)
    while True:
        try:
            return proc.wait()
        except KeyboardInterrupt:
            try:
                return proc.wait(2.0)
            except subprocess.TimeoutExpired:
                proc.send_signal(signal.SIGINT)


def main(argv=None) -> int:
    """pneumactl's exit status. Its output piped into a reader that stops early (``| head``)
    ends it quietly, as a Unix tool killed by SIGPIPE ends (status 128 + SIGPIPE), instead of a
    BrokenPipeError's traceback; stdout is flushed here, so nothing is left to fail at exit."""
    try:
        try:
            return _main(argv)
        finally:
            sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # what is still buffered goes nowhere
        return 128 + signal.SIGPIPE


def _main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args, _ = parser().parse_known_args(argv)
    if args.what == "evaluate":  # a process of its own (the daemon's loop on a virtual clock, a pool): never imported here
        return child([sys.executable, "-m", "evaluation", *argv[argv.index("evaluate") + 1:]])
    args = parser().parse_args(argv)
    if args.what == "identify" and args.source:
        return identify(None, args)
    if args.what in ("export", "plot"):
        return export_or_plot(args)
    if args.what == "replay":
        return replay(args)
    if args.what == "doctor":
        return doctor.run(args)
    try:
        if args.what == "keys" and args.action == "new":
            return new_key(args)
        client = Client(args.command, args.control, args.telemetry, timeout=args.timeout, key_file=args.key,
                        server_key_file=args.server_key)
    except keys.KeyFileError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        result = run(client, args)
    except Interrupted as exc:
        print(exc, file=sys.stderr)
        return 130
    except KeyboardInterrupt:  # a one-shot command: its request was sent or not, and the lease handed back
        print("interrupted: `pneumactl status` shows what the daemon is doing", file=sys.stderr)
        return 130
    except KeyRefused as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except RequestTooLarge as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except RemoteError as exc:
        print(f"error: {exc}", file=sys.stderr)
        if exc.data:
            print(json.dumps(exc.data, indent=2), file=sys.stderr)
        return 1
    except TimeoutError as exc:
        print(f"error: {exc}{timeout_hint(client)}", file=sys.stderr)
        return 2
    finally:
        client.close()
    if isinstance(result, dict) and result.get("approach_chosen"):
        print(f"approach: {result['approach_s']:g} s to the start (the shortest feasible, with a margin; "
              f"--approach S to choose)", file=sys.stderr)
    if result is not None:
        print(json.dumps(result, indent=2))
    if isinstance(result, dict) and result.get("ended") is False:  # --wait: `... --wait && next` goes no further
        print(f"error: the reference did not end: the arm is {result['state']} ({result['cause'] or 'no cause given'}); "
              f"exit {NOT_ENDED}", file=sys.stderr)
        return NOT_ENDED
    return 0


def identify(client: Client | None, args) -> int:
    """``pneumactl identify``: the experiments (unless ``--from``), then the fit and its files."""
    import time
    from pathlib import Path

    out = Path(args.out or f"identify-{args.joint}-{time.strftime('%Y%m%d-%H%M%S')}")
    try:
        from daemon.client import identify as ident  # scipy and matplotlib: only when identifying
        source = Path(args.source) if args.source else out / "experiments.mcap"
        if client is not None:
            out.mkdir(parents=True, exist_ok=True)
            ident.run_experiments(client, args.joint, source, ident.Plan.of(args.quick), args.amplitude, args.at,
                                  args.band)
        report = ident.analyse(source, args.joint, out, args.population, args.generations)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except Interrupted as exc:  # what it stopped, said where it was stopped
        print(exc, file=sys.stderr)
        return 130
    except KeyboardInterrupt:  # before the experiments or the reading, or while the figures are written
        print(f"interrupted: identify stopped; {out} may hold part of its files", file=sys.stderr)
        return 130
    print(json.dumps({k: report[k] for k in ("joint", "model", "rig_file", "figures", "fit_percent",
                                             "heldout_fit_percent", "wall_s")}, indent=2))
    return 0


def new_key(args) -> int:
    """Your own key pair, made here: the secret stays with you, the public file goes to the lab."""
    if not args.name:
        raise SystemExit("pneumactl keys new NAME")
    public, secret = keys.new_client_pair(args.dir, args.name, args.server_key)
    print(f"your key: {secret} (mode 0600: keep it to yourself)\n"
          f"send {public} to the lab, who allow it with `pneumad keys allow {os.path.basename(public)}`"
          + ("" if args.server_key else "; use it with --server-key server.key (the daemon's public key)"))
    if warning := keys.commit_warning(secret):
        print(warning, file=sys.stderr)
    return 0


def timeout_hint(client: Client) -> str:
    """Whether the daemon is there at all: a quick ping on the control socket."""
    try:
        client.call("ping", control=True, timeout=0.5)
    except RemoteError:
        return " (pneumad answers, but not this request: see `pneumactl status`)"
    except KeyRefused as exc:
        return f" ({exc})"
    except TimeoutError:
        return " (is pneumad running?)"
    return " (pneumad is running: the request may still be in progress, see `pneumactl status`)"


def run(client: Client, args):
    w = args.what
    if w in ("ping", "status", "describe"):
        return getattr(client, w)()
    if w == "estop":
        return client.estop("pneumactl")
    if w == "abort":
        return client.abort()
    if w in ("enable", "disable", "reset"):
        return with_lease(client, getattr(client, w))
    if w == "watch":
        from daemon.client.watch import watch  # rich: only for the live view
        watch(client, args.seconds)
        return None
    if w in MOTION:
        return motion(client, args)
    if w == "record.start":
        return client.record_start(args.name, args.seconds)
    if w == "record.stop":
        return client.record_stop(args.name)
    if w == "record.list":
        return client.record_list()
    if w == "record.snapshot":
        return client.record_snapshot(args.name)
    if w == "controller":
        if args.action == "list":
            return client.controllers()
        if args.action == "get":
            return client.controller()
        if args.action == "commit":
            return with_lease(client, lambda: client.commit(args.force))
        if args.action == "discard":
            return with_lease(client, client.discard)
        if args.action == "reload":
            if len(args.args) != 1:
                raise SystemExit("controller reload NAME")
            return client.reload_controller(args.args[0])
        if args.action in ("switch", "shadow"):
            if not args.args:
                raise SystemExit(f"controller {args.action} NAME [KEY=VALUE ...] [--design FILE]")
            # the design read before the lease is taken: under load it can outlast the lease's time to live
            request = client.candidate(args.args[0], key_values(args.args[1:]), args.design)
            result = with_lease(client, lambda: client.call(f"controller.{args.action}", request))
            for key, values in result.get("reset", {}).items():  # the user's setting, not silently dropped
                was = values["was"]
                print(f"note: {key} was set to {was} on the controller replaced; {result['active']} starts it at "
                      f"{values['now']} (`pneumactl controller set {key}={json.dumps(was)}` sets it again)",
                      file=sys.stderr)
            for key, value in result.get("carried", {}).items():
                print(f"note: {key} = {value}, as set on {result.get('shadow', result.get('active'))} before",
                      file=sys.stderr)
            return result
        return with_lease(client, lambda: client.set_params(**key_values(args.args)))
    if w == "keys":
        return client.call("keys.reload")  # the command socket: the control socket serves the arm's stops only
    if w == "load":
        if args.action == "clear":
            return with_lease(client, client.clear_load)
        if args.mass_kg is None:
            raise SystemExit("load set MASS_KG [--com ALONG,ACROSS]")
        try:
            com = [float(v) for v in args.com.split(",")]
        except ValueError:
            raise SystemExit(f"--com {args.com!r}: two numbers ALONG,ACROSS [mm]") from None
        return with_lease(client, lambda: client.set_load(args.mass_kg, com))
    if w == "payload":
        from pathlib import Path

        from daemon.client import payload_routine
        try:
            return payload_routine.run(client, Path(args.reference), args.unloaded, args.apply)
        except ValueError as exc:
            raise SystemExit(f"error: {exc}") from None
    if w == "identify":
        code = identify(client, args)
        if code:
            raise SystemExit(code)
        return None
    if w == "record":
        code = record(client, args.file, args.seconds)
        if code:
            raise SystemExit(code)
        return None
    raise SystemExit(f"unknown command {w}")


if __name__ == "__main__":
    sys.exit(main())
