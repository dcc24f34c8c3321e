"""The BabyAI study's suite file (``configs/suites/babyai.yaml``): its entries and evaluations are
what the study needs, and every run's config resolves against the installed plug-in."""

from pathlib import Path

from gpl_dist.app.suite.spec import load_suite, plan
from gpl_dist.domains import get_domain
from gpl_dist.splits import split_tasks

SUITE = Path(__file__).resolve().parents[3] / "configs" / "suites" / "babyai.yaml"


def test_the_babyai_suite_trains_four_methods_at_five_seeds_and_tests_every_level(tmp_path):
    suite = load_suite(SUITE)
    assert suite.reference == "babyai-gpl"
    runs = plan(suite, tmp_path)
    assert len(runs) == 20 and {r.seed for r in runs} == {0, 1, 2, 3, 4}
    variants = {}
    for run in runs:
        cfg = run.config(suite)
        assert cfg.env.domain == "babyai" and cfg.env.train_split == "train" and cfg.seed == run.seed
        variants[run.entry.name] = (cfg.model.variant, cfg.env.correction_kind)
    assert variants == {"babyai-gpl": ("gpl", "default"), "babyai-instruction": ("instruction_only", "default"),
                        "babyai-full-info": ("full_information", "default"), "babyai-retry": ("gpl", "retry")}
    domain = get_domain("babyai")
    splits = {e.config.split for e in suite.evaluations.values()}
    # every trained level's test seeds, together and one by one, and the held-out levels
    assert {"test", "heldout_level_test"} <= splits
    assert {s for s in domain.split_names if s.startswith(("test_", "heldout_"))} <= splits
    assert all(split_tasks("babyai", s) for s in splits)
    for entry in suite.entries:
        assert set(entry.evaluations) == set(suite.evaluations)
