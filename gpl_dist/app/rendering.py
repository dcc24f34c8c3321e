"""Pictures of tasks and attempts: a PNG of a task's start state, a GIF of an attempt.

A domain's env draws its scene with ``render_mode="rgb_array"`` where it offers that; an env that
offers only ``render_mode="ansi"`` is drawn as its text picture, and one that offers neither as a
card with its instruction and completion. ``picture_points()`` (the moving things in pixels), where
the env has it, draws the attempt's path on its last frame; without it the frames have no path.
This module only drives the envs and writes files (``docs/adding-a-domain.md``, optional parts).
"""

from __future__ import annotations

import io
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from PIL import Image

from gpl_dist.app.replay import Course, step_through
from gpl_dist.atomic import write_atomic
from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.experts import make_expert
from gpl_dist.roles import DomainSpec
from learner.evaluate import load_trained_policy, meta_test_rollout


def parse_actions(text: str) -> list[int]:
    """Actions from ``"0,1,1,3"`` or a file holding such a list (commas or whitespace)."""
    p = Path(text)
    looks_like_list = all(ch.isdigit() or ch in ", \t\n-" for ch in text)
    if not looks_like_list and not p.is_file():
        raise FileNotFoundError(f"no actions file at {text[:200]} (give '0,1,3,...' or a file holding them)")
    try:
        raw = p.read_text() if p.is_file() else text
    except UnicodeDecodeError:
        raise UsageError(f"actions file {text[:200]} is not text") from None
    parts = raw.replace(",", " ").split()
    try:
        return [int(x) for x in parts]
    except ValueError:
        raise UsageError(f"actions must be integers separated by commas or spaces, got {raw[:60]!r}") from None


@dataclass(frozen=True)
class Replay:
    """An attempt stepped again from its reset seed and actions and drawn (``replay_attempt``).

    Attributes:
        frames: RGB frames of the start state and the state after each action (empty unless drawn).
        points: per frame, the picture's moving things in pixels (``env.picture_points()``).
        completion: float ``(T + 1,)`` the completion at the start and after each action.
        success: bool ``(T + 1,)`` whether the task is solved at the start and after each action.
    """

    frames: list[np.ndarray]
    points: list[tuple[tuple[float, float], ...]]
    completion: np.ndarray
    success: np.ndarray

    @property
    def solved_at(self) -> int | None:
        """The first step (actions taken) at which the task was solved; None if never."""
        hits = np.flatnonzero(self.success)
        return int(hits[0]) if hits.size else None


def picture_mode(domain_name: str) -> str | None:
    """How a domain's env draws itself: ``rgb_array``, else ``ansi``, else None (its
    ``metadata["render_modes"]``)."""
    if domain_name not in _MODES:
        env = get_domain(domain_name).make_env(0)
        modes = tuple(getattr(env, "metadata", {}).get("render_modes", ()) or ())
        _MODES[domain_name] = next((m for m in ("rgb_array", "ansi") if m in modes), None)
    return _MODES[domain_name]


_MODES: dict[str, str | None] = {}
#: Pixels of one character of a text picture (an ``ansi``-only domain's frames).
TEXT_CELL_PX = (8, 16)


def draw(env: Any, mode: str | None, info: dict) -> np.ndarray:
    """The env's picture as an RGB array: its own (``rgb_array``), its text picture drawn
    (``ansi``), or a card with its instruction and completion (neither)."""
    if mode == "rgb_array":
        return np.asarray(env.render())
    text = str(env.render()) if mode == "ansi" else (f"{getattr(env, 'instruction', '')}\n(this domain draws no "
                                                    f"picture)\ncompletion {float(info.get('completion', 0.0)):.2f}")
    return text_picture(text)


def text_picture(text: str) -> np.ndarray:
    """``text`` (an env's ANSI picture, colour codes dropped) drawn black on white, one cell per character."""
    import re

    from PIL import ImageDraw, ImageFont

    lines = re.sub(r"\x1b\[[0-9;]*m", "", text).splitlines() or [""]
    cw, ch = TEXT_CELL_PX
    image = Image.new("RGB", (max(160, cw * max(len(line) for line in lines) + 8), ch * len(lines) + 8), "white")
    font = ImageFont.load_default(size=ch - 3)
    pen = ImageDraw.Draw(image)
    for i, line in enumerate(lines):
        for j, c in enumerate(line):
            pen.text((4 + cw * j, 4 + ch * i), c, fill="black", font=font)
    return np.asarray(image)


def _points(env: Any) -> tuple:
    return tuple(env.picture_points()) if hasattr(env, "picture_points") else ()


def replay_attempt(domain_name: str, task_id: int, actions: Sequence[int] | np.ndarray, reset_seed: int,
                   render: bool = True) -> Replay:
    """Step ``task_id``'s env from ``reset_seed`` through ``actions`` (``gpl_dist.app.replay.step_through``),
    drawing each state when ``render``."""
    mode = picture_mode(domain_name) if render else None
    frames: list[np.ndarray] = []
    points: list[tuple] = []

    def drawn(t: int, env: Any, info: dict) -> None:
        frames.append(draw(env, mode, info))
        points.append(_points(env))

    course = step_through(domain_name, task_id, actions, reset_seed, render_mode=mode, visit=drawn if render else None)
    return Replay(frames, points, course.completion, course.success)


def attempt_frames(domain_name: str, task_id: int, actions: Sequence[int] | None = None, expert: bool = False,
                   seed: int = 0, max_steps: int | None = None) -> list[np.ndarray]:
    """RGB frames of the task's start state and each state after ``actions`` (or the expert's)."""
    if not expert:
        return replay_attempt(domain_name, task_id, list(actions or ())[: max_steps or None], seed).frames
    domain = get_domain(domain_name)
    mode = picture_mode(domain_name)
    env = domain.make_env(task_id, render_mode=mode) if mode else domain.make_env(task_id)
    _, info = env.reset(seed=seed)
    frames: list[np.ndarray] = [draw(env, mode, info)]
    policy = make_expert(env)
    for _ in range(max_steps or domain.steps_per_attempt):
        _, _, _, _, info = env.step(policy.act(env))
        frames.append(draw(env, mode, info))
        if info.get("success"):
            break  # the expert's attempt ends where the task is solved, in either domain
    return frames


def write_picture(frames: list[np.ndarray], out: str | Path, fps: int = 8) -> Path:
    """Write one frame as PNG, or all frames as an animated GIF when ``out`` ends in .gif."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".gif":
        write_atomic(out, gif_bytes(frames, fps))
    else:
        buf = io.BytesIO()
        Image.fromarray(frames[-1] if len(frames) > 1 else frames[0]).save(buf, format="PNG")
        write_atomic(out, buf.getvalue())
    return out


#: Pixels of one caption line under each frame of a policy's attempts.
CAPTION_LINE_PX = 20
#: Characters of a caption line: longer captions wrap onto more lines, never cut.
CAPTION_CHARS = 48
#: Font size of the captions, in pixels (readable when the page shows the GIF 300 px wide).
CAPTION_FONT_PX = 14
#: Colours of the drawn paths (one per ``picture_points`` entry) and of the mark where the task was solved.
PATH_RGB = ((230, 40, 40), (40, 120, 230))
SOLVED_RGB = (20, 200, 60)


def picture_legend(domain: DomainSpec) -> tuple[tuple[str, str], ...]:
    """What the marks of ``still_frame`` mean for ``domain``: ``(CSS colour, meaning)`` for each
    drawn path (named by the env's optional ``picture_point_names``, one name for each point of
    ``picture_points()`` after a reset of task 0), then the ring where the task was first solved;
    empty for an env without ``picture_points``, whose pictures carry no marks."""
    env = domain.make_env(0)
    try:
        env.reset(seed=0)
        points = env.picture_points() if hasattr(env, "picture_points") else ()
        names = tuple(getattr(env, "picture_point_names", ()))
    finally:
        if hasattr(env, "close"):
            env.close()
    if not points:
        return ()
    css = lambda rgb: "#" + "".join(f"{c:02x}" for c in rgb)  # noqa: E731
    paths = tuple((css(PATH_RGB[i % len(PATH_RGB)]),
                   f"the path of {names[i] if i < len(names) else f'moving thing {i + 1}'}")
                  for i in range(len(points)))
    return (*paths, (css(SOLVED_RGB), "the ring: where the task was first solved"))


def caption_lines(text: str) -> list[str]:
    """``text`` wrapped into caption lines of at most ``CAPTION_CHARS`` characters (a long word is split)."""
    return textwrap.wrap(text, CAPTION_CHARS) or [""]


def step_caption(t: int, last: int, replay: Replay | Course) -> str:
    """``step t/T``, the completion then, and where the task was solved once it has been."""
    solved = replay.solved_at
    text = f"step {t}/{last}: completion {replay.completion[t]:.2f}"
    if solved is not None and t >= solved:
        text += f", solved at step {solved}" + (" (runs on)" if t > solved else "")
    return text


def policy_attempt_frames(run_dir: str | Path, task_id: int, num_attempts: int, seed: int = 0,
                          checkpoint: str | None = None, frame_stride: int | None = None,
                          foreign_checkpoint: bool = False) -> list[np.ndarray]:
    """Frames of a trained policy's successive attempts at ``task_id``, as at meta-test.

    The run's policy makes up to ``num_attempts`` attempts, each after the oracle's correction of
    the one before (the run's own conditioning and oracle, ``workers.rollout.Rollout``); each attempt
    is then replayed from its reset seed and actions to draw it. Every frame carries a caption:
    the attempt, the correction that led to it (the instruction for the first), and the attempt's
    completion. ``frame_stride`` keeps every n-th step (default: about 40 frames an attempt). A
    checkpoint of another run, domain or model is refused unless ``foreign_checkpoint``.
    """

    if num_attempts < 1:
        raise UsageError(f"--attempts must be at least 1, got {num_attempts}")
    cfg, model, _ = load_trained_policy(run_dir, checkpoint, allow_foreign=foreign_checkpoint)
    domain = get_domain(cfg.env.domain)
    if not 0 <= task_id < domain.num_tasks:
        raise UsageError(f"task {task_id} is outside 0..{domain.num_tasks - 1} of {domain.name}")
    model.eval()
    result = meta_test_rollout(cfg, model).run([task_id], num_attempts - 1, seed, split="render")
    if result.failures:
        raise UsageError(str(result.failures[0]))
    frames: list[np.ndarray] = []
    tops = []
    for k, att in enumerate(result.attempts):
        said = att.instruction if k == 0 else result.attempts[k - 1].correction
        tops.append(f"attempt {k + 1}/{len(result.attempts)}: {'instruction' if k == 0 else 'correction'}: {said}")
    lines = max(len(caption_lines(top)) for top in tops)  # every frame of the GIF the same size
    for att, top in zip(result.attempts, tops):
        frames += captioned_attempt_frames(domain.name, task_id, att.actions, att.seed, top, frame_stride, top_lines=lines)
    return frames


def frame_steps(domain_name: str, length: int, frame_stride: int | None = None) -> list[int]:
    """The steps an attempt of ``length`` actions is drawn at: every ``frame_stride``-th (default
    about 40 frames) and the last."""
    stride = frame_stride or max(1, get_domain(domain_name).steps_per_attempt // 40)
    return [*range(0, length, stride), length]


def captioned_attempt_frames(domain_name: str, task_id: int, actions: np.ndarray, reset_seed: int, top: str,
                             frame_stride: int | None = None, top_lines: int | None = None) -> list[np.ndarray]:
    """An attempt replayed from ``reset_seed`` and ``actions`` at ``frame_steps``, each frame
    captioned with ``top`` (wrapped, padded to ``top_lines`` lines) over ``step_caption``; the last
    frame, with the path drawn, is held for a moment."""
    replay = replay_attempt(domain_name, task_id, actions, reset_seed)
    last = len(replay.frames) - 1
    steps = frame_steps(domain_name, last, frame_stride)
    lines = caption_lines(top)
    lines += [""] * max(0, (top_lines or 0) - len(lines))
    frames = [_captioned(replay.frames[t] if t < last else still_frame(replay), [*lines, step_caption(t, last, replay)])
              for t in steps]
    return frames + [frames[-1]] * 6


def still_frame(replay: Replay) -> np.ndarray:
    """The attempt's final state with the path of each moving thing drawn over it and a ring where
    the task was first solved."""
    from PIL import ImageDraw

    image = Image.fromarray(replay.frames[-1])
    pen = ImageDraw.Draw(image)
    width = max(2, image.width // 150)
    if not replay.points or not replay.points[0]:
        return np.asarray(image)  # the env has no picture_points: no path to draw
    for i in range(len(replay.points[0])):
        path = [p[i] for p in replay.points]
        pen.line(path, fill=PATH_RGB[i % len(PATH_RGB)], width=width, joint="curve")
    solved = replay.solved_at
    if solved is not None:
        for x, y in replay.points[solved][-1:]:
            r = image.width / 40
            pen.ellipse((x - r, y - r, x + r, y + r), outline=SOLVED_RGB, width=width + 1)
    return np.asarray(image)


def gif_bytes(frames: list[np.ndarray], fps: int = 8) -> bytes:
    """``frames`` as the bytes of an animated GIF (what ``write_picture`` writes to a .gif)."""
    import io

    images = [Image.fromarray(f) for f in frames]
    out = io.BytesIO()
    images[0].save(out, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return out.getvalue()


def _captioned(frame: np.ndarray, lines: list[str], width_px: int = 400) -> np.ndarray:
    """``frame``, scaled to ``width_px`` wide, over a white bar holding ``lines`` of text."""
    from PIL import ImageDraw, ImageFont

    image = Image.fromarray(frame)
    image = image.resize((width_px, round(image.height * width_px / image.width)))
    w, h = image.size
    canvas = Image.new("RGB", (w, h + CAPTION_LINE_PX * len(lines) + 4), "white")
    canvas.paste(image, (0, 0))
    draw = ImageDraw.Draw(canvas)
    font = ImageFont.load_default(size=CAPTION_FONT_PX)
    for i, line in enumerate(lines):
        draw.text((6, h + 3 + CAPTION_LINE_PX * i), line, fill="black", font=font)
    return np.asarray(canvas)
