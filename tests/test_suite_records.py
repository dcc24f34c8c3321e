"""The evaluation, curve and instruction-swap files as records: each era of the archived files
reads through ``from_json`` (the one place an older shape is upgraded), and a record written
today reads back as itself."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from gpl_dist.app.suite.records import (
    CURVE_SCHEMA,
    SWAP_SCHEMA,
    UNKNOWN_SPLIT,
    CurveRecord,
    CurveSettings,
    SwapRecord,
    read_curve,
    read_swap,
)
from gpl_dist.errors import RunDirError
from learner.evaluate import EVAL_SCHEMA, EvalRecord, read_eval

RUNS = Path(__file__).resolve().parents[1] / "docs" / "paper-report" / "runs"


@pytest.mark.parametrize("path,run_id,instructions", [
    ("multiroom-instruction/seed2/eval.json", False, False),  # before run ids
    ("multiroom-binary/seed2/eval.json", True, False),  # before the swap control
    ("multiroom-gpl-goal-room-apart/seed2/eval.json", True, True),  # every key of today's, no version
])
def test_every_era_of_the_archived_eval_files_reads_as_a_record(path, run_id, instructions):
    text = (RUNS / path).read_text()
    raw = json.loads(text)
    assert ("run_id" in raw, "instructions" in raw, "schema_version" in raw) == (run_id, instructions, False)
    record = EvalRecord.from_json(text)
    assert record.schema_version == 1 and record.completion == tuple(raw["completion"])
    assert record.run_id == (raw["run_id"] if run_id else None) and record.instructions == "own" and not record.swapped
    assert record.correction_effort is not None and record.seeds == tuple(raw["seeds"])
    if run_id and instructions:  # today's keys in today's order: the same bytes but for the version
        assert record.to_json() == text.replace("\n}", ',\n "schema_version": 1\n}')
    again = dataclasses.replace(record, schema_version=EVAL_SCHEMA)
    assert EvalRecord.from_json(again.to_json()) == again


def test_an_eval_file_that_is_no_record_or_of_a_later_schema_fails_in_one_line(tmp_path):
    path = tmp_path / "eval.json"
    raw = json.loads((RUNS / "multiroom-gpl" / "seed0" / "eval.json").read_text())
    no_split = {k: v for k, v in raw.items() if k != "split"}
    for bad, why in (({**raw, "completion": "high"}, "expected a list"), (no_split, "'split'"),
                     ({**raw, "schema_version": EVAL_SCHEMA + 1}, "schema_version"), ([1, 2], "not a JSON object")):
        path.write_text(json.dumps(bad))
        with pytest.raises(RunDirError, match=why) as err:
            read_eval(path)
        assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_the_archived_curve_and_swap_files_read_and_todays_records_round_trip(tmp_path):
    curve = read_curve(RUNS / "multiroom-binary" / "seed2" / "curve-valid.json")
    assert curve.schema_version == 1 and curve.settings.split == "valid" and len(curve.rounds) == len(curve.completion)
    assert curve.rounds and len(curve.checkpoints) == len(curve.rounds)
    grown = curve.with_point(99, [0.5, 0.6], [0.1, 0.2], "round-000099.pt")
    assert grown.schema_version == CURVE_SCHEMA and grown.rounds[-1] == 99 and CurveRecord.from_json(grown.to_json()) == grown
    swap = read_swap(RUNS / "multiroom-gpl" / "seed0" / "instruction-swap-valid.json")
    assert swap.schema_version == 1 and swap.settings.split == "valid"
    assert len(swap.own.completion) == len(swap.swapped.completion) == swap.settings.num_corrections + 1
    assert swap.measures(swap.settings, swap.rule, swap.round, swap.weights_sha256)
    assert not swap.measures(dataclasses.replace(swap.settings, tasks=3), swap.rule, swap.round, swap.weights_sha256)
    now = dataclasses.replace(swap, schema_version=SWAP_SCHEMA)
    assert SwapRecord.from_json(now.to_json()) == now


def test_a_curve_file_from_before_its_settings_reads_as_measured_on_no_known_split(tmp_path):
    path = tmp_path / "curve-valid.json"
    path.write_text(json.dumps({"rounds": [0, 1], "completion": [[0.1], [0.2]]}))
    curve = read_curve(path)
    assert curve.settings == CurveSettings(split=UNKNOWN_SPLIT) and curve.rounds == (0, 1) and curve.checkpoints == ()
    path.write_text(json.dumps({"rounds": [0], "completion": [[0.1]], "schema_version": CURVE_SCHEMA}))
    with pytest.raises(RunDirError, match="not a learning curve .*'settings'"):
        read_curve(path)
