"""Every shell, Python and SQL snippet in ``docs/*.md`` runs as the page gives it.

A fenced block of ``bash``, ``sh``, ``shell``, ``console`` (its ``$ `` lines), ``python`` or ``sql``
(run by duckdb) is run in a working folder of its page's own, with ``gpl-dist`` and ``python``
from this environment first on ``PATH``. The folder holds the repository's files (linked) and what
the pages name besides: ``runs/mr`` and ``runs/smoke``, a small trained multi-room run (trained once
for the module; the second is the README's set-up run);
``BUFFER``, its buffer root (``docs/buffer.md``); ``mypkg/corridor.py``, the reader's domain
package of ``docs/adding-a-domain.md`` (``tests/domains/corridor.py``). A page's blocks run in
order in the same folder, as a reader would type them.

A block that cannot run here says so on the line before its fence, with the reason:
``<!-- snippet: not run: needs a Ray cluster -->``. Such blocks are few (``MAX_NOT_RUN``), and each
carries a reason; every other block must exit 0.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest
from _cluster_tools import quiet_env

from gpl_dist.cli import main

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: How each fence's language is run.
RUNNERS = {"bash": "shell", "sh": "shell", "shell": "shell", "console": "console", "python": "python",
           "py": "python", "sql": "sql"}
MARKER = re.compile(r"^\s*<!--\s*snippet:\s*not run:(?P<reason>.*?)-->\s*$")
FENCE = re.compile(r"^(?P<indent>\s*)(?P<fence>`{3,}|~{3,})\s*(?P<lang>[\w+-]*)[^`]*$")
#: The most blocks the docs may leave unrun (clusters, GPUs, the paper's suite, benchmarks).
MAX_NOT_RUN = 12
#: Seconds one block may take.
BLOCK_TIMEOUT_S = 180


@dataclass(frozen=True)
class Snippet:
    """One fenced block of a page: where it is, its language, its text, and why it is not run
    (None: it is run)."""

    doc: str
    line: int
    lang: str
    code: str
    not_run: str | None

    @property
    def name(self) -> str:
        return f"{self.doc}:{self.line}"


def parse(text: str, doc: str) -> tuple[list[Snippet], list[str]]:
    """The runnable blocks of a page (those of a language in ``RUNNERS``), and its problems: a
    not-run marker without a reason, or not on the line before such a block's fence."""
    lines = text.splitlines()
    found: list[Snippet] = []
    problems: list[str] = []
    marked_at: set[int] = set()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        closing = re.compile(r"^\s*" + re.escape(m["fence"][0]) + "{" + str(len(m["fence"])) + r",}\s*$")
        j = i + 1
        while j < len(lines) and not closing.match(lines[j]):
            j += 1
        lang = m["lang"].lower()
        if lang in RUNNERS:
            marker = MARKER.match(lines[i - 1]) if i > 0 else None
            reason = marker["reason"].strip() if marker else None
            if marker:
                marked_at.add(i - 1)
                if not reason:
                    problems.append(f"{doc}:{i}: a not-run marker without a reason")
            found.append(Snippet(doc, i + 1, lang, textwrap.dedent("\n".join(lines[i + 1:j])), reason or None))
        i = j + 1
    for k, line in enumerate(lines):
        if MARKER.match(line) and k not in marked_at:
            problems.append(f"{doc}:{k + 1}: a not-run marker that is not on the line before a snippet's fence")
    return found, problems


def all_snippets() -> tuple[list[Snippet], list[str]]:
    snippets: list[Snippet] = []
    problems: list[str] = []
    for page in sorted(DOCS.glob("*.md")):
        found, wrong = parse(page.read_text(), f"docs/{page.name}")
        snippets += found
        problems += wrong
    return snippets, problems


SNIPPETS, PROBLEMS = all_snippets()


def console_commands(code: str) -> str:
    """The commands of a ``console`` block: its ``$ `` lines (the others are output)."""
    return "\n".join(line.split("$ ", 1)[1] for line in code.splitlines() if line.lstrip().startswith("$ "))


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A small multi-room run (one round on 4 tasks, a 2-task evaluation): what ``runs/mr`` is."""
    run = tmp_path_factory.mktemp("docs-run") / "mr"
    assert main(["train", "--config", str(ROOT / "configs/multiroom-smoke.yaml"), "--serial", "--no-progress",
                 "--run-dir", str(run), "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4",
                 "--set", "training.num_epochs_per_round=1", "--set", "eval.max_tasks=2"]) == 0
    return run


@pytest.fixture(scope="module")
def workspaces(tmp_path_factory, trained):
    """A working folder per page, made when its first block runs (see the module docstring)."""
    made: dict[str, Path] = {}

    def folder(doc: str) -> Path:
        if doc not in made:
            work = tmp_path_factory.mktemp("docs-" + Path(doc).stem)
            for entry in ROOT.iterdir():
                if not entry.name.startswith(".") and entry.name != "runs":
                    (work / entry.name).symlink_to(entry)
            shutil.copytree(trained, work / "runs" / "mr")
            shutil.copytree(trained, work / "runs" / "smoke")  # what the README's first command leaves
            (work / "BUFFER").symlink_to(work / "runs" / "mr" / "buffer")
            (work / "mypkg").mkdir()
            (work / "mypkg" / "__init__.py").write_text("")
            shutil.copy(ROOT / "tests" / "domains" / "corridor.py", work / "mypkg" / "corridor.py")
            made[doc] = work
        return made[doc]

    return folder


def run_snippet(snippet: Snippet, work: Path) -> subprocess.CompletedProcess:
    """Run ``snippet`` in ``work``; its exit status and output."""
    env = quiet_env(PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
                    PYTHONPATH=str(work), GPL_DIST_TRUST_FILE=str(work / "trusted-domain-modules.json"))
    kind = RUNNERS[snippet.lang]
    if kind == "python":
        argv = [sys.executable, "-c", snippet.code]
    elif kind == "sql":
        argv = [sys.executable, "-c", "import sys, duckdb; print(duckdb.connect().execute(sys.argv[1]).fetchall())",
                snippet.code]
    else:
        code = console_commands(snippet.code) if kind == "console" else snippet.code
        argv = ["bash", "-e", "-o", "pipefail", "-c", code]
    return subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=BLOCK_TIMEOUT_S)


def test_the_docs_hold_snippets_and_every_marker_is_well_placed():
    assert not PROBLEMS, PROBLEMS
    langs = {RUNNERS[s.lang] for s in SNIPPETS if s.not_run is None}
    assert {"shell", "python", "sql"} <= langs  # the parser finds each kind the docs use


def test_few_snippets_are_left_unrun_and_each_says_why():
    not_run = [s for s in SNIPPETS if s.not_run is not None]
    assert len(not_run) <= MAX_NOT_RUN, [s.name for s in not_run]
    for s in not_run:
        assert len(s.not_run.split()) >= 2, f"{s.name}: say why it is not run"


@pytest.mark.parametrize("snippet", [s for s in SNIPPETS if s.not_run is None], ids=lambda s: s.name)
def test_the_snippet_runs(snippet, workspaces):
    done = run_snippet(snippet, workspaces(snippet.doc))
    assert done.returncode == 0, f"{snippet.name} exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"


def test_a_failing_snippet_fails_and_console_output_lines_are_not_run(tmp_path):
    """The runner itself: a shell block stops at its first failing command, and only a console
    block's ``$`` lines are commands."""
    failing = Snippet("x.md", 1, "bash", "false\ntrue", None)
    assert run_snippet(failing, tmp_path).returncode != 0
    console = Snippet("x.md", 1, "console", "$ echo hello > out.txt\nhello\nnot a command", None)
    assert run_snippet(console, tmp_path).returncode == 0 and (tmp_path / "out.txt").read_text() == "hello\n"
    found, problems = parse("<!-- snippet: not run: -->\n```bash\nx\n```\n<!-- snippet: not run: why -->\ntext\n", "y.md")
    assert [s.not_run for s in found] == [None] and len(problems) == 2
