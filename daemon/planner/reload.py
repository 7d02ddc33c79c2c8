"""``controller.reload``, the planner worker's side: a controller directory's plugin file read
again, executed as its new version's module (:mod:`controllers.directory`), and checked before
anything in the daemon sees it: each controller it defines built on the rig (its defaults),
reset from the measured state and the output in force, and stepped once holding the measured
angles; its output must be one finite value per command. The loop's controller is not touched:
the daemon's process takes the new version when the reply arrives, and ``switch``/``shadow``
build it from then on.

``describe``'s controllers are re-described and the whole reply packed here too, so the loop's
thread only swaps references when it takes the result.
"""
from __future__ import annotations

from dataclasses import dataclass

from controllers import directory
from controllers.base import ControllerContext, JointState, Reference, check_output
from daemon.wire import protocol as P


@dataclass(frozen=True)
class Reloaded:
    source: directory.Source
    controllers: list  # describe's controller entries, this file's replaced
    described: dict  # describe, with them
    packed: P.Packed  # ... packed


@dataclass(frozen=True)
class Refused:
    message: str
    file: str


def reload_file(context: ControllerContext, path: str, taken: frozenset, state: JointState, last_output: list,
                described: dict) -> Reloaded | Refused:
    """The file at ``path`` (the daemon's, from its table: never a request's) as a new version,
    checked; its controllers' names may not be ``taken`` by another's. Refused (with the
    plugin's own error, file and line) if it does not import, defines no controller, or one of
    them cannot be built or stepped."""
    try:
        source = directory.read(path, taken)
    except directory.PluginError as exc:
        return Refused(str(exc), path)
    hold = Reference(list(state.angles), [0.0] * context.n, [0.0] * context.n)
    entries = []
    for name, _ in source.controllers:
        cls, stage = source.cls(name), "could not be built"
        try:
            controller = cls(context)
            stage = "failed in reset()"
            controller.reset(state, list(last_output))
            stage = "failed in step() on the measured state"
            check_output(controller.step(state, hold), context.width)
            stage = "could not be described"
            entries.append({**cls.describe(), "source": source.provenance})
        except Exception as exc:  # whatever the plugin raises: a refusal naming it
            return Refused(f"{path}: {name} {stage}: {type(exc).__name__}: {exc}", path)
    controllers = [c for c in described["controllers"] if _file(c) != path] + entries
    described = {**described, "controllers": controllers}
    return Reloaded(source, controllers, described, P.Packed.of(described))


def _file(entry: dict) -> str | None:
    return (entry.get("source") or {}).get("file") or entry.get("file")

