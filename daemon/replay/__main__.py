"""``python -m daemon.replay RUN.mcap [--config RIG] [--out DIR] [--part X]``: what ``pneumactl
replay`` runs (daemon/replay/run.py). Exit status 0: replayed; 1: refused (what is missing
said); 2: the file cannot be read; 3: replayed, from a cut file (said); 130: stopped by Ctrl-C."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from daemon.recordings.reading import open_run
from daemon.replay import figures
from daemon.replay.run import Refused, replay


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="pneumactl replay", description=__doc__.splitlines()[0])
    p.add_argument("recording")
    p.add_argument("--config", default=None, help="replay on this rig file's model (default: the recording's own)")
    p.add_argument("--out", default=None, help="directory for the PNGs and report.json (default: RUN-replay)")
    p.add_argument("--part", type=float, default=None,
                   help="the difference [deg or mm] beyond which measured and simulated have parted (default 1)")
    args = p.parse_args(argv)
    path = Path(args.recording)
    try:
        run = open_run(path)
        rig_text = Path(args.config).read_text() if args.config else None
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"replaying {path.name} on the {'given' if args.config else 'recorded'} rig's model (Ctrl-C stops it)",
          file=sys.stderr, flush=True)
    try:
        result = replay(run, rig_text, args.part)
    except Refused as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    out = Path(args.out) if args.out else path.with_name(path.stem + "-replay")
    written = figures.plot(result, out, path.name)
    report = figures.summary(result)
    (out / "report.json").write_text(json.dumps(report, indent=2))
    for joint, f in report["joints"].items():
        where = f"parted at {f['parted_s']:.2f} s" if f["parted_s"] is not None else "never parted"
        print(f"{joint}: Fit {f['fit_percent']:.1f} %, RMS {f['rms_' + f['unit']]:.3g} {f['unit']}, "
              f"largest {f['max_' + f['unit']]:.3g} {f['unit']}, {where} (limit {f['part_limit']:g} {f['unit']})")
    if report["tripped"]:
        print(report["tripped"])
    print(f"wrote {', '.join(str(w) for w in written)} and {out / 'report.json'}")
    notice = run.cut_notice(path.name)
    if notice:  # replayed as far as it goes, never passed off as whole (as plot and export)
        print(f"warning: {notice}; the replay covers what is there (exit 3)", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        print("interrupted: the replay stopped; its figures and report.json are written only once it has run "
              "(a file being written when it stopped may be incomplete)", file=sys.stderr)
        sys.exit(130)
