"""The report's statistics (t intervals, Welch's test) and its health gate, on real records."""

import json
import math

import numpy as np
import pytest

from gpl_dist.app.suite.report import (
    RunResult,
    cell,
    comparisons_markdown,
    healthy,
    provenance_markdown,
    table_markdown,
    wanted_runs,
)
from gpl_dist.app.suite.report_paper import load_paper
from gpl_dist.app.suite.run_facts import run_budget, run_health
from gpl_dist.app.suite.stats import mean_ci, t_quantile, t_two_sided_p, welch
from learner.health import EncoderHealth
from learner.rounds import RoundMetrics

# two-sided 95 % critical values of Student's t (any statistics table)
T975 = {1: 12.7062, 2: 4.3027, 3: 3.1824, 4: 2.7764, 5: 2.5706, 9: 2.2622, 19: 2.0930, 30: 2.0423}


@pytest.mark.parametrize("df,expected", sorted(T975.items()))
def test_t_quantiles_match_the_table_and_invert_the_p_value(df, expected):
    q = t_quantile(0.975, df)
    assert q == pytest.approx(expected, abs=5e-4)
    assert t_two_sided_p(q, df) == pytest.approx(0.05, abs=1e-9)
    assert t_quantile(0.025, df) == pytest.approx(-q)


def test_mean_ci_and_welch_agree_with_their_formulas():
    a, b = [0.938, 0.942, 0.949], [0.911, 0.938, 0.951, 0.937, 0.825]
    ci = mean_ci(b)
    assert ci.mean == pytest.approx(np.mean(b)) and ci.sd == pytest.approx(np.std(b, ddof=1))
    assert ci.half_width == pytest.approx(T975[4] * np.std(b, ddof=1) / math.sqrt(5), rel=1e-4)
    assert ci.relation(0.99) == "below" and ci.relation(0.80) == "above" and ci.relation(0.9) == "inside"
    w = welch(a, b)
    va, vb = np.var(a, ddof=1) / 3, np.var(b, ddof=1) / 5
    assert w.t == pytest.approx((np.mean(a) - np.mean(b)) / math.sqrt(va + vb))
    assert w.df == pytest.approx((va + vb) ** 2 / (va ** 2 / 2 + vb ** 2 / 4))
    assert 0.2 < w.p < 0.3 and w.verdict() == "tie"  # the LeakyReLU candidate against the former network
    far = welch([0.9, 0.91, 0.92], [0.1, 0.12, 0.11])
    assert far.p < 1e-4 and far.verdict("GPL", "baseline") == "GPL above baseline"
    assert welch([0.5], [0.1, 0.2]).verdict().startswith("untested")
    assert mean_ci([0.4]).half_width is None and mean_ci([0.4]).relation(0.1) == "unknown"


def _run(tmp_path, name, dead_rounds=(), encoder="instruction", kind=None):
    """A run dir whose metrics.jsonl holds 3 rounds (real RoundMetrics rows); the instruction
    encoder's layer dead whole in ``dead_rounds``."""
    d = tmp_path / name
    d.mkdir()
    rows = []
    for r in range(3):
        dead = r in dead_rounds
        health = tuple(EncoderHealth(e, 16, 16 if dead and e == encoder else 3, 0, 0, 1 if dead and e == encoder else 0)
                       for e in ("instruction", "correction"))
        rows.append(RoundMetrics(round_index=r, collected_tuples=100 * (r + 1), failed_tasks=(), collection_seconds=1.0,
                                 load_seconds=0.1, completion_by_corrections=(0.1 * r, 0.2 * r), buffer_tuples=100,
                                 loss=1.0, accuracy=0.5, train_seconds=60.0, train_steps=10,
                                 correction_spread=1.0, encoder_health=health).to_dict())
    (d / "metrics.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    if kind:
        (d / "config.yaml").write_text(f"env:\n  correction_kind: {kind}\n")
    return d


def test_a_run_dead_at_its_final_round_is_left_out_of_every_mean(tmp_path):
    ok, early, dead = _run(tmp_path, "ok"), _run(tmp_path, "early", (0,)), _run(tmp_path, "dead", (1, 2))
    h = {d: run_health(d) for d in (ok, early, dead)}
    assert h[ok].valid and not h[ok].dead_layers and h[ok].instrumented
    assert h[early].valid and h[early].dead_layers == ((0, "instruction"),) and "rounds 0" in h[early].text()
    assert not h[dead].valid and h[dead].dead_at_end == ("instruction",) and "NOT VALID" in h[dead].text()
    # the retry control's correction is one fixed sentence: its encoder is constant by design
    rh = run_health(_run(tmp_path, "retry", (1, 2), "correction", "retry"))
    assert rh.valid and "not counted" in rh.text() and rh.constant_inputs == ("correction",)
    assert not run_health(_run(tmp_path, "retry-blind", (2,), "instruction", "retry")).valid
    assert not run_health(_run(tmp_path, "gpl-blind", (2,), "correction", "default")).valid
    budget = run_budget(ok)
    assert (budget.rounds, budget.tuples, budget.gradient_steps, budget.train_seconds) == (3, 600, 30, 180.0)
    assert budget.parameters is None  # no checkpoint in this dir
    results = [RunResult("multiroom-gpl", s, d, "test", (0.1, c), d / "eval.json", (), ("abc",), 1.0, 1.0, None, (0.0, c))
               for s, (d, c) in enumerate([(ok, 0.9), (early, 0.8), (dead, 0.1)])]
    kept = healthy(results, h)
    assert [r.seed for r in kept] == [0, 1]
    c = cell(kept, "multiroom-gpl", "test", 1)
    assert c is not None and c.n == 2 and c.mean == pytest.approx(0.85)
    table = next(t for t in load_paper().tables if t.key == "table1-multiroom")
    md = table_markdown(kept, table, {"multiroom-gpl": (0, 1, 2)}, [r for r in results if r not in kept])
    gpl_line = next(line for line in md.splitlines() if line.startswith("| GPL |"))
    assert "2 training seed(s): 0, 1" in gpl_line and "left out: 2" in gpl_line and "not run yet" not in gpl_line
    # the runs table lists every archived run, the one left out marked so
    prov = provenance_markdown(kept, tmp_path, [r for r in results if r not in kept]).splitlines()
    rows = {line.split("|")[2].strip(): line for line in prov if line.startswith("| multiroom-gpl |")}
    assert sorted(rows) == ["0", "1", "2 (not valid: left out of the means)"]


def test_comparisons_test_every_row_against_its_tables_gpl(tmp_path):
    d = _run(tmp_path, "r")
    results = [RunResult("multiroom-gpl", s, d, "test", (0.02, 0.5, 0.8, 0.9, 0.92, 0.93 + 0.01 * s), d, (), (), 1, 1)
               for s in range(3)]
    results += [RunResult("multiroom-instruction", s, d, "test", (0.02 + 0.001 * s,), d, (), (), 1, 1) for s in range(3)]
    results += [RunResult("multiroom-retry", s, d, "test", (0.02, 0.3, 0.5, 0.6, 0.7, 0.80 + 0.2 * s), d, (), (), 1, 1)
                for s in range(3)]
    md = comparisons_markdown(results)
    lines = {line.split("|")[1].strip(): line for line in md.splitlines()[2:]}
    instr = next(v for k, v in lines.items() if "Instruction c0" in k and "multiroom" in k)
    assert "GPL above other" in instr
    retry = next(v for k, v in lines.items() if "retry control c5" in k and "gain" not in k)
    assert "tie" in retry  # 0.94 vs 1.0 +- a wide spread over 3 seeds
    assert any("gain over c0" in k for k in lines)
    # a side short of the suite's planned seeds makes a verdict provisional, never a claim
    planned = {"multiroom-gpl": (0, 1, 2, 3), "multiroom-instruction": (0, 1, 2, 3, 4), "multiroom-retry": (0, 1, 2)}
    left_out = [RunResult("multiroom-gpl", 3, d, "test", (0.02, 0.1), d, (), (), 1, 1)]  # seed 3 stands in for it
    wanted = wanted_runs(planned, left_out)
    assert wanted == {"multiroom-gpl": 3, "multiroom-instruction": 5, "multiroom-retry": 3}
    short = {line.split("|")[1].strip(): line for line in comparisons_markdown(results, wanted).splitlines()[2:]}
    instr = next(v for k, v in short.items() if "Instruction c0" in k and "multiroom" in k)
    assert "GPL above other (provisional: multiroom-instruction 3 of 5 seeds)" in instr
    assert all("provisional" not in v for k, v in short.items() if "retry" in k)
    # equal budgets: a 12-round ablation is set against GPL trained 12 rounds too, and against GPL's 6
    long = [RunResult(entry, s, d, "test", (0.02, 0.5, 0.8, 0.9, 0.92, c + 0.01 * s), d, (), (), 1, 1)
            for entry, c in (("multiroom-gpl-long", 0.95), ("multiroom-latest-correction-long", 0.80)) for s in range(3)]
    both = {line.split("|")[1].strip(): line for line in comparisons_markdown(results + long).splitlines()[2:]}
    assert "GPL above other" in both["Table 2: GPL 12 rounds c5 vs Only immediate correction, 12 rounds c5"]
    assert "GPL above other" in both["Table 2: GPL c5 vs Only immediate correction, 12 rounds c5"]
    assert "Table 1, multiroom: GPL c5 vs GPL, 12 rounds c5" in both
    assert not any(k.startswith("Table 2: GPL 12 rounds c5 vs Base") for k in both)
