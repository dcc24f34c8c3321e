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
        from gpl_dist.experts import make_expert
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
        images = [Image.fromarray(f) for f in frames]
        images[0].save(out, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    else:
        Image.fromarray(frames[-1] if len(frames) > 1 else frames[0]).save(out)
    return out
