"""RL per test task on stable-baselines3's PPO: the same code path on both domains, fine-tuning
from a DAgger policy, and the suite's rl section end to end (serial and on Ray)."""

import json

import gymnasium
import numpy as np
import pytest
import torch
from test_suite import entry, write_suite

from gpl_dist.app.suite.every_run import run_suite
from gpl_dist.app.suite.rl.jobs import load_results, run_rl_plan
from gpl_dist.app.suite.rl.per_task import (
    CompletionRecorder,
    RLJob,
    _instruction_only,
    all_copies_solved,
    budget_callback,
    log_points,
    make_ppo,
    run_rl_job,
    smoothed,
)
from gpl_dist.app.suite.rl.plan import rl_jobs
from gpl_dist.app.suite.spec import load_suite
from gpl_dist.cli import main
from gpl_dist.config import ConfigError
from gpl_dist.models.build import state_dict_to_numpy
from learner.evaluate import load_trained_policy
from learner.ppo import PPOSettings

SMALL = PPOSettings(n_envs=2, batch_size=64, n_epochs=1)  # one episode of each copy per update


@pytest.mark.parametrize("domain, task", [("multiroom", 69), ("relocation", 11)])
def test_ppo_records_every_trajectorys_completion_reproducibly(domain, task):
    job = RLJob("rl-scratch", domain, task, 0, 6)
    a, b = run_rl_job(job, SMALL), run_rl_job(job, SMALL)
    assert len(a.completion) == 6 == len(a.success)
    assert all(0.0 <= c <= 1.0 for c in a.completion)
    steps = {"multiroom": 100, "relocation": 350}[domain]
    # two copies end their episodes together: the budget's 6 are 3 episodes of each, then it stops
    assert a.env_steps == 6 * steps
    assert a.completion == b.completion  # seeded: the same job gives the same curve
    assert RLJob("rl-scratch", domain, task, 1, 6) != job


def test_updates_stop_once_every_copy_solved_the_task_and_sampling_goes_on():
    assert all_copies_solved([False, True, True], 2) and not all_copies_solved([True, False], 2)
    assert not all_copies_solved([True], 2)  # not every copy has ended an episode yet
    model, log = make_ppo(RLJob("rl-scratch", "multiroom", 69, 0, 4), SMALL)
    solved_at: list[int] = []
    callback = budget_callback(log, 10_000, SMALL, solved_at)
    callback.init_callback(model)
    log.success[:] = [True, False]
    callback.on_rollout_end()
    assert model.updating and solved_at == []  # one copy failed: PPO goes on updating
    log.success[:] = [False, True, True]
    callback.on_rollout_end()
    assert not model.updating and solved_at == [3]
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(total_timesteps=2 * 100 * SMALL.n_envs)
    assert len(log.completion) >= 4  # it kept sampling episodes...
    assert all(torch.equal(a, b) for a, b in zip(before, model.policy.parameters()))  # ...with the same policy
    model.updating = True
    model.learn(total_timesteps=100 * SMALL.n_envs)
    assert not all(torch.equal(a, b) for a, b in zip(before, model.policy.parameters()))


def test_the_horizon_ends_an_rl_episode_as_terminal():
    env = CompletionRecorder(gymnasium.make("gpl/MultiRoom-v0", task_id=69), horizon_is_terminal=True)
    env.reset(seed=0)
    ends = [env.step(0)[2:4] for _ in range(100)]
    assert ends[:99] == [(False, False)] * 99 and ends[99] == (True, False) and len(env.completion) == 1


@pytest.fixture(scope="module")
def instruction_run(tmp_path_factory):
    run = tmp_path_factory.mktemp("rl") / "instr"
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--no-progress", "--run-dir", str(run),
                 "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4",
                 "--set", "training.num_epochs_per_round=1", "--set", "model.variant=instruction_only"]) == 0
    return run


def test_finetuning_starts_from_exactly_the_pretrained_policy(instruction_run):
    cfg, network, _ = load_trained_policy(instruction_run)
    network.eval()
    job = RLJob("rl-finetune", "multiroom", 69, 0, 4, pretrained="instr")
    model, env = make_ppo(job, SMALL, state_dict_to_numpy(network), cfg.model)
    obs = model.env.reset()[:1]  # the first copy, as SB3 sees it (channels first)
    obs_t, _ = model.policy.obs_to_tensor(obs)
    model.policy.set_training_mode(False)
    with torch.no_grad():
        sb3 = model.policy.get_distribution(obs_t).distribution.logits
        raw = torch.from_numpy(np.transpose(obs, (0, 2, 3, 1)))
        ids = torch.from_numpy(network.vocabulary.encode(env.unwrapped.instruction)).reshape(1, -1)
        ours = torch.log_softmax(network.action_logits(raw, network.encode_conditioning(_instruction_only(ids))), 1)
    assert torch.allclose(sb3, ours, atol=1e-5)
    pi, vf = model.policy.pi_features_extractor, model.policy.vf_features_extractor  # the authors' separate value net
    assert not {id(p) for p in pi.parameters()} & {id(p) for p in vf.parameters()}
    assert all(torch.equal(a, b) for a, b in zip(pi.parameters(), vf.parameters()))  # both from the pretrained trunk
    with pytest.raises(Exception, match="needs a pretrained policy"):
        make_ppo(job, SMALL, None)


def test_relocation_finetuning_starts_from_exactly_the_pretrained_policy():
    """Relocation's path (a state vector, an input and a policy BatchNorm with their statistics):
    weights of an instruction-only network built as ``configs/relocation.yaml`` says, with
    non-trivial BatchNorm statistics, give SB3's policy the network's own action distribution."""
    import dataclasses

    from gpl_dist.app.suite.rl.per_task import task_network
    from gpl_dist.config import load_config
    from gpl_dist.domains import get_domain

    model_cfg = dataclasses.replace(load_config("configs/relocation.yaml").model, variant="instruction_only")
    network = task_network(get_domain("relocation"), None, seed=5, model=model_cfg)
    generator = torch.Generator().manual_seed(5)
    for norm in (m for m in network.modules() if isinstance(m, torch.nn.BatchNorm1d)):
        norm.running_mean = torch.randn(norm.num_features, generator=generator)
        norm.running_var = torch.rand(norm.num_features, generator=generator) + 0.5
    network.eval()
    job = RLJob("rl-finetune", "relocation", 11, 0, 4, pretrained="instr")
    model, env = make_ppo(job, SMALL, state_dict_to_numpy(network), model_cfg)
    obs = model.env.reset()[:1]
    obs_t, _ = model.policy.obs_to_tensor(obs)
    model.policy.set_training_mode(False)
    with torch.no_grad():
        sb3 = model.policy.get_distribution(obs_t).distribution.logits
        ids = torch.from_numpy(network.vocabulary.encode(env.unwrapped.instruction)).reshape(1, -1)
        ours = torch.log_softmax(network.action_logits(torch.from_numpy(obs), network.encode_conditioning(
            _instruction_only(ids))), 1)
    assert torch.allclose(sb3, ours, atol=1e-5)
    assert not torch.allclose(ours, torch.full_like(ours, -np.log(ours.shape[1])), atol=1e-3)  # not uniform


def _suite(tmp_path, **rl_overrides):
    spec = {"instr": entry(**{"training.num_rounds": 1, "model.variant": "instruction_only"}),
            "gpl": entry(**{"training.num_rounds": 1})}
    path = write_suite(tmp_path / "suite.yaml", spec)
    raw = json.loads(path.read_text())
    raw["rl"] = {"tasks": {"multiroom": [69, 180]}, "seeds": [0], "trajectories": 3,
                 "pretrained": {"multiroom": "instr"}, "attempts_from": {"multiroom": ["gpl"]},
                 "ppo": {"n_envs": 2, "n_steps": 64, "batch_size": 32, "multiroom": {"n_epochs": 1}}, **rl_overrides}
    path.write_text(json.dumps(raw))
    return path


def test_the_rl_section_runs_every_job_once_and_reports_the_figure(tmp_path, capsys, ray_cluster):
    path = _suite(tmp_path)
    suite = load_suite(path)
    out = tmp_path / "out"
    lines: list[str] = []
    assert run_rl_plan(suite.rl, out, serial=True, log=lines.append) == 2  # rl-scratch needs no trained entry
    assert any("rl-finetune/multiroom left for later" in s and "has not finished training yet" in s for s in lines)
    run_suite(suite, out, serial=True, progress=False)
    address = ray_cluster.get_runtime_context().gcs_address
    assert run_rl_plan(suite.rl, out, address=address, log=lambda s: None) == 1 + 2  # GPL's points, rl-finetune x 2 tasks
    curves, attempts, _, _ = load_results(out)
    assert sorted(c.job.key for c in curves) == sorted(j.key for j in rl_jobs(suite.rl)) and len(curves) == 4
    assert all(len(c.completion) == 3 for c in curves)
    assert attempts[0]["tasks"] == [69, 180] and np.array(attempts[0]["completion"]).shape == (2, 6)
    assert run_rl_plan(suite.rl, out, serial=True, log=lambda s: None) == 0  # done: nothing runs again
    capsys.readouterr()
    assert main(["suite", "status", str(path), "--out", str(out)]) == 0
    status = capsys.readouterr().out
    assert "rl: 4 of 4 RL jobs done" in status and "rl: 1 of 1 GPL/GPR attempt sets done" in status
    (out / "rl" / "rl-scratch" / "multiroom" / "task69-seed0.json").unlink()  # as if killed before writing it
    stale = out / "rl" / "rl-finetune" / "multiroom" / "task180-seed0.json"
    stale.write_text(json.dumps({**json.loads(stale.read_text()), "settings": {"n_envs": 7}}))  # other PPO settings
    # made from an earlier training of the entries: the pretrained policy, GPL's policy
    started = out / "rl" / "rl-finetune" / "multiroom" / "task69-seed0.json"
    policy = json.loads(started.read_text())["policy"]
    points = out / "rl" / "attempts" / "gpl-seed0.json"
    for made in (started, points):
        assert len(json.loads(made.read_text())["policy"]) == 16
        made.write_text(json.dumps({**json.loads(made.read_text()), "policy": "0" * 16}))
    assert main(["suite", "status", str(path), "--out", str(out)]) == 0
    status = capsys.readouterr().out  # neither the missing nor the stale ones
    assert "rl: 1 of 4 RL jobs done" in status and "rl: 0 of 1 GPL/GPR attempt sets done" in status
    (out / "suite.yaml").unlink()  # as if only 'suite rl' had run: it keeps the copy the report reads
    assert main(["suite", "rl", str(path), "--out", str(out), "--serial"]) == 0
    assert "4 RL job(s) ran" in capsys.readouterr().out
    assert (out / "suite.yaml").read_text() == path.read_text()
    assert json.loads(stale.read_text())["settings"]["n_envs"] == 2
    assert json.loads(started.read_text())["policy"] == policy and json.loads(points.read_text())["policy"] != "0" * 16
    assert main(["suite", "report", str(out), "--out", str(tmp_path / "report")]) == 0
    md = (tmp_path / "report" / "report.md").read_text()
    assert "## Sample complexity" in md and "| multiroom | rl-finetune | 2 |" in md and "gpl (gpl)" in md
    assert md.count("| 0 of 2 |") == 2  # no task solved in 3 trajectories, by either method
    assert "Code commits of these results (results each): `" in md and "(5)" in md  # 4 curves and GPL's points, one run
    assert (tmp_path / "report" / "sample-complexity.png").stat().st_size > 5000


def test_points_of_an_entry_not_trained_yet_are_left_for_a_later_run(tmp_path):
    plan = load_suite(_suite(tmp_path, pretrained={}, tasks={"multiroom": [69]})).rl
    lines: list[str] = []
    assert run_rl_plan(plan, tmp_path / "out", serial=True, log=lines.append) == 1  # the one rl-scratch job
    assert any("attempts/gpl-seed0 left for later" in s and "has not finished training yet" in s for s in lines), lines
    curves, attempts, _, _ = load_results(tmp_path / "out")
    assert [c.job.key for c in curves] == ["rl-scratch/multiroom/task69-seed0"] and attempts == []


@pytest.mark.parametrize("change, needle", [
    ({"tasks": {"multiroom": [99999]}}, "task ids must be in 0..3239"),
    ({"pretrained": {"multiroom": "nope"}}, "no entry 'nope'"),
    ({"ppo": {"n_step": 5}}, "unknown PPO setting"),
    ({"ppo": {"multiroom": {"batch_sise": 5}}}, r"ppo\.multiroom\.batch_sise: unknown PPO setting"),
    ({"ppo": {"n_envs": 2.5}}, r"ppo\.n_envs: expected a whole number >= 1"),
    ({"ppo": {"multiroom": {"n_steps": -1}}}, r"ppo\.multiroom\.n_steps: expected a whole number >= 0"),
    ({"ppo": {"multiroom": 3}}, "expected a mapping of PPO settings"),
    ({"ppo": {"stop_when_solved": 0}}, r"ppo\.stop_when_solved: expected true or false"),
    ({"ppo": {"batch_size": 1}}, r"ppo\.batch_size: expected a whole number >= 2"),
    ({"ppo": {"value_hidden": 64.5}}, r"ppo\.value_hidden: expected a whole number"),
    ({"ppo": {"learning_rate": True}}, r"ppo\.learning_rate: expected a number"),
    ({"ppo": {"learning_rate": None}}, r"ppo\.learning_rate: expected a number >= 0$"),
    ({"ppo": {"target_kl": "0.01"}}, r"ppo\.target_kl: expected a number >= 0 or null"),
    ({"ppo": {"value_layers": 0}}, r"ppo\.value_layers: expected a whole number >= 1"),
    ({"colour": 1}, "unknown key"),
    ({"trajectories": 0}, "expected an int >= 1"),
])
def test_a_bad_rl_section_fails_in_one_line(tmp_path, change, needle):
    with pytest.raises(ConfigError, match=needle):
        load_suite(_suite(tmp_path, **change))


def test_a_domain_overrides_the_common_ppo_settings(tmp_path):
    plan = load_suite(_suite(tmp_path)).rl
    assert plan.settings("multiroom") == PPOSettings(n_envs=2, n_steps=64, batch_size=32, n_epochs=1)
    shipped = load_suite("configs/suites/paper.yaml").rl
    assert shipped.settings("relocation").batch_size == 128 and shipped.settings("multiroom") == PPOSettings()
    optional = load_suite(_suite(tmp_path, ppo={"target_kl": None, "multiroom": {"value_learning_rate": 0.01}})).rl
    assert optional.settings("multiroom") == PPOSettings(value_learning_rate=0.01)


def test_a_result_written_before_the_ppo_settings_gained_fields_stays_current(tmp_path):
    """Results record their ``PPOSettings``; one written before it had ``value_learning_rate``,
    ``target_kl``, ``max_grad_norm`` and ``value_layers`` ran with their defaults, and counts as such."""
    import dataclasses

    from gpl_dist.app.suite.rl.jobs import is_current, write_result
    from gpl_dist.app.suite.rl.per_task import RLCurve

    settings = PPOSettings(n_envs=2)
    later = ("value_learning_rate", "target_kl", "max_grad_norm", "value_layers")
    old = {k: v for k, v in dataclasses.asdict(settings).items() if k not in later}
    curve = RLCurve(RLJob("rl-scratch", "multiroom", 1, 0, 5), (1.0,) * 5, (True,) * 5, 1, 1.0)
    write_result(tmp_path, curve.job.key, {**curve.to_json(), "settings": old})
    assert is_current(tmp_path, curve.job, settings)
    assert not is_current(tmp_path, curve.job, PPOSettings(n_envs=2, max_grad_norm=1.0))  # not those defaults
    assert not is_current(tmp_path, curve.job, PPOSettings(n_envs=3))


def test_curves_are_read_at_log_spaced_points():
    assert log_points(2000)[:4] == (1, 2, 3, 4) and log_points(2000)[-1] == 2000
    c = [0.0] * 9 + [1.0]
    assert smoothed(c, (1, 10)) == [0.0, 1.0] and np.isnan(smoothed(c, (11,))[0])


def test_the_table_reads_every_named_column_of_a_long_curve(tmp_path):
    from gpl_dist.app.suite.rl.jobs import write_result
    from gpl_dist.app.suite.rl.per_task import RLCurve
    from gpl_dist.app.suite.rl.report import sample_complexity_section

    ramp = tuple(min(1.0, i / 1000) for i in range(2000))  # completion rises to 1 by trajectory 1000
    for t in (1, 2):
        curve = RLCurve(RLJob("rl-scratch", "multiroom", t, 0, 2000), ramp, (False,) * 2000, 200_000, 1.0)
        write_result(tmp_path, curve.job.key, {**curve.to_json(), "commit": "abc1234"})
    md, png = sample_complexity_section(tmp_path, tmp_path / "report")
    row = next(line for line in md.splitlines() if line.startswith("| multiroom | rl-scratch |")).split("|")
    assert row[8].strip().startswith("0.09") and row[9].strip().startswith("0.95")  # at 100 and at 1000 trajectories
    assert "`abc1234` (2)" in md and png is not None and png.is_file()


def test_the_report_reads_only_the_results_of_the_suites_rl_plan(tmp_path):
    """Results of an older task list, budget or PPO settings stay on disk but out of the medians."""
    import dataclasses

    from gpl_dist.app.suite.rl.jobs import plan_of_copy, write_result
    from gpl_dist.app.suite.rl.per_task import RLCurve
    from gpl_dist.app.suite.rl.plan import parse_rl_plan
    from gpl_dist.app.suite.rl.report import sample_complexity_section

    plan = parse_rl_plan("t", {"tasks": {"multiroom": [1, 2]}, "seeds": [0], "trajectories": 50}, ())
    settings = dataclasses.asdict(plan.settings("multiroom"))

    def put(task: int, budget: int, value: float, settings=settings) -> None:
        curve = RLCurve(RLJob("rl-scratch", "multiroom", task, 0, budget), (value,) * budget, (False,) * budget, 1, 1.0)
        write_result(tmp_path, curve.job.key, {**curve.to_json(), "settings": settings})

    put(1, 50, 1.0)
    put(2, 50, 1.0)
    put(3, 50, 0.0)  # a task the plan no longer lists
    put(4, 80, 0.0)  # another budget
    md, _ = sample_complexity_section(tmp_path, tmp_path / "report", plan=plan)
    row = next(line for line in md.splitlines() if line.startswith("| multiroom | rl-scratch |")).split("|")
    assert row[3].strip() == "2" and row[4].strip().startswith("1.00")  # two tasks, both at 1.0
    assert "Left out: 2 result(s)" in md and "task3-seed0" in md
    put(2, 50, 0.0, settings={**settings, "learning_rate": 0.5})  # other PPO settings: left out too
    md, _ = sample_complexity_section(tmp_path, tmp_path / "report", plan=plan)
    assert "Left out: 3 result(s)" in md
    # without a plan every result counts (a run folder read on its own)
    md, _ = sample_complexity_section(tmp_path, tmp_path / "report")
    assert next(line for line in md.splitlines() if line.startswith("| multiroom | rl-scratch |")).split("|")[3].strip() == "4"
    # the plan a report uses is read from the suite file's copy without resolving its bases
    (tmp_path / "suite.yaml").write_text("entries: {a: {base: ../nowhere.yaml}}\n"
                                         "rl: {tasks: {multiroom: [1, 2]}, seeds: [0], trajectories: 50}\n")
    assert plan_of_copy(tmp_path / "suite.yaml") == plan and plan_of_copy(tmp_path / "none.yaml") is None


def test_a_changed_budget_or_task_list_makes_a_written_result_stale(tmp_path):
    """The budget is not in a result's file name and the task list not in an attempts set's: both
    are compared with the plan, so changing either runs the job again instead of counting it done."""
    import dataclasses

    from gpl_dist.app.suite.rl.jobs import attempts_current, is_current, write_result
    from gpl_dist.app.suite.rl.per_task import RLCurve
    from gpl_dist.app.suite.rl.plan import AttemptsJob, parse_rl_plan

    plan = parse_rl_plan("t", {"tasks": {"multiroom": [1, 2]}, "seeds": [0], "trajectories": 50}, ("gpl",))
    settings = plan.settings("multiroom")
    curve = RLCurve(RLJob("rl-scratch", "multiroom", 1, 0, 50), (1.0,) * 50, (True,) * 50, 1, 1.0)
    write_result(tmp_path, curve.job.key, {**curve.to_json(), "settings": dataclasses.asdict(settings)})
    assert is_current(tmp_path, curve.job, settings)
    assert not is_current(tmp_path, dataclasses.replace(curve.job, trajectories=80), settings)
    points = AttemptsJob("gpl", "multiroom", 0)
    write_result(tmp_path, points.key, {"entry": "gpl", "domain": "multiroom", "seed": 0, "tasks": [1, 2]})
    assert attempts_current(tmp_path, points, plan)  # "gpl" is not trained here: what is written stays
    wider = parse_rl_plan("t", {"tasks": {"multiroom": [1, 2, 3]}, "seeds": [0], "trajectories": 50}, ("gpl",))
    assert not attempts_current(tmp_path, points, wider)


def test_rl_reaches_gpl_against_gpls_median_on_the_same_tasks_and_missing_jobs_are_named(tmp_path):
    """With RL on 2 of 3 tasks, the bar is GPL's median on those 2 (0.30), not on all 3 (0.40)."""
    import dataclasses

    from gpl_dist.app.suite.rl.jobs import write_result
    from gpl_dist.app.suite.rl.per_task import RLCurve
    from gpl_dist.app.suite.rl.plan import parse_rl_plan
    from gpl_dist.app.suite.rl.report import sample_complexity_section

    plan = parse_rl_plan("t", {"tasks": {"multiroom": [1, 2, 3]}, "seeds": [0], "trajectories": 40,
                               "attempts_from": {"multiroom": ["gpl"]}}, ("gpl",))
    settings = dataclasses.asdict(plan.settings("multiroom"))
    last = {1: 0.2, 2: 0.4, 3: 1.0}  # GPL after 5 corrections, per task
    write_result(tmp_path, "attempts/gpl-seed0", {
        "entry": "gpl", "domain": "multiroom", "seed": 0, "variant": "gpl", "tasks": [1, 2, 3],
        "completion": [[0.0] * 5 + [last[t]] for t in (1, 2, 3)]})
    for task in (1, 2):
        curve = RLCurve(RLJob("rl-scratch", "multiroom", task, 0, 40), (0.35,) * 40, (False,) * 40, 1, 1.0)
        write_result(tmp_path, curve.job.key, {**curve.to_json(), "settings": settings})
    md, _ = sample_complexity_section(tmp_path, tmp_path / "report", plan=plan)
    row = next(line for line in md.splitlines() if line.startswith("| multiroom | rl-scratch |")).split("|")
    assert row[-3].strip() == "1 (GPL: 0.30)", row
    assert "Not run yet" in md and "multiroom rl-scratch: 1 of 3" in md and "gpl: 0 of" not in md
