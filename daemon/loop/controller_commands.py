"""The controller commands, the loop's side (:class:`daemon.loop.commands.Commands` is made
of these and the rest): list and get, and what is built beside the loop and taken at a cycle
boundary: switch, set, shadow (then commit or discard) and reload (a controller directory's file
read again: :mod:`daemon.planner.reload`)."""
from __future__ import annotations

from controllers import directory, registry
from daemon.loop.safety import StateError
from daemon.planner import commands as planner
from daemon.planner import reload as reloading
from daemon.wire import protocol as P
from daemon.wire.arguments import CommandFailed, bad_args


class ControllerCommands:
    """Mixed into Commands: reads its view, loop, preparer and ``_off_loop``."""

    def controller_list(self, args):
        return {"active": self.view.controller.name, "available": self._controllers}

    @staticmethod
    def _describe_controllers(plugins: dict[str, str]) -> list[dict]:
        """Every registered controller described, or refused: ``{name, error}`` for a plugin
        that cannot be loaded or described (whatever its module raises: never fatal)."""
        available = []
        for name in registry.available(plugins):
            try:
                cls = registry.load(name, plugins)
                source = directory.provenance(cls)
                available.append({**cls.describe(), **({"source": source} if source else {})})
            except LookupError as exc:
                available.append({"name": name, "error": str(exc)})
            except Exception as exc:  # a plugin's module or describe() that raises: refused, the daemon starts
                available.append({"name": name, "error": f"{type(exc).__name__}: {exc}"})
        return available

    def controller_get(self, args):
        c = self.view.controller
        return {"name": c.name, "params": c.get_params(), "spec": [p.describe() for p in c.params],
                "source": directory.provenance(type(c))}

    def controller_switch(self, request):
        """Build a controller beside the loop, then swap it in at a cycle boundary (bumpless);
        the parameters set on it before are carried (``carried`` says which)."""

        def finish(built):
            new, name, carried, given, reset = built
            self.loop.switch(new)
            self._active_as = name
            self._sync_sources()
            self._set_before[name] = {**carried, **given}
            return {"active": new.name, "params": new.get_params(), "carried": carried, "reset": reset,
                    "cycle": self.view.cycle}

        return self._off_loop(finish, planner.build_controller, self.view.context, self.view.controller_plugins,
                              request, self._set_before, self._active_as)

    def controller_set(self, request):
        """Validate and derive a parameter change beside the loop; apply it at a cycle boundary."""
        c, name = self.view.controller, self._active_as

        def finish(result):
            prepared, given = result
            params = self.loop.set_params(c, prepared)
            self._set_before[name] = {**self._set_before.get(name, {}), **given}
            return {"name": c.name, "params": params, "cycle": self.view.cycle}

        return self._off_loop(finish, planner.prepare_change, type(c), c.context, c.given_options, c.get_params(),
                              request)

    def controller_shadow(self, request):
        """Build a candidate beside the loop and run it beside the active controller, unapplied."""

        def finish(built):
            candidate, name, carried, given, _ = built
            self.loop.shadow(candidate)
            self._shadow_set = (name, {**carried, **given})
            self._sync_sources()
            return {"shadow": candidate.name, "active": self.view.controller.name, "carried": carried,
                    "cycle": self.view.cycle}

        return self._off_loop(finish, planner.build_controller, self.view.context, self.view.controller_plugins,
                              request, self._set_before, self._active_as)

    def controller_commit(self, args):
        """Make the shadow candidate the active controller (bumpless); the run's comparison."""
        summary = in_state(lambda: self.loop.commit(args.get("force", False)))
        self._sync_sources()
        if self._shadow_set is not None:  # the candidate's name and parameters are the active ones now
            self._active_as, self._set_before[self._shadow_set[0]] = self._shadow_set
            self._shadow_set = None
        return {**summary, "active": self.view.controller.name, "cycle": self.view.cycle}

    def controller_discard(self, args):
        """End the shadow run without applying it; the run's comparison."""
        summary = in_state(self.loop.discard)
        self._shadow_set = None
        self._sync_sources()
        return summary

    def controller_reload(self, request):
        """Read a controller directory's file again beside the loop and check it
        (:mod:`daemon.planner.reload`); its new version is built by switch and shadow from then
        on, while the controller running now runs on. The request names a controller (or a
        refused file); the file is the daemon's own record of where that name came from."""
        name = P.decode_args(request)["name"]  # one short string: checked against the catalog by the messenger
        path = self.dirs.file_of(name)
        if path is None:
            reloadable = sorted({*self.dirs.sources, *(r["name"] for r in self.dirs.refused)})
            raise bad_args(f"{name!r} is not from a controller directory: only those reload (from: "
                           f"{', '.join(reloadable) or 'none; start the daemon with --controller-dir DIR'}); a "
                           f"built-in or an installed plugin changes with a restart", "name", allowed=reloadable)
        previous = self.dirs.sources.get(name)
        taken = frozenset(n for n in registry.available(self.view.controller_plugins)
                          if self.dirs.file_of(n) != path)

        def finish(result):
            if isinstance(result, reloading.Refused):
                self.loop.events.add({"kind": "reload", "action": "refused", "name": name, "file": path,
                                      "cause": result.message})
                raise CommandFailed(P.REFUSED, f"{result.message} (the version loaded before stays: "
                                               f"{self.view.controller.name} runs on)",
                                    {"reason": "plugin", "file": path})
            source = result.source
            unchanged = previous is not None and previous.sha256 == source.sha256
            for old in [n for n, s in self.dirs.sources.items() if s.path == path]:
                self.view.controller_plugins.pop(old, None)
            self.dirs.replace(path, source)
            self.view.controller_plugins.update({n: source.target(n) for n, _ in source.controllers})
            self._controllers, self.described, self._describe_packed = result.controllers, result.described, \
                result.packed
            self.refused_controllers = [c for c in self._controllers if "error" in c]
            self._sync_sources()
            names = [n for n, _ in source.controllers]
            self.loop.events.add({"kind": "reload", "action": "unchanged" if unchanged else "loaded", "name": name,
                                  "controllers": names, **source.provenance})
            return {"name": name, "file": path, "sha256": source.sha256,
                    "previous_sha256": previous.sha256 if previous is not None else None, "unchanged": unchanged,
                    "controllers": names, "cycle": self.view.cycle}

        return self._off_loop(finish, reloading.reload_file, self.view.context, path, taken,
                              self.view.measured_state(), self.view.output(), self.described)

    def _sync_sources(self) -> None:
        """The plugin versions the worker is sent: the current ones, the active and shadow controllers'."""
        shadow = self.view.shadow_controller
        self.preparer.sources = self.dirs.live(type(self.view.controller), *(() if shadow is None else (type(shadow),)))


def in_state(control):
    """Call one of the loop's controls; a state it cannot act in is a ``bad_state`` error."""
    try:
        return control()
    except StateError as exc:
        raise CommandFailed(P.BAD_STATE, str(exc)) from None
