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


def test_suite_status_reads_the_archived_babyai_runs_without_importing_the_plug_in(tmp_path):
    """The study's archived runs (``docs/babyai-report/runs``), restored, are the whole study (every
    entry at every training seed, every evaluation made) and count as done for ``suite status``, a
    read-only command that imports no plug-in (a fresh process, as a user runs it): the fields the
    entry leaves to the domain (its expert, its splits) are the runs' own, not a changed config."""
    import subprocess
    import sys

    archive = SUITE.parents[2] / "docs" / "babyai-report" / "runs"
    out = tmp_path / "babyai"

    def cli(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "gpl_dist.cli", *args], capture_output=True, text=True, timeout=300)

    assert cli("suite", "restore", str(archive), "--out", str(out)).returncode == 0
    status = cli("suite", "status", str(SUITE), "--out", str(out))
    assert status.returncode == 0, status.stderr[-500:]
    states = {}
    for line in status.stdout.splitlines():
        words = line.split()
        if len(words) > 3 and words[2] == "seed":  # "<state> <entry> seed <k> (<run dir>; ...)"
            states[(words[1], int(words[3]))] = words[0]
    planned = {(run.entry.name, run.seed) for run in plan(load_suite(SUITE), out)}
    assert len(planned) == 20 and states == {key: "done" for key in planned}


def test_the_babyai_report_is_regenerated_byte_for_byte_from_its_archive(tmp_path):
    """Every file of docs/babyai-report (report.md, report.html, each plot) from its archived runs,
    the report naming the suite output it was made from, as the committed one does."""
    from gpl_dist.app.suite.report import rebuild_report

    report_dir = SUITE.parents[2] / "docs" / "babyai-report"
    rebuild_report(report_dir, tmp_path, log=lambda _: None)
    expected = sorted(p.name for p in report_dir.iterdir() if p.is_file())
    assert sorted(p.name for p in tmp_path.iterdir()) == expected and "report.md" in expected
    for name in expected:
        assert (tmp_path / name).read_bytes() == (report_dir / name).read_bytes(), name
