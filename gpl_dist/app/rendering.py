"""Pictures of tasks and attempts: a PNG of a task's start state, a GIF of an attempt.

Both domains' envs render the full scene with ``render_mode="rgb_array"``; this module only
drives them and writes files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image

from gpl_dist.domains import get_domain
from gpl_dist.errors import UsageError
from gpl_dist.experts import make_expert
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


def attempt_frames(domain_name: str, task_id: int, actions: Sequence[int] | None = None, expert: bool = False,
                   seed: int = 0, max_steps: int | None = None) -> list[np.ndarray]:
    """RGB frames of the task's start state and each state after ``actions`` (or the expert's)."""
    domain = get_domain(domain_name)
    env = domain.make_env(task_id, render_mode="rgb_array")
    env.reset(seed=seed)
    frames: list[np.ndarray] = [np.asarray(env.render())]
    if actions is None and not expert:
        return frames
    steps = max_steps or domain.steps_per_attempt
    policy = None
    if expert:
        policy = make_expert(env)
    planned = list(actions or ())
    for t in range(steps if expert else min(len(planned), steps)):
        a = policy.act(env) if policy is not None else int(planned[t])
        if not 0 <= a < domain.num_actions:
            raise UsageError(f"action {a} at step {t} is outside 0..{domain.num_actions - 1}")
        _, _, _, _, info = env.step(a)
        frames.append(np.asarray(env.render()))
        if expert and info.get("success"):
            break  # the expert's attempt ends where the task is solved, in either domain
    return frames


def write_picture(frames: list[np.ndarray], out: str | Path, fps: int = 8) -> Path:
    """Write one frame as PNG, or all frames as an animated GIF when ``out`` ends in .gif."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".gif":
        out.write_bytes(gif_bytes(frames, fps))
    else:
        Image.fromarray(frames[-1] if len(frames) > 1 else frames[0]).save(out)
    return out


#: Pixels of the caption bar under each frame of a policy's attempts.
CAPTION_PX = 44
#: Characters of a caption line (a correction is cut there, with "...").
CAPTION_CHARS = 48
#: Font size of the captions, in pixels (readable when the page shows the GIF 300 px wide).
CAPTION_FONT_PX = 14


def policy_attempt_frames(run_dir: str | Path, task_id: int, num_attempts: int, seed: int = 0,
                          checkpoint: str | None = None, frame_stride: int | None = None,
                          foreign_checkpoint: bool = False) -> list[np.ndarray]:
    """Frames of a trained policy's successive attempts at ``task_id``, as at meta-test.

    The run's policy makes up to ``num_attempts`` attempts, each after the oracle's correction of
    the one before (the run's own conditioning and oracle, ``workers.loop.Rollout``); each attempt
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
    for k, att in enumerate(result.attempts):
        said = att.instruction if k == 0 else result.attempts[k - 1].correction
        top = f"attempt {k + 1}/{len(result.attempts)}: {'instruction' if k == 0 else 'correction'}: {said}"
        bottom = f"completion {att.completion:.2f}" + (" - solved" if att.success else "")
        frames += captioned_attempt_frames(domain.name, task_id, att.actions, att.seed, top, bottom, frame_stride)
    return frames


def captioned_attempt_frames(domain_name: str, task_id: int, actions: np.ndarray, reset_seed: int, top: str,
                             bottom: str, frame_stride: int | None = None) -> list[np.ndarray]:
    """An attempt replayed from ``reset_seed`` and ``actions``, every ``frame_stride``-th step
    (default: about 40 frames), each frame captioned ``top`` over ``step t`` (``bottom`` on the
    last, which is held for a moment)."""
    stride = frame_stride or max(1, get_domain(domain_name).steps_per_attempt // 40)
    drawn = attempt_frames(domain_name, task_id, np.asarray(actions).tolist(), seed=reset_seed)
    last = len(drawn) - 1
    frames = [_captioned(drawn[t], top, bottom if t == last else f"step {t}") for t in [*range(0, last, stride), last]]
    return frames + [frames[-1]] * 6


def gif_bytes(frames: list[np.ndarray], fps: int = 8) -> bytes:
    """``frames`` as the bytes of an animated GIF (what ``write_picture`` writes to a .gif)."""
    import io

    images = [Image.fromarray(f) for f in frames]
    out = io.BytesIO()
    images[0].save(out, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return out.getvalue()


def _captioned(frame: np.ndarray, top: str, bottom: str, width_px: int = 400) -> np.ndarray:
    """``frame``, scaled to ``width_px`` wide, over a white bar holding two lines of text."""
    from PIL import ImageDraw, ImageFont

    image = Image.fromarray(frame)
    image = image.resize((width_px, round(image.height * width_px / image.width)))
    w, h = image.size
    canvas = Image.new("RGB", (w, h + CAPTION_PX), "white")
    canvas.paste(image, (0, 0))
    draw = ImageDraw.Draw(canvas)
    font = ImageFont.load_default(size=CAPTION_FONT_PX)
    cut = lambda text: text if len(text) <= CAPTION_CHARS else text[: CAPTION_CHARS - 3] + "..."  # noqa: E731
    draw.text((6, h + 3), cut(top), fill="black", font=font)
    draw.text((6, h + 23), cut(bottom), fill="black", font=font)
    return np.asarray(canvas)
