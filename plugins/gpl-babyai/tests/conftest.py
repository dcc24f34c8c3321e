"""Fixtures of the BabyAI plug-in's tests."""

from __future__ import annotations

import os
import tempfile

import pytest

# Plug-in files a test trains from are trusted in a file of this session's own, never the user's.
os.environ.setdefault("GPL_DIST_TRUST_FILE", os.path.join(tempfile.mkdtemp(prefix="gpltrust-"), "trusted.json"))


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """2 shared cores: torch's default threads make a batched rollout forward 10-40x slower under load."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
