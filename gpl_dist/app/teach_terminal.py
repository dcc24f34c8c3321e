"""``gpl-dist teach``: teach a trained policy by typing corrections in the terminal.

Each attempt is printed as text (the path, the final state, the step it solved the task at), with
its completion and the path of a GIF of it; then the person types the next correction. Lines
starting with ``:`` are commands: ``:hint`` (what the run's oracle would say), ``:undo`` (take the
last correction back), ``:quit``. Examples of the corrections the policy was trained on (its
correction kind, and its paraphrases when it was trained with them) are shown first. A correction
with words the policy does not know, or that is none of the phrasings it was trained on, is shown
with the closest of them before it is sent:
Enter sends it as typed, ``:use`` the closest one (the log keeps both what was typed and what was
sent). Lines typed while an attempt runs are dropped (they were typed before seeing it). Every
attempt is logged (``gpl_dist.app.teaching``); the log and the GIFs are written under temporary
names and renamed into place, and ``OUT`` is checked (a folder that takes a file) before the first
attempt.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, TextIO

from gpl_dist.app.teaching import (
    TaughtAttempt,
    TeachingEpisode,
    TeachingError,
    ensure_folder,
    teaching_writer,
    write_atomic,
    write_episode_log,
)

HELP = "type a correction; commands: ':hint' (what the oracle would say), ':undo' (take the last correction back), ':quit'"


def teach_in_terminal(episode: TeachingEpisode, out_dir: Path, *, always_hint: bool = False,
                      read_line: Callable[[str], str] = input, out: TextIO | None = None) -> Path:
    """Run ``episode`` until solved, out of corrections, ``:quit`` or end of input; writes the log
    under ``out_dir/log`` and GIFs under ``out_dir/gifs``; returns the log file's path."""
    import sys

    if read_line is input:
        try:
            import readline  # noqa: F401 - arrow keys and history for input()
        except ImportError:  # not on every platform
            pass
    stream = out or sys.stdout

    def say(text: str = "") -> None:
        print(text, file=stream, flush=True)

    with teaching_writer(out_dir) as folder:  # OUT checked (one line when it cannot hold the log), and held
        return _teach(episode, folder, always_hint, read_line, say)


def _teach(episode: TeachingEpisode, out_dir: Path, always_hint: bool, read_line: Callable[[str], str],
           say: Callable[[str], None]) -> Path:
    log_dir, gif_dir = out_dir / "log", ensure_folder(out_dir / "gifs")
    say(f"task {episode.task_id} of {episode.teacher.domain.name} ({episode.split} split), seed {episode.seed}: "
        f"'{episode.instruction}'")
    examples = episode.teacher.examples()
    if examples:
        say(f"corrections this policy was trained on look like: {', '.join(repr(e) for e in examples)}")
    log_path = ""
    correction: str | None = None
    typed: str | None = None
    takes: dict[int, int] = {}  # attempt index -> how often it was made (an undone attempt keeps its GIF)
    while True:
        attempt = episode.attempt(correction, typed)
        log_path = write_episode_log(episode, log_dir)
        takes[attempt.index] = takes.get(attempt.index, 0) + 1
        take = "" if takes[attempt.index] == 1 else f"-take{takes[attempt.index]}"
        gif = write_atomic(gif_dir / f"{episode.episode_id}-attempt{attempt.index}{take}.gif", episode.gif(attempt.index))
        _show(say, attempt, gif)
        if attempt.success or episode.corrections_left <= 0:
            say("solved." if attempt.success else f"no corrections left ({episode.teacher.max_corrections} given).")
            _discard_typed_ahead()  # nothing typed for the episode may reach the shell
            break
        if always_hint:
            say(f"hint: the oracle would say '{episode.hint()}'")
        read = _read_correction(episode, read_line, say)
        if read is None:
            break
        correction, typed = read
    log_path = write_episode_log(episode, log_dir)  # an ':undo' after the last attempt is logged too
    say(f"log: {log_path} (pyarrow.dataset.dataset('{log_dir}') reads every episode)")
    return Path(log_path)


def _show(say: Callable[[str], None], attempt: TaughtAttempt, gif: Path) -> None:
    led_by = "instruction" if attempt.index == 0 else "correction"
    say(f"\nattempt {attempt.index + 1} ({led_by}: '{attempt.said_before}'):")
    say(attempt.picture)
    say(f"completion {attempt.completion:.2f}, {'solved' if attempt.success else 'not solved'}; GIF: {gif}")


def _read_correction(episode: TeachingEpisode, read_line: Callable[[str], str],
                     say: Callable[[str], None]) -> tuple[str, str | None] | None:
    """The next usable correction and, when the closest phrasing is sent in its place, what was
    typed; None to stop (``:quit``, end of input). ``:undo`` takes the last correction back and
    shows the attempt before it again.

    A correction with unknown words, or that is none of the phrasings the policy was trained on,
    is shown with the closest one first: Enter sends it as typed, ``:use`` sends the closest one.
    """
    pending = None  # (typed text, closest phrasing) awaiting confirmation
    say(HELP)
    while True:
        _discard_typed_ahead()  # lines typed while the attempt ran were typed before seeing it
        if read_line is input and _stdin_closed():
            say("standard input is closed: no more corrections can be read (gpl-dist serve teaches in a browser)")
            return None
        try:
            line = read_line("correction> " if pending is None else "Enter: send as typed, :use: send the closest, "
                             "or type another> ")
        except EOFError:
            say("")
            return None
        text = line.strip()
        if pending is not None and text in ("", ":use"):
            return (pending[0], None) if text == "" else (pending[1], pending[0])
        pending = None
        if text in (":quit", ":q"):
            return None
        if text == ":undo":
            try:
                undone = episode.undo()
            except TeachingError as err:
                say(str(err))
                continue
            say(f"undone: attempt {undone.index + 1} (after '{undone.said_before}'); back to attempt {undone.index}:")
            say(episode.attempts[-1].picture)
            continue
        if text == ":hint":
            say(f"hint: the oracle would say '{episode.hint()}'")
            continue
        if text.startswith(":"):
            say(f"unknown command {text[:20]!r}: {HELP}")
            continue
        check = episode.check(line)
        if check.problem:
            say(f"not sent: {check.problem}")
            continue
        if check.suggestion is None:
            return check.text, None
        if check.warning:
            say(f"{check.warning}; the closest it trained on: '{check.suggestion}'")
        elif check.unknown_words:
            say(f"unknown words: {', '.join(w[:40] for w in check.unknown_words[:8])} (the policy reads them as <unk>); "
                f"closest known phrasing: '{check.suggestion}'")
        else:
            say(f"not a phrasing the policy was trained on; the closest is '{check.suggestion}'")
        pending = (check.text, check.suggestion)


def _stdin_closed() -> bool:
    """Whether this process has no standard input to read (started with ``0<&-``, or it was closed)."""
    import sys

    return sys.stdin is None or sys.stdin.closed


def _discard_typed_ahead() -> None:
    """Drop what was typed at a terminal before the prompt appeared (no-op for piped or closed input)."""
    import sys

    if _stdin_closed():
        return
    try:
        import termios

        if sys.stdin.isatty():
            termios.tcflush(sys.stdin, termios.TCIFLUSH)
    except (ImportError, OSError, ValueError):  # not a POSIX terminal
        pass
