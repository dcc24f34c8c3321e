"""A hung rollout actor is noticed in time (issue 65): the unit timeout adapts to the run (a multiple
of the median unit time so far, with a floor; ``collection.unit_timeout_s`` only caps it), and the
stall is printed while it lasts. The hang is real: ``gpl-dist train`` on its own local Ray cluster,
with one unit of round 1 paused inside its actor (``gpl_dist.faults``)."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest
from _cluster_tools import TINY_YAML, assert_buffer_exactly_once, wait_for
from test_fault_tolerance import _Driver, _pause_unit

from gpl_dist.config import ConfigError, config_from_dict
from gpl_dist.faults import FAULT_ENV


def test_the_unit_timeout_is_a_multiple_of_the_median_within_the_floor_and_the_ceiling():
    from workers.ray_collector import unit_timeout

    assert unit_timeout([], 60, 10, 1800) == 1800  # nothing timed yet: only the ceiling
    assert unit_timeout([1.0, 2.0, 300.0], 60, 10, 1800) == 60  # median 2 s: the floor
    assert unit_timeout([20.0, 30.0, 40.0], 60, 10, 1800) == 300
    assert unit_timeout([500.0], 60, 10, 1800) == 1800
    assert unit_timeout([1.0], 60, 10, 30) == 30  # a ceiling below the floor wins


def test_the_adaptive_timeout_settings_are_checked_in_one_line():
    cfg = config_from_dict({"collection": {"unit_timeout_floor_s": 20, "unit_timeout_multiple": 4}})
    assert (cfg.collection.unit_timeout_floor_s, cfg.collection.unit_timeout_multiple) == (20.0, 4.0)
    for key, value, needle in (("unit_timeout_floor_s", 0, "collection.unit_timeout_floor_s must be positive"),
                               ("unit_timeout_multiple", 0.5, "collection.unit_timeout_multiple must be at least 1")):
        with pytest.raises(ConfigError, match=re.escape(needle)) as info:
            config_from_dict({"collection": {key: value}})
        assert "\n" not in str(info.value)


@pytest.mark.cluster
def test_a_hung_actor_costs_a_round_the_adaptive_timeout_not_the_ceiling_and_the_stall_is_printed(tmp_path):
    """Round 1's unit 0 hangs in its actor (alive, silent); round 0 timed the units (a second or
    so each). With the shipped ceiling (1800 s) and a floor of 20 s, the unit is handed out again
    after about 20 s, lines name the stall meanwhile, and the run finishes, every unit once."""
    config, run_dir, signals = tmp_path / "tiny.yaml", tmp_path / "run", tmp_path / "signals"
    config.write_text(TINY_YAML)
    signals.mkdir()
    floor_s = 20
    driver = _Driver(["--config", str(config), "--run-dir", str(run_dir), "--set", f"collection.unit_timeout_floor_s={floor_s}"],
                     tmp_path / "driver.log", **{FAULT_ENV: _pause_unit(1, 0, signals)})
    try:
        wait_for(signals / "round-1-unit-0.pid", driver.proc, timeout=180)
        paused_at = time.monotonic()
        paused_pid = int((signals / "round-1-unit-0.pid").read_text())
        # the ceiling is 1800 s: the run ends only if the adaptive timeout handed the unit out again
        assert driver.proc.wait(240) == 0
        waited = time.monotonic() - paused_at
        assert not Path(f"/proc/{paused_pid}").exists() or b"RolloutActor" not in \
            Path(f"/proc/{paused_pid}/cmdline").read_bytes(), "the hung actor was left running"
    finally:
        assert driver.cleanup() == []
    log = (tmp_path / "driver.log").read_text()
    timed_out = re.search(r"unit \(1, 0\) got no result from actor-\d within (\d+)s \(10 x the median unit time "
                          r"[\d.]+s of \d+ units, at least collection.unit_timeout_floor_s=20s, at most "
                          r"collection.unit_timeout_s=1800s; a hung actor or a lost call\)", log)
    assert timed_out, log[-3000:]
    timeout = int(timed_out.group(1))
    assert floor_s <= timeout <= 120, timeout  # far below the ceiling
    assert floor_s - 5 < waited < timeout + 90, (waited, timeout)
    stalls = re.findall(r"^unit 0 of round 1 on actor \d: no result for (\d+) s \(timeout (\d+) s\)$", log, re.M)
    assert stalls, log[-3000:]  # printed while it lasted, before the unit was handed out again
    assert all(int(t) == timeout and 0 < int(w) <= timeout for w, t in stalls), stalls
    assert "returned nothing in time" in log and "round 1:" in log, log[-3000:]
    assert_buffer_exactly_once(run_dir / "buffer", [0, 1])
