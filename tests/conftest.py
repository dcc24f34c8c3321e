"""Shared fixtures: one Ray cluster per test session, on loopback, with its own temp dir."""

from __future__ import annotations

import os
import tempfile

import pytest


@pytest.fixture(scope="session")
def ray_cluster():
    """A local Ray cluster shared by every test that needs one (started once: it takes seconds)."""
    import ray

    from workers.ray_collector import init_ray

    if ray.is_initialized():
        yield ray
        return
    # Short path: Ray's Unix sockets live under the temp dir and have a length limit.
    temp_dir = tempfile.mkdtemp(prefix="gplray-", dir="/tmp")
    # The product's own start-up path, so the loopback test checks what `gpl-dist train` runs.
    init_ray(None, 2, temp_dir=temp_dir, log_to_driver=False, object_store_memory=512 * 1024 * 1024)
    yield ray
    ray.shutdown()


@pytest.fixture(autouse=True)
def _single_torch_thread():
    """Tests share 2 cores with Ray; one torch thread keeps timings and results stable."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


os.environ.setdefault("RAY_DEDUP_LOGS", "0")
# The plug-in files this test session trains from are trusted in a file of its own, never the user's.
os.environ["GPL_DIST_TRUST_FILE"] = os.path.join(tempfile.mkdtemp(prefix="gpltrust-"), "trusted-domain-modules.json")
