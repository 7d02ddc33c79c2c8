"""The code blocks of README.md, docs/*.md and systemd/README.md, read for the tests that run
them, and the accounting of who runs each line (tests/doc_claims.toml).

Every shell line and Python snippet in those documents is run by a test, or is listed with
the reason it cannot run here; tests/test_doc_lines.py fails, naming the document, line and
text, when one is neither. What this module reads:

- **Blocks**: 4-space indented blocks after a blank line, and ``` fenced blocks. A block is a
  Python snippet (its first line ``import ...`` or ``from ... import``, or fenced ``python``),
  TOML (its first line a ``[table]``), JSON (it parses as JSON), or lines: a line is a shell
  command when it starts with ``$ `` (then only such lines are), or with ``command: ``/
  ``Produced by: `` (a bench's header in output it shows; then only those are), or else when
  its first word (after ``NAME=value`` assignments) is in ``COMMAND_WORDS`` or is a path
  (``.venv/bin/pneumactl``). A trailing comment (`` # ...``) and a trailing annotation (two
  spaces, then ``(...)``) are not part of the command; a line ending in ``\\`` continues on
  the next. Everything else (output, formulas, tables, log lines) is shown, not run.
- **Sections**: a block belongs to the heading above it (its text, without the ``#``s).

How to account for a line you add to a document:

1. Run it in a test, reading it from the document through this module, never a copy:
   ``doc_blocks.commands("docs/x.md", "Its heading")`` gives the section's shell lines (a
   ``match=`` regex picks some; section None: the whole document's), ``doc_blocks.snippet(...)``
   a Python snippet; each carries ``.text`` (what to run, the declared substitutions made),
   ``.written`` (as the document has it) and ``.line``; tests/doc_runs.py runs one as a user
   would. Then claim it in tests/doc_claims.toml: a ``[[run]]`` table with ``doc``,
   ``section`` (optional: every section), ``lines`` (optional: a regex the claimed lines match)
   and ``test`` (``tests/test_x.py::test_name``, a file that names the doc and section). The
   reading fails unless the calling test file claims what it reads.
2. What a test must change in a line to run it here (a private endpoint for the lab's, a
   scratch directory, a shorter ``--seconds``) is a ``[[substitute]]`` table of the same file:
   ``pattern`` (a regex), ``with`` (its replacement; ``{name}`` is a value the test passes,
   ``commands(..., link=...)``, ``{m1}`` the pattern's first group), ``reason``;
   ``interrupt_after`` (a regex of its output) says the line is left with Ctrl-C once it has
   printed that (a live view, a run of minutes).
3. A line no test can run here (real hardware, systemd as PID 1, an install from the
   network) is a ``[[cannot]]`` table with its ``reason``.

``python -m tests.doc_blocks`` prints every line and who runs it, or why it cannot run.
"""
from __future__ import annotations

import json
import re
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLAIMS = ROOT / "tests" / "doc_claims.toml"
BIN = str(Path(sys.executable).parent) + "/"  # the interpreter running the suite: its venv's bin

# First words that make a line of a block a shell command (a path to a program is one too).
COMMAND_WORDS = frozenset("""
    python python3 pip pneumad pneumactl sudo journalctl systemctl systemd-analyze udevadm echo
    make cmake chrt cyclictest taskset redis-server tiled start-re-manager bash sh env export cd cp
    mkdir git curl apt-get
""".split())
PROMPT = "$ "
HEADERS = ("command: ", "Produced by: ")  # a bench's own header line in the output a document shows
LOG_LINE = re.compile(r"^\S+ (DEBUG|INFO|WARNING|ERROR|CRITICAL): ")  # a program's log line, shown
ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=\S*$")


def documents() -> list[str]:
    """The documents whose lines are accounted for, as paths relative to the checkout."""
    return ["README.md", *(f"docs/{p.name}" for p in sorted((ROOT / "docs").glob("*.md"))), "systemd/README.md"]


@dataclass(frozen=True)
class Block:
    doc: str
    line: int  # the first content line, 1-based
    section: str  # the heading above it
    kind: str  # "python", "toml", "json", "lines"
    rows: tuple[tuple[int, str], ...]  # (line number, text with the block's indent removed)

    @property
    def text(self) -> str:
        return "\n".join(text for _, text in self.rows)


@dataclass(frozen=True)
class Item:
    """A shell command or a Python snippet of a document: what the accounting counts."""
    doc: str
    line: int
    section: str
    kind: str  # "shell" or "python"
    written: str  # the command as written (continuations joined, comment and annotation dropped), or the snippet

    def where(self) -> str:
        first = self.written.splitlines()[0] if self.written else ""
        return f"{self.doc}:{self.line} ({self.section}): {first}"


@dataclass(frozen=True)
class Command:
    """An item as a test runs it: ``text`` with the declared substitutions made."""
    item: Item
    text: str
    interrupt_after: str | None  # a regex of its output, after which the test sends Ctrl-C
    reasons: tuple[str, ...]  # the substitutions made, each with its reason

    @property
    def written(self) -> str:
        return self.item.written

    @property
    def line(self) -> int:
        return self.item.line


# ---- parsing ------------------------------------------------------------------------------

FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)")
HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$")


def blocks(doc: str, text: str | None = None) -> list[Block]:
    """The code blocks of ``doc`` (a path relative to the checkout), in order."""
    lines = (ROOT / doc).read_text().splitlines() if text is None else text.splitlines()
    out, section, i = [], "", 0
    while i < len(lines):
        line = lines[i]
        fence = FENCE.match(line)
        if fence:
            indent, mark, lang = len(fence.group(1)), fence.group(2), fence.group(3).lower()
            j = i + 1
            while j < len(lines) and not lines[j].lstrip().startswith(mark):
                j += 1
            rows = tuple((k + 1, lines[k][indent:] if not lines[k][:indent].strip() else lines[k].lstrip())
                         for k in range(i + 1, j))
            out.append(_block(doc, section, rows, lang))
            i = j + 1
            continue
        if (line.startswith("    ") or line.startswith("\t")) and line.strip() and (i == 0 or not lines[i - 1].strip()):
            j = i
            while j < len(lines) and (lines[j].startswith(("    ", "\t")) or not lines[j].strip()):
                j += 1
            while not lines[j - 1].strip():
                j -= 1
            rows = tuple((k + 1, lines[k][4:] if lines[k].startswith("    ") else lines[k][1:]) for k in range(i, j))
            out.append(_block(doc, section, rows, ""))
            i = j
            continue
        heading = HEADING.match(line)
        if heading:
            section = heading.group(1)
        i += 1
    return out


def _block(doc: str, section: str, rows, lang: str) -> Block:
    first = next((text.strip() for _, text in rows if text.strip()), "")
    body = "\n".join(text for _, text in rows)
    if lang in ("python", "py", "pycon") or (not lang and re.match(r"^(from\s+[\w.]+\s+import\s|import\s+\w)", first)):
        kind = "python"
    elif lang == "toml" or (not lang and re.match(r"^\[[\w.\-\" ]+\]\s*(#.*)?$", first)):
        kind = "toml"
    elif lang == "json" or (not lang and first[:1] in "{[" and _is_json(body)):
        kind = "json"
    else:
        kind = "lines"
    return Block(doc, rows[0][0] if rows else 0, section, kind, rows)


def _is_json(text: str) -> bool:
    try:
        json.loads(text)
    except ValueError:
        return False
    return True


def strip_note(line: str) -> str:
    """``line`` without a trailing comment (`` # ...``, outside quotes) or annotation (two
    spaces and ``(``, outside quotes: ``(vm x86_64 2 cpus, ...)``)."""
    quote = None
    for k, ch in enumerate(line):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (k == 0 or line[k - 1].isspace()):
            return line[:k].rstrip()
        elif ch == "(" and line[max(0, k - 2):k] == "  ":
            return line[:k].rstrip()
    return line.rstrip()


def is_command(line: str) -> bool:
    """A line whose first word (past ``NAME=value`` assignments) runs a program."""
    if LOG_LINE.match(line):
        return False
    words = line.split()
    while words and ASSIGNMENT.match(words[0]):
        words = words[1:]
    if not words:
        return False
    word = words[0]
    return word in COMMAND_WORDS or ("/" in word and re.match(r"^[\w./~-]+$", word) is not None
                                     and not word.endswith("/"))


def items(doc: str, text: str | None = None) -> list[Item]:
    """The shell commands and Python snippets of ``doc``."""
    out = []
    for block in blocks(doc, text):
        if block.kind == "python":
            out.append(Item(doc, block.line, block.section, "python", block.text.rstrip()))
        elif block.kind == "lines":
            out.extend(_commands(block))
    return out


def _commands(block: Block) -> list[Item]:
    rows = list(block.rows)
    if any(t.startswith(PROMPT) for _, t in rows):
        picked = [(n, t[len(PROMPT):]) for n, t in rows if t.startswith(PROMPT)]
        rows = _with_continuations(rows, picked)
    elif any(t.startswith(HEADERS) for _, t in rows):
        rows = [(n, next(t[len(h):] for h in HEADERS if t.startswith(h))) for n, t in rows if t.startswith(HEADERS)]
    else:
        rows = _with_continuations(rows, [(n, t) for n, t in rows if is_command(t.strip())])
    out = []
    for number, text in rows:
        written = strip_note(text.strip())
        if written:
            out.append(Item(block.doc, number, block.section, "shell", written))
    return out


def _with_continuations(rows, picked):
    """The picked lines, each joined with the lines its trailing ``\\`` continues onto."""
    by_number = dict(rows)
    joined = []
    for number, text in picked:
        n = number
        while strip_note(text).endswith("\\") and (n + 1) in by_number:
            n += 1
            text = strip_note(text)[:-1].rstrip() + " " + by_number[n].strip()
        joined.append((number, text))
    return joined


# ---- the claims file ------------------------------------------------------------------------

def load_claims(path: Path = CLAIMS) -> dict[str, list[dict]]:
    data = tomllib.loads(path.read_text())
    return {kind: data.get(kind, []) for kind in ("run", "cannot", "substitute")}


def covers(entry: dict, item: Item) -> bool:
    """Whether a claims-file table (run, cannot, substitute) is about ``item``."""
    if entry.get("doc", "*") not in ("*", item.doc):
        return False
    if "section" in entry and entry["section"] != item.section:
        return False
    return "lines" not in entry or re.search(entry["lines"], item.written) is not None


def test_file(claim: dict) -> str:
    return claim["test"].split("::", 1)[0]


# ---- reading for a test ----------------------------------------------------------------------

def commands(doc: str, section: str | None, match: str | None = None, **fill) -> list[Command]:
    """The shell commands of ``doc``'s ``section`` (None: of every section) that match
    ``match``, with the declared substitutions made (``fill`` gives their ``{name}`` values).
    The calling test file must claim each of them in tests/doc_claims.toml."""
    return _read(doc, section, "shell", match, fill)


def snippet(doc: str, section: str, match: str | None = None, **fill) -> Command:
    """The one Python snippet of ``doc``'s ``section`` (matching ``match``), as :func:`commands`."""
    found = _read(doc, section, "python", match, fill)
    if len(found) != 1:
        raise LookupError(f"{doc}, {section!r}: {len(found)} Python snippets match {match!r}, not one")
    return found[0]


def _read(doc: str, section: str | None, kind: str, match: str | None, fill: dict) -> list[Command]:
    found = [i for i in items(doc) if section in (None, i.section) and i.kind == kind
             and (match is None or re.search(match, i.written))]
    if not found:
        raise LookupError(f"{doc} has no {kind} lines" + (f" in a section {section!r}" if section else "")
                          + (f" matching {match!r}" if match else ""))
    claims = load_claims()
    callers = _calling_test_files()
    for item in found:
        if not any(covers(c, item) and test_file(c) in callers for c in claims["run"]):
            raise LookupError(f"{item.where()}: read by {', '.join(sorted(callers)) or 'no test file'}, which does not "
                              f"claim it: add a [[run]] table to tests/doc_claims.toml (tests/doc_blocks.py says how)")
    return [substituted(item, claims["substitute"], fill) for item in found]


def _calling_test_files() -> set[str]:
    """The files of tests/ on the calling stack (this one left out)."""
    here = Path(__file__).resolve()
    out, frame = set(), sys._getframe(1)
    while frame is not None:
        path = Path(frame.f_code.co_filename).resolve()
        if path != here and path.parent == here.parent:
            out.add(f"tests/{path.name}")
        frame = frame.f_back
    return out


def substituted(item: Item, substitutions: list[dict], fill: dict) -> Command:
    """``item`` with every substitution declared for it made, in the file's order."""
    values = {"bin": BIN, "python": sys.executable, **fill}
    text, interrupt, reasons = item.written, None, []
    for sub in substitutions:
        if not covers(sub, item):
            continue
        if "pattern" in sub:
            template = sub.get("with", "")

            def replace(m, template=template):
                return template.format_map(_Values(values, m))
            text, count = re.subn(sub["pattern"], replace, text, count=0 if sub.get("all") else 1)
            if not count:
                continue
        interrupt = sub.get("interrupt_after", interrupt)
        reasons.append(sub["reason"])
    return Command(item, text, interrupt, tuple(reasons))


class _Values(dict):
    """``{name}`` from the test's values; ``{m0}``, ``{m1}`` ... the pattern's match and groups; a callable
    value is called with the match."""

    def __init__(self, values: dict, match: re.Match):
        super().__init__(values)
        self.match = match

    def __missing__(self, key):
        if re.fullmatch(r"m\d", key):
            return self.match.group(int(key[1:])) or ""
        raise KeyError(f"substitution needs {{{key}}}: pass {key}=... to doc_blocks.commands")

    def __getitem__(self, key):
        value = super().__getitem__(key) if key in self else self.__missing__(key)
        return value(self.match) if callable(value) else value


# ---- the accounting ------------------------------------------------------------------------------

TO_DO = ("run it in a test that reads it through tests/doc_blocks.py and claim it with a [[run]] table "
         "in tests/doc_claims.toml, or list it there in a [[cannot]] table with the reason it cannot run "
         "here (tests/doc_blocks.py's docstring says how)")


@dataclass
class Accounting:
    run: dict[Item, list[dict]]  # each item some [[run]] claims, with the claims
    listed: dict[Item, dict]  # each item a [[cannot]] lists, with the entry
    problems: list[str]  # what is wrong, each naming the document, line and text


def account(all_items: list[Item], claims: dict[str, list[dict]]) -> Accounting:
    """Which claim runs or lists each item, and every item that is neither (or both), every
    table that matches no item, and every entry without its reason."""
    run, listed, problems = {}, {}, []
    for item in all_items:
        runs = [c for c in claims["run"] if covers(c, item)]
        cannot = [c for c in claims["cannot"] if covers(c, item)]
        if runs and cannot:
            problems.append(f"{item.where()}: claimed by {runs[0]['test']} and listed as not runnable "
                            f"({cannot[0]['reason'].split(chr(10))[0]} ...): one or the other")
        elif runs:
            run[item] = runs
        elif cannot:
            listed[item] = cannot[0]
        else:
            problems.append(f"{item.where()}: run by no test and listed nowhere: {TO_DO}")
    for kind in ("run", "cannot", "substitute"):
        for k, entry in enumerate(claims[kind]):
            label = f"tests/doc_claims.toml [[{kind}]] #{k + 1} {_label(entry)}"
            if kind != "run" and not entry.get("reason", "").strip():
                problems.append(f"{label}: no reason")
            if kind == "run" and "test" not in entry:
                problems.append(f"{label}: no test")
            if kind == "substitute":
                hit = [i for i in run if covers(entry, i) and
                       ("pattern" not in entry or re.search(entry["pattern"], i.written))]
                if not hit:
                    problems.append(f"{label}: substitutes in no line a test runs (the document changed?): "
                                    f"update it or remove it")
            elif not any(covers(entry, i) for i in all_items):
                problems.append(f"{label}: matches no line of the documents (the document changed?): "
                                f"update it or remove it")
    return Accounting(run, listed, problems)


def _label(entry: dict) -> str:
    return "(" + ", ".join(f"{k} {entry[k]!r}" for k in ("doc", "section", "lines", "pattern") if k in entry) + ")"


def all_items() -> list[Item]:
    return [item for doc in documents() for item in items(doc)]


def main() -> int:
    """Print every shell line and Python snippet of the documents and who runs it."""
    result = account(all_items(), load_claims())
    for item in all_items():
        who = (", ".join(sorted({c["test"] for c in result.run[item]})) if item in result.run else
               "CANNOT: " + result.listed[item]["reason"].split("\n")[0] if item in result.listed else "NEITHER")
        print(f"{item.doc}:{item.line}: {item.written.splitlines()[0][:90]}\n    {who}")
    print(f"\n{len(result.run)} run, {len(result.listed)} listed, {len(result.problems)} problems")
    for problem in result.problems:
        print("PROBLEM: " + problem)
    return 1 if result.problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
