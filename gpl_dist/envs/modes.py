"""Constructor arguments shared by every gpl-dist env."""

from __future__ import annotations

#: ``rgb_array``: an RGB picture of the scene; ``ansi``: a text picture of the scene and the path
#: taken since reset (what ``gpl-dist teach`` prints).
RENDER_MODES = (None, "rgb_array", "ansi")
REWARD_MODES = ("dense", "sparse")


def check_modes(render_mode: str | None, reward_mode: str) -> tuple[str | None, str]:
    """Validate ``render_mode`` and ``reward_mode``; a bad value fails naming the allowed ones."""
    if render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be None, 'rgb_array' or 'ansi', got {render_mode!r}")
    if reward_mode not in REWARD_MODES:
        raise ValueError(f"reward_mode must be 'dense' or 'sparse', got {reward_mode!r}")
    return render_mode, reward_mode
