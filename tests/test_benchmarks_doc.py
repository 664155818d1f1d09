"""BENCHMARKS.md: every command in it runs with today's command line, and it starts with a summary.

(a) Every command line in BENCHMARKS.md that starts with `galileo`, `python -m galileo` or
    `python bench/X.py` (each line of a fenced code block, after a `$ ` prompt, continuation
    lines joined; each inline code span outside them, in a table cell or in the prose, a span
    that runs over a line break included) is accepted by today's parser
    (`galileo.cli.build_parser(lazy=False)`, no deprecated spelling), and every bench script it
    names exists and lists each flag used in its `--help`; a folder output is not named like a
    file (`--out report.json`). Placeholders (DIR, DATASET, VIDEO,
    /tmp/x) are fine as arguments; a span that only names a command (`galileo infer`) is a name,
    not a command line; `[...]` marks an optional part (checked as given); a command with an
    elision (`...`) has its flags checked, not its arguments.
(b) The checker can fail: made-up refused lines are caught, each named.
(c) The file starts with "Where things stand", one table with a command, a machine and a date
    in each row and a link to an existing section, then the subjects in their order.
"""
import contextlib
import io
import re
import shlex
import subprocess
import sys
from functools import lru_cache
from pathlib import Path

import pytest

from galileo import cli
from galileo.errors import GalileoError

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "BENCHMARKS.md"
SUBJECTS = ("Where things stand", "Speed", "Accuracy", "Convergence and calibration", "Scale", "Reliability",
            "Browser")

FENCE = re.compile(r"^\s*(```|~~~)")
COMMAND = re.compile(r"^(?:galileo|python -m galileo|python bench/[\w.-]+\.py)(?=\s|$)")
SPAN = re.compile(r"(?<!`)`([^`]+)`(?!`)")
ELISION = ("...", "…")
FILE_SUFFIXES = {".json", ".md", ".npz", ".csv", ".txt", ".png", ".html", ".rrd", ".mp4"}


def command_lines(text: str) -> list[tuple[int, str]]:
    """(line number, command) for every command line of the Markdown `text` (see the module's
    docstring for what counts)."""
    found: list[tuple[int, str]] = []
    lines = text.splitlines()
    fenced, prose, i = False, [], 0

    def spans(block: list[tuple[int, str]]):
        if not block:
            return
        joined, starts = "", []
        for number, line in block:
            starts.append((len(joined), number))
            joined += line + "\n"
        for m in SPAN.finditer(joined):
            command = " ".join(m.group(1).split())
            if COMMAND.match(command) and not only_a_name(command):
                number = max(n for at, n in starts if at <= m.start())
                found.append((number, command))

    while i < len(lines):
        line = lines[i]
        if FENCE.match(line):
            if not fenced:
                spans(prose)
                prose = []
            fenced = not fenced
            i += 1
            continue
        if fenced:
            number, logical = i + 1, line
            while logical.rstrip().endswith("\\") and i + 1 < len(lines):
                i += 1
                logical = logical.rstrip()[:-1] + " " + lines[i].strip()
            for command in commands_of_a_code_line(logical):
                found.append((number, command))
        elif not line.strip():
            spans(prose)
            prose = []
        else:
            prose.append((i + 1, line))
        i += 1
    spans(prose)
    return found


def commands_of_a_code_line(line: str) -> list[str]:
    """The commands on one (joined) line of a code block: the line itself after a `$ ` prompt,
    without a trailing `# comment`; in a `farm-bench ... -- CMD` line, the CMD measured now
    (its `--vs` command is an old checkout's)."""
    s = re.sub(r"^\s*\$\s+", "", line).strip()
    if s.startswith("farm-bench ") and " -- " in s:
        s = s.rsplit(" -- ", 1)[1].strip()
    s = re.sub(r"\s+#.*$", "", s)
    s = " ".join(s.split())
    return [s] if COMMAND.match(s) else []


def only_a_name(command: str) -> bool:
    """`galileo infer`, `galileo recognize label`: the command's name in the prose, no line to run."""
    words = command.split()
    rest = words[3:] if words[:3] == ["python", "-m", "galileo"] else words[1:]
    return command.startswith(("galileo", "python -m galileo")) and len(rest) <= 2 and all(
        re.fullmatch(r"[a-z]+", w) for w in rest)


def argv_of(command: str, tmp: Path) -> list[str]:
    """The command's words after the program: optional parts' brackets dropped, /tmp/... paths
    moved under `tmp` (the parser probes where an output would go)."""
    while True:
        dropped = re.sub(r"\[([^\[\]]*)\]", r"\1", command)
        if dropped == command:
            break
        command = dropped
    words = shlex.split(command)
    words = words[3:] if words[:3] == ["python", "-m", "galileo"] else words[1:]
    return [str(tmp / w[1:]) if w.startswith("/tmp/") else w for w in words]


def flags_of(words: list[str]) -> list[str]:
    return [w.split("=", 1)[0] for w in words if re.match(r"^--?[A-Za-z]", w)]


def subcommand(parser, words: list[str]):
    """(the subcommand's words, its parser) that `words` name: `infer`, `recognize eval`, ..."""
    path, p = [], parser
    for w in words:
        if p._subparsers is None:
            break
        choices = p._subparsers._group_actions[0].choices
        if w in choices:
            path.append(w)
            p = choices[w]
        elif not w.startswith("-"):
            break
    return path, p


def check_galileo(command: str, tmp: Path) -> str | None:
    """None when today's `galileo` parser accepts `command`, else why not (its error line)."""
    words = argv_of(command, tmp)
    parser = cli.build_parser(lazy=False)
    path, p = subcommand(parser, words)
    if any(w in ELISION for w in words):           # elided: the flags must be the command's
        unknown = [f for f in flags_of(words) if f not in p._option_string_actions]
        return f"no such flag of galileo {' '.join(path)}: {', '.join(unknown)}" if unknown else None
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            args = parser.parse_args(words)
    except SystemExit as e:
        if e.code in (0, None):                    # --help, --version
            return None
        return (err.getvalue().strip().splitlines() or [f"exit {e.code}"])[-1]
    old = getattr(args, cli.DEPRECATED, None)
    if old:
        return "; ".join(f"{o} is deprecated: use {n}" for o, n in old.values())
    for action in p._actions:                      # a folder named like a file (`--out report.json`)
        value = getattr(args, action.dest, None)
        if action.type is cli.out_dir and isinstance(value, str) and Path(value).suffix in FILE_SUFFIXES:
            return f"{action.option_strings[0]} takes a folder, not a file: {value}"
    try:
        cli.check_not_an_input(args)
    except GalileoError as e:
        return str(e)
    return None


@lru_cache(maxsize=None)
def bench_help(script: str) -> str:
    run = subprocess.run([sys.executable, script, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, f"{script} --help failed:\n{run.stderr[-2000:]}"
    return run.stdout


def check_bench(command: str, tmp: Path) -> str | None:
    """None when the bench script exists and its --help lists every flag `command` uses."""
    script = command.split()[1]
    if not (ROOT / script).is_file():
        return f"{script} does not exist"
    text = bench_help(script)
    unknown = [f for f in flags_of(argv_of(command, tmp))
               if not re.search(r"(?<![\w-])" + re.escape(f) + r"(?![\w-])", text)]
    return f"{script} --help does not list {', '.join(unknown)}" if unknown else None


def problems(text: str, tmp: Path) -> list[str]:
    out = []
    for number, command in command_lines(text):
        check = check_bench if command.startswith("python bench/") else check_galileo
        why = check(command, tmp)
        if why:
            out.append(f"BENCHMARKS.md line {number}: {command!r}: {why}")
    return out


# -- (a) every command in BENCHMARKS.md runs with today's command line ------------------------------

def test_every_command_in_benchmarks_is_accepted(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)                    # relative outputs are probed here, not in the checkout
    text = BENCHMARKS.read_text(encoding="utf-8")
    commands = command_lines(text)
    assert len(commands) > 80, f"only {len(commands)} command lines found: the extraction broke"
    kinds = {c.split()[0] + (" bench" if c.startswith("python bench/") else "") for _, c in commands}
    assert {"galileo", "python", "python bench"} <= kinds, kinds
    found = problems(text, tmp_path)
    assert not found, "commands in BENCHMARKS.md that today's command line refuses:\n" + "\n".join(found)


# -- (b) the checker can fail ------------------------------------------------------------------------

BAD = """\
# Doc

```
galileo experiment DATASET --out DIR --frobnicate 3
$ python bench/bench_track.py --repeatz 7
```

| figure | command |
|---|---|
| render | `galileo dataset --preset small` |

Prose that names `galileo infer` (a name: not checked) and runs `galileo predict --result R
--target` over a line break, `python bench/bench_nothing.py`, `galileo infer VIDEO --tracks T
--moves M --out DIR` and `galileo infer ... --no-such-flag 1`.

```
galileo experiment DATASET --out DIR --workers 2
galileo experiment DATASET --out report.json
```
"""


def test_the_checker_catches_refused_lines_and_names_them(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert [n for n, _ in command_lines(BAD)] == [4, 5, 10, 12, 13, 13, 14, 17, 18]
    found = problems(BAD, tmp_path)
    expected = {
        4: "unrecognized arguments: --frobnicate 3",
        5: "--help does not list --repeatz",
        10: "the following arguments are required: --out",
        12: "--target is deprecated: use --target-outcome",
        13: "bench/bench_nothing.py does not exist",
        14: "no such flag of galileo infer: --no-such-flag",
        18: "--out takes a folder, not a file: report.json",
    }
    for line, why in expected.items():
        assert any(f.startswith(f"BENCHMARKS.md line {line}:") and why in f for f in found), (line, why, found)
    assert any("line 13:" in f and "invalid choice: 'M'" in f for f in found), found
    assert not any("line 17:" in f for f in found), found       # a good line passes
    assert len(found) == 8, found


def test_the_extraction_reads_prompts_comments_continuations_and_farm_bench():
    doc = ("```\n$ python bench/bench_scrub.py   # a comment\ngalileo dataset --preset demo \\\n"
           "    --out DIR\nnot a command\n$ farm-bench -n 3 --vs \"python -m galileo infer OLD --out a.json\" \\\n"
           "    -- python -m galileo infer NEW --out b.json --quiet\n```\n")
    assert command_lines(doc) == [(2, "python bench/bench_scrub.py"), (3, "galileo dataset --preset demo --out DIR"),
                                  (6, "python -m galileo infer NEW --out b.json --quiet")]


# -- (c) a summary first, then the subjects ----------------------------------------------------------

def test_benchmarks_starts_with_where_things_stand_then_the_subjects():
    text = BENCHMARKS.read_text(encoding="utf-8")
    body = re.sub(r"(?ms)^```.*?^```", "", text)
    assert [h for h in re.findall(r"(?m)^## (.+)$", body)] == list(SUBJECTS)
    summary = body.split("## Where things stand", 1)[1].split("\n## ", 1)[0]
    rows = [r for r in summary.splitlines() if r.startswith("| [")]
    assert 20 <= len(rows) <= 40, len(rows)
    slug = pytest.importorskip("pymdownx.slugs").slugify(case="lower")       # the site's (mkdocs.yml)
    anchors = {slug(re.sub(r"^#+\s*", "", h), "-") for h in re.findall(r"(?m)^#{2,6} .+$", body)}
    for row in rows:
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", row)[1:-1]]
        assert len(cells) == 6, row                # figure, value, target, command, machine, date
        anchor = re.match(r"\[.+\]\(#([^)]+)\)$", cells[0])
        assert anchor and anchor.group(1) in anchors, f"the row's link is to no section: {row}"
        assert cells[1] and "`" in cells[3] and cells[4], row
        assert re.search(r"20\d\d-\d\d-\d\d", cells[5]), row
