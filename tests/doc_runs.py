"""Running a document's line as a user types it: through bash, from a directory of the test's,
left with Ctrl-C where tests/doc_claims.toml says so (``interrupt_after``: a live view, a run
of minutes), every failure naming the document's line."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import time
from dataclasses import dataclass

from tests.doc_blocks import Command


@dataclass
class Done:
    command: Command
    returncode: int
    stdout: str
    stderr: str

    def explain(self) -> str:
        item = self.command.item
        return (f"{item.doc}:{item.line}: {item.written}\nran as: {self.command.text}\nexit {self.returncode}\n"
                f"--- stdout (end)\n{self.stdout[-3000:]}\n--- stderr (end)\n{self.stderr[-3000:]}")


def restore_sigint() -> None:
    """In the child before exec: SIGINT's default action (a terminal's Ctrl-C stops it). A
    test run started in the background by a script has SIGINT ignored, and children inherit
    that (a shell cannot undo it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(command: Command, cwd, env=None) -> subprocess.Popen:
    """The line in the background (bash ``exec``: the process is the line's own program)."""
    return subprocess.Popen(["bash", "-c", "exec " + command.text], cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, preexec_fn=restore_sigint)


def run(command: Command, cwd, env=None, timeout: float = 120.0) -> Done:
    """The line run to its end; or, if it is to be interrupted, until its output (stdout or
    stderr) matches ``interrupt_after``, then Ctrl-C, and to its end."""
    if command.interrupt_after is None:
        done = subprocess.run(["bash", "-c", command.text], cwd=cwd, env=env, capture_output=True, text=True,
                              timeout=timeout, preexec_fn=restore_sigint)
        return Done(command, done.returncode, done.stdout, done.stderr)
    proc = start(command, cwd, env)
    out, err = [], []
    readers = [threading.Thread(target=_drain, args=(stream, sink), daemon=True)
               for stream, sink in ((proc.stdout, out), (proc.stderr, err))]
    for reader in readers:
        reader.start()
    deadline = time.monotonic() + timeout
    try:
        while not re.search(command.interrupt_after, _text(out) + _text(err)):
            if proc.poll() is not None or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        proc.wait(timeout=max(10.0, deadline - time.monotonic()))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for reader in readers:
            reader.join(5)
    return Done(command, proc.returncode, _text(out), _text(err))


def _drain(stream, sink: list) -> None:
    for chunk in iter(lambda: os.read(stream.fileno(), 65536), b""):
        sink.append(chunk)


def _text(chunks: list) -> str:
    return b"".join(chunks).decode(errors="replace")
