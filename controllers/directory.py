"""Controllers from directories the daemon's admin names (``pneumad --controller-dir DIR``, or
the rig file's ``[rig] controller_dirs``): each ``*.py`` file there (not ``_*``) is a plugin
module, and each :class:`~controllers.base.Controller` subclass it defines with a ``name`` is a
controller under that name. A request names a controller, never a file or a module.

A file is read whole, hashed (SHA-256 of its bytes) and executed from that text under a module
name of its own version, ``pneumad_plugin_<stem>_<first 12 hex of the hash>``, so an edited
file loaded again (``controller.reload``) is a new module beside the old one: the controller
running on the old class runs on, and a switch or shadow builds the new one. The text travels
with the version (:class:`Source` pickles as its text and executes it where it arrives), so the
planner worker, the daemon's process, and a worker started again all run the very bytes whose
hash ``controller.list``, the switch event and the recordings carry.
"""
from __future__ import annotations

import hashlib
import inspect
import sys
import traceback
import types
from dataclasses import dataclass, field
from pathlib import Path

from controllers.base import Controller

MAX_BYTES = 1 << 20  # a plugin file larger than this is refused (it travels with every build job)
PREFIX = "pneumad_plugin_"
LOADED: dict[str, "Source"] = {}  # module name -> the version executed in this process


class PluginError(Exception):
    """A plugin file that cannot be read, executed or used; the message names the file and line."""


@dataclass(frozen=True)
class Source:
    """One version of a plugin file: where it was read, its text and hash, the module it runs
    as, and the controllers it defines (name, class's qualified name)."""

    path: str
    sha256: str
    text: str
    module: str
    controllers: tuple[tuple[str, str], ...] = ()

    def __reduce__(self):  # arrives executed: a class of it unpickled after it finds its module
        return _arrive, (self.path, self.sha256, self.text, self.module, self.controllers)

    @property
    def provenance(self) -> dict:
        """What the switch event, controller.list and the recordings say of it."""
        return {"file": self.path, "sha256": self.sha256}

    def target(self, name: str) -> str:
        """``module:Class`` of controller ``name`` (the registry's form)."""
        return f"{self.module}:{dict(self.controllers)[name]}"

    def cls(self, name: str) -> type[Controller]:
        return getattr(sys.modules[self.module], dict(self.controllers)[name])


@dataclass
class Directories:
    """The daemon's controller directories and what they hold now: each controller name's
    current version, and the files that would not load (``{name: stem, file, error}``)."""

    dirs: tuple[str, ...] = ()
    sources: dict[str, Source] = field(default_factory=dict)
    refused: list[dict] = field(default_factory=list)

    def plugins(self) -> dict[str, str]:
        """name -> module:Class, as the registry takes configured plugins."""
        return {name: s.target(name) for name, s in self.sources.items()}

    def file_of(self, name: str) -> str | None:
        """The file controller (or refused file stem) ``name`` comes from, or a file of that stem
        put in a directory since (``NAME.py``: a new plugin, loaded by its first reload); None:
        not from here."""
        if name in self.sources:
            return self.sources[name].path
        refused = next((r["file"] for r in self.refused if r["name"] == name), None)
        if refused is not None or not name.isidentifier() or name.startswith("_"):  # never a path: a plain stem
            return refused
        return next((str(Path(d) / f"{name}.py") for d in self.dirs if (Path(d) / f"{name}.py").is_file()), None)

    def replace(self, path: str, new: Source) -> None:
        """``new`` is the version of ``path`` from now on: its controllers replace the file's."""
        self.sources = {n: s for n, s in self.sources.items() if s.path != path}
        self.sources.update({name: new for name, _ in new.controllers})
        self.refused = [r for r in self.refused if r["file"] != path]

    def live(self, *in_use: type) -> tuple[Source, ...]:
        """The versions a build may need: every current one, and those of classes in use."""
        kept = {s.module: s for s in self.sources.values()}
        for cls in in_use:
            source = LOADED.get(getattr(cls, "__module__", ""))
            if source is not None:
                kept.setdefault(source.module, source)
        return tuple(kept.values())


def scan(dirs, taken) -> Directories:
    """Every plugin file in ``dirs`` (paths, in order) loaded; a file that fails, or defines a
    name already ``taken`` (built-ins, other plugins) or defined by an earlier file, is refused
    with its error. PluginError if a directory does not exist."""
    found = Directories(tuple(str(Path(d).resolve()) for d in dirs))
    taken = set(taken)
    for d in found.dirs:
        if not Path(d).is_dir():
            raise PluginError(f"controller directory {d}: not a directory")
        for path in sorted(Path(d).glob("*.py")):
            if path.name.startswith("_") or not path.stem.isidentifier():
                continue
            try:
                source = read(str(path), taken)
            except PluginError as exc:
                found.refused.append({"name": path.stem, "file": str(path), "error": str(exc)})
                continue
            taken.update(name for name, _ in source.controllers)
            found.sources.update({name: source for name, _ in source.controllers})
    return found


def read(path: str, taken=()) -> Source:
    """The file at ``path`` read, hashed and executed as its version's module (at once if this
    version was executed before); PluginError naming the file and line if it cannot be, defines
    no controller, or defines one under a ``taken`` name."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise PluginError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    if len(data) > MAX_BYTES:
        raise PluginError(f"{path}: {len(data)} bytes, more than a plugin file may hold ({MAX_BYTES})")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PluginError(f"{path}: not UTF-8 text: {exc}") from None
    sha = hashlib.sha256(data).hexdigest()
    module = execute(path, text, f"{PREFIX}{Path(path).stem}_{sha[:12]}")
    controllers = tuple((cls.name, cls.__qualname__) for cls in vars(module).values()
                        if isinstance(cls, type) and issubclass(cls, Controller) and cls.__module__ == module.__name__
                        and cls.name and not inspect.isabstract(cls))
    if not controllers:
        raise PluginError(f"{path}: defines no controller (a Controller subclass with a name)")
    clash = sorted(name for name, _ in controllers if name in set(taken))
    if clash:
        raise PluginError(f"{path}: the name {clash[0]!r} is taken (a built-in or another plugin's)")
    source = Source(path, sha, text, module.__name__, controllers)
    LOADED[source.module] = source
    return source


def execute(path: str, text: str, name: str) -> types.ModuleType:
    """``text`` run as module ``name`` (once per process: the module if it was); PluginError
    with the exception and the plugin's own line where it failed."""
    module = sys.modules.get(name)
    if module is not None:
        return module
    module = types.ModuleType(name)
    module.__file__ = path
    sys.modules[name] = module  # before it runs: dataclasses and pickle look it up there
    try:
        exec(compile(text, path, "exec"), module.__dict__)
    except BaseException as exc:  # whatever a plugin's import raises, SystemExit included
        del sys.modules[name]
        raise PluginError(f"{path}{_where(exc, path)}: {type(exc).__name__}: {exc}") from None
    return module


def provenance(cls: type) -> dict | None:
    """The file and hash a controller class was loaded from, None for one not from a directory."""
    source = LOADED.get(cls.__module__)
    return None if source is None else source.provenance


def _where(exc: BaseException, path: str) -> str:
    """``, line N`` of the plugin's own frame deepest in the traceback (a SyntaxError's line)."""
    if isinstance(exc, SyntaxError) and exc.filename == path:
        return f", line {exc.lineno}"
    lines = [f.lineno for f in traceback.extract_tb(exc.__traceback__) if f.filename == path]
    return f", line {lines[-1]}" if lines else ""


def _arrive(path: str, sha256: str, text: str, module: str, controllers) -> Source:
    """A Source unpickled: its module executed in this process if it was not."""
    source = Source(path, sha256, text, module, tuple(map(tuple, controllers)))
    if module not in sys.modules:
        execute(path, text, module)
    LOADED.setdefault(module, source)
    return source
