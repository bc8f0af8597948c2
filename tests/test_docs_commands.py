"""Every ``usdbtf ...`` command line the documentation quotes parses with today's command line.

The README, the guides under ``docs/`` and ``benchmarks/README.md`` quote commands in code
blocks and in inline code.  Each is split like a shell would (``shlex``) and handed to the
real parser (:func:`usdbtf.cli.build_parser`) without running anything, so a renamed or
removed option, a wrong command name or a missing positional argument fails here rather
than in a reader's terminal.  Placeholders such as ``IN``, ``OUT`` or ``SCENE.usda`` are
positional strings, which the parser takes as they are.

What counts as a command line:

- in a fenced code block, every ``usdbtf`` in a command's place: at the start of a line (after
  an optional ``$`` prompt), after ``.venv/bin/``, or right inside ``$(``; a line ending in ``\\`` continues; a ``#`` comment,
  a pipe, ``;``, ``&&`` or a trailing ``&`` ends it;
- in inline code, a span that starts with ``usdbtf`` and a word.  A span of only
  ``usdbtf NAME`` names a command (in prose: "`usdbtf compress`'s own parser"), so only the
  name is checked.  Prose also quotes a command with the options it is talking about
  (`usdbtf unwrap --btf COMPRESSED --keep-uvs`): an inline span may leave out required
  arguments, but every option it names must exist and take the values it is given.  Code
  blocks are command lines to copy, so they must parse whole.

Optional parts in square brackets (``usdbtf bench [--quick]``) are parsed with their
contents, and spans that are templates rather than command lines (``usdbtf <stage>``,
``usdbtf CMD: error: ...``, anything with an ellipsis) are skipped.  An upper-case word given
to an option that checks its value (``--size N``, ``--dask ADDRESS``) is a placeholder: it is
replaced by a value the option accepts (its first choice, or the first of a few typical
values its type takes), so the option's name and arity are still checked.

Seconds: parsing only, no USD or numpy import beyond what the parser needs.
"""
from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", ROOT / "benchmarks" / "README.md", *(ROOT / "docs").glob("*.md")])

_FENCE = re.compile(r"^\s*```")
_START = re.compile(r"(?:^\s*(?:\$\s+)?|(?<=\$\()|(?<=\.venv/bin/))usdbtf(?=\s)")
_INLINE = re.compile(r"(?<!`)`(usdbtf [^`]+)`(?!`)")
_TEMPLATE = re.compile(r"<|\bCMD\b|\.\.\.|…|\\\|")


def _cut(text: str) -> str:
    """A command line up to where the shell would end it (comment, pipe, list, subshell)."""
    out, quote, depth = [], None, 0
    for i, ch in enumerate(text):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "(":
            depth += 1
        elif ch == ")":
            if depth == 0:
                break
            depth -= 1
        elif ch == "#" and (i == 0 or text[i - 1].isspace()):
            break
        elif ch in ";|" or text.startswith("&&", i) or (ch == "&" and re.match(r"\s*(#|$)", text[i + 1:])):
            break
        out.append(ch)
    return "".join(out).strip()


def _block_commands(lines: list[str]) -> list[str]:
    """The ``usdbtf`` command lines of one code block's lines (continuations joined)."""
    joined, buf = [], ""
    for line in lines:
        if line.rstrip().endswith("\\"):
            buf += line.rstrip()[:-1] + " "
            continue
        joined.append(buf + line)
        buf = ""
    if buf:
        joined.append(buf)
    found = []
    for line in joined:
        stripped = line.strip()
        if stripped.startswith("#"):
            continue
        for m in _START.finditer(line):
            found.append(_cut(line[m.start():]))
    return found


def doc_commands(path: Path) -> list[tuple[str, int, str, bool]]:
    """(file name, line number, command text, inline) of every command line quoted in one document."""
    text = path.read_text(encoding="utf-8").splitlines()
    found, block, start = [], None, 0
    for number, line in enumerate(text, 1):
        if _FENCE.match(line):
            if block is None:
                block, start = [], number
            else:
                found += [(path.name, start, cmd, False) for cmd in _block_commands(block)]
                block = None
            continue
        if block is not None:
            block.append(line)
            continue
        for m in _INLINE.finditer(line):
            found.append((path.name, number, m.group(1).strip(), True))
    return found


def _words(command: str) -> list[str] | None:
    """The argument words after ``usdbtf``, or None for a template that is not a command line."""
    if _TEMPLATE.search(command):
        return None
    command = re.sub(r"\[([^\[\]]*)\]", r"\1", command)        # [--quick] -> --quick
    words = shlex.split(command)
    assert words[0] == "usdbtf"
    return words[1:]


def _commands():
    out = []
    for path in DOCS:
        for name, line, command, inline in doc_commands(path):
            words = _words(command)
            if words:
                out.append(pytest.param(words, inline, id=f"{name}:{line}:{' '.join(words)[:60]}"))
    return out


_PLACEHOLDER = re.compile(r"[A-Z][A-Z0-9_]*")
#: Values tried, in order, for a placeholder given to an option whose type checks its value.
_SAMPLES = ("16", "1", "0.5", "local:1", "30,0", "dir:0,0,1", "eye=0,0,1 target=0,0,0", "k8")


def _accepts(action, value: str) -> bool:
    """Whether an option takes ``value`` as it is (then it is not a placeholder to fill)."""
    if action.choices:
        return value in action.choices
    if callable(action.type):
        try:
            action.type(value)
        except Exception:       # noqa: BLE001 - argparse's own test: any error refuses
            return False
    return True


def _filled(parser, words: list[str]) -> list[str]:
    """``words`` with each placeholder value of a typed option replaced by one it accepts."""
    commands = parser._subparsers._group_actions[0].choices
    sub = commands.get(words[0]) if words else None
    if sub is None:
        return words
    words, i = list(words), 1
    while i < len(words):
        action = sub._option_string_actions.get(words[i])
        i += 1
        if action is None or action.nargs == 0:
            continue
        n = action.nargs if isinstance(action.nargs, int) else 1
        for j in range(i, min(i + n, len(words))):
            if not _PLACEHOLDER.fullmatch(words[j]) or _accepts(action, words[j]):
                continue
            if action.choices:
                words[j] = str(next(iter(action.choices)))
            elif callable(action.type):
                for value in _SAMPLES:
                    try:
                        action.type(value)
                    except Exception:       # noqa: BLE001 - argparse's own test: any error refuses
                        continue
                    words[j] = value
                    break
        i += n
    return words


COMMANDS = _commands()


def _parse(parser, words):
    """(exit status or None, stderr) of parsing ``words``: None when it parsed."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            parser.parse_args(words)
    except SystemExit as stop:
        return stop.code, err.getvalue()
    return None, err.getvalue()


@pytest.fixture(scope="module")
def parser():
    from usdbtf.cli import build_parser

    return build_parser()


def test_the_documents_quote_commands():
    """The extraction finds the commands (a regex gone wrong would find none and pass)."""
    assert len(COMMANDS) >= 60, len(COMMANDS)
    names = {p.values[0][0] for p in COMMANDS}
    assert {"compress", "package", "build", "render", "preview", "quilt", "unwrap", "rectify", "bench"} <= names


_MISSING = re.compile(r"the following arguments are required|one of the arguments .* is required")


@pytest.mark.parametrize("words, inline", COMMANDS)
def test_quoted_command_parses(parser, words, inline):
    commands = parser._subparsers._group_actions[0].choices
    if len(words) == 1 and not words[0].startswith("-"):
        assert words[0] in commands, f"usdbtf {words[0]}: no such command"
        return
    status, err = _parse(parser, _filled(parser, words))
    if inline and status == 2 and _MISSING.search(err):
        return                      # prose naming some options of a command: they all exist
    assert status in (None, 0), f"usdbtf {' '.join(words)}: {err.strip()}"


def test_a_wrong_command_line_fails_the_check(parser):
    """The control: the parser used here refuses an unknown option and a missing argument,
    and a placeholder is filled only where an option checks its value."""
    assert _parse(parser, ["compress", "IN", "-o", "OUT", "--no-such-option"])[0] == 2
    assert _parse(parser, ["package", "-o", "asset.usda"])[0] == 2
    assert _parse(parser, ["compress", "IN", "-o", "OUT", "--k", "150"])[0] is None
    filled = _filled(parser, ["quilt", "C", "-o", "Q", "--size", "W", "H", "--codec", "X"])
    assert filled[:4] == ["quilt", "C", "-o", "Q"] and filled[4:7] == ["--size", "16", "16"]
    assert _parse(parser, _filled(parser, ["compress", "IN", "-o", "OUT", "--dask", "ADDRESS", "--k", "K"]))[0] is None
    assert _parse(parser, _filled(parser, ["quilt", "C", "-o", "Q", "--atlas"]))[0] == 2       # arity still checked


def test_extraction_rules(tmp_path):
    doc = tmp_path / "x.md"
    doc.write_text(
        "Run `usdbtf compress IN -o OUT --k 8`, `usdbtf <stage>` and `usdbtf bench [--quick]`.\n"
        "```sh\n"
        'eval "$(usdbtf env)"   # the environment\n'
        "usdbtf render C --swatch \\\n    --view 30,0 -o x.exr   # a comment\n"
        "usdbtf rig-sim --pty &\n"
        "python -m usdbtf.gpu.shaders\n"
        "```\n", encoding="utf-8")
    commands = [c for _, _, c, _ in doc_commands(doc)]
    assert commands == ["usdbtf compress IN -o OUT --k 8", "usdbtf <stage>", "usdbtf bench [--quick]",
                        "usdbtf env", "usdbtf render C --swatch      --view 30,0 -o x.exr", "usdbtf rig-sim --pty"]
    assert [_words(c) for c in commands] == [["compress", "IN", "-o", "OUT", "--k", "8"], None, ["bench", "--quick"],
                                             ["env"], ["render", "C", "--swatch", "--view", "30,0", "-o", "x.exr"],
                                             ["rig-sim", "--pty"]]


# --- links -----------------------------------------------------------------------------------

_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower().replace("`", ""))
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    lines, inside = [], False
    for line in path.read_text(encoding="utf-8").splitlines():
        if _FENCE.match(line):
            inside = not inside
        elif not inside and line.startswith("#"):
            lines.append(_slug(line.lstrip("#")))
    return set(lines)


LINKED = [ROOT / "README.md", ROOT / "benchmarks" / "README.md", ROOT / "benchmarks" / "RESULTS.md",
          *(ROOT / "docs").glob("*.md"), *(ROOT / "benchmarks" / "history").glob("*.md")]


@pytest.mark.parametrize("path", LINKED, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    """Every relative link and picture of the documents names a file (and a heading) that exists,
    so moving a guide or renaming a section cannot leave a dead link behind."""
    text = re.sub(r"```.*?```", "", path.read_text(encoding="utf-8"), flags=re.S)
    dead = []
    for target in _LINK.findall(text):
        if re.match(r"[a-z]+:", target):
            continue                                # http(s), mailto: not checked here
        name, _, anchor = target.partition("#")
        file = (path.parent / name).resolve() if name else path
        if not file.exists():
            dead.append(target)
        elif anchor and file.suffix == ".md" and anchor not in _anchors(file):
            dead.append(target)
    assert not dead, f"{path.relative_to(ROOT)}: dead links {dead}"


def test_a_dead_link_is_found(tmp_path):
    """The control: a missing file and a missing heading both count as dead."""
    (tmp_path / "a.md").write_text("# A page\n\n## The `usdbtf` part, twice\n", encoding="utf-8")
    assert _anchors(tmp_path / "a.md") == {"a-page", "the-usdbtf-part-twice"}
    doc = tmp_path / "b.md"
    doc.write_text("[ok](a.md#the-usdbtf-part-twice) [no file](c.md) [no heading](a.md#gone)\n", encoding="utf-8")
    with pytest.raises(AssertionError, match=r"c\.md.*a\.md#gone"):
        global ROOT
        saved, ROOT = ROOT, tmp_path
        try:
            test_relative_links_resolve(doc)
        finally:
            ROOT = saved
