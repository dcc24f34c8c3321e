"""The learned relocation expert: packaged weights, labels, the export from torch, selection by config."""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from gpl_dist.config import config_from_dict
from gpl_dist.domains import get_domain
from gpl_dist.envs.relocation import make_env
from gpl_dist.experts import make_expert
from gpl_dist.experts.relocation import RelocationExpert
from gpl_dist.experts.relocation_learned import LearnedRelocationExpert, action_probs, load_weights, policy_inputs
from gpl_dist.splits import split_tasks
from tests.test_rollout import worker_settings
from workers.worker import RolloutWorker

ROOT = Path(__file__).resolve().parents[1]


def _module(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _small(script, iterations: int):
    """Step 2 on 2 envs, one warm-up iteration, no valid-split completion in between, 4 minibatches per epoch."""
    return script.FinetuneSettings(ppo=replace(script.EXPERT_PPO, n_envs=2, batch_size=175), iterations=iterations,
                                   warmup=1, eval_every=100, valid_tasks=1)


def test_packaged_weights_load_without_pickle_and_give_distributions():
    w = load_weights()
    assert w["w0"].shape == (256, 33) and w["w3"].shape == (4, 256) and w["norm_var"].min() > 0
    env = make_env(split_tasks("relocation", "test")[0])
    env.reset(seed=5)
    expert = make_expert(env, "learned")
    assert isinstance(expert, LearnedRelocationExpert) and expert.soft_labels
    action, probs = expert.label(env)
    assert probs.dtype == np.float32 and probs.shape == (4,) and abs(float(probs.sum()) - 1.0) < 1e-5
    assert action == int(np.argmax(probs)) == expert.act(env)
    again = LearnedRelocationExpert().label(env)
    assert again[0] == action and np.array_equal(again[1], probs)  # stateless: same state, same label


def test_export_round_trip_matches_the_torch_policy(tmp_path):
    """``relocation_expert_training.export`` writes what ``action_probs`` computes like torch."""
    from learner import relocation_expert_training as script
    torch.manual_seed(0)
    policy = script.build_policy(33, 256)
    with torch.no_grad():
        policy[0].running_mean.uniform_(-1, 1)
        policy[0].running_var.uniform_(0.5, 2.0)
        policy[0].weight.uniform_(0.5, 1.5)
    policy.eval()
    path = tmp_path / "expert.npz"
    script.export(policy, str(path))
    with np.load(path, allow_pickle=False) as raw:
        weights = {k: raw[k].astype(np.float64) for k in raw.files}
    x = np.random.default_rng(0).normal(size=(16, 33))
    with torch.no_grad():
        expected = torch.softmax(policy(torch.from_numpy(x.astype(np.float32))), 1).numpy()
    np.testing.assert_allclose(action_probs(weights, x), expected, atol=1e-5)


def test_policy_inputs_are_the_observation_target_and_block():
    env = make_env(split_tasks("relocation", "train")[3])
    obs, _ = env.reset(seed=1)
    for a in (2, 2, 0, 1):
        obs, *_ = env.step(a)
    x = policy_inputs(env)
    np.testing.assert_allclose(x[:28], obs, atol=1e-6)
    assert tuple(x[28:30]) == env.task.target and x[30 + env.task.block] == 1.0 and x[30:33].sum() == 1.0


def test_training_reads_the_packaged_experts_inputs_in_float32():
    """One builder of the 33 values: the training's inputs (from the env's float32 observation)
    are the packaged expert's (from the simulator's float64 state) cast to float32, bit for bit,
    in a batch and one episode at a time (step 2's env)."""
    from gpl_dist.experts.relocation_learned import policy_inputs_batch
    from learner.relocation_expert_training import PrivilegedTasks, privileged_inputs, task_targets

    tasks = split_tasks("relocation", "train")[:5]
    envs = [make_env(t) for t in tasks]
    obs = np.stack([e.reset(seed=k)[0] for k, e in enumerate(envs)])
    for a in (2, 2, 0, 1, 3):
        obs = np.stack([e.step(a)[0] for e in envs])
    targets, blocks = task_targets(tasks)
    x = privileged_inputs(obs.astype(np.float32), targets, blocks)
    assert x.dtype == np.float32 and x.tobytes() == policy_inputs_batch(envs).astype(np.float32).tobytes()
    one = PrivilegedTasks(tasks, seed=0)
    first, _ = one.reset()
    assert first.tobytes() == policy_inputs(one.env).astype(np.float32).tobytes()
    stepped = one.step(1)[0]
    assert stepped.tobytes() == policy_inputs(one.env).astype(np.float32).tobytes()


def test_learned_expert_solves_tasks_on_its_own():
    """Its own (argmax) actions on the first 3 test tasks: at least 0.8 mean completion."""
    expert = LearnedRelocationExpert()
    completions = []
    for task in split_tasks("relocation", "test")[:3]:
        env = make_env(task)
        env.reset(seed=99_999)
        for _ in range(350):
            env.step(expert.act(env))
        completions.append(env.completion())
    assert np.mean(completions) >= 0.8, completions


def test_unknown_expert_kinds_fail_with_the_known_ones(tmp_path):
    env = make_env(0)
    with pytest.raises(ValueError, match=r"unknown expert 'ppo' for relocation \(known: scripted, learned\)"):
        make_expert(env, "ppo")
    assert isinstance(make_expert(env), RelocationExpert)  # scripted stays the default
    # a domain-foreign expert fails when the config is read, before any run could start
    with pytest.raises(ValueError, match=r"env.expert must be one of scripted for multiroom, got 'learned'"):
        config_from_dict({"env": {"domain": "multiroom", "expert": "learned"}})
    assert config_from_dict({"env": {"domain": "relocation", "expert": "learned"}}).env.expert == "learned"


def test_worker_labels_with_the_configured_expert():
    settings = worker_settings("relocation", num_corrections=0, expert="learned")
    worker = RolloutWorker(get_domain("relocation"), settings, worker_id="t")
    attempts = worker.collect(tuple(split_tasks("relocation", "train")[:2]), "train", 0)
    assert len(attempts) == 2
    for a in attempts:
        assert a.expert_probs is not None and a.expert_probs.shape == (len(a.actions), 4)
        np.testing.assert_allclose(a.expert_probs.sum(1), 1.0, atol=1e-5)
        assert np.array_equal(a.expert_actions, a.expert_probs.argmax(1))


def test_training_script_runs_ppo_and_exports(tmp_path, capsys, monkeypatch):
    """Two PPO iterations (one critic-only) from a saved policy on 4 tasks; the export loads; the
    printed completions read the valid split, and nothing in the step reads the test split."""
    from learner import relocation_expert_training as training

    script = _module(ROOT / "scripts" / "train_relocation_expert.py")
    read: list[str] = []

    def recorded(domain, split):
        read.append(split)
        return split_tasks(domain, split)

    monkeypatch.setattr(training, "split_tasks", recorded)
    torch.manual_seed(1)
    init, out = tmp_path / "init.pt", tmp_path / "expert.npz"
    torch.save(script.build_policy(33, 256).state_dict(), init)
    script.main(["--threads", "1", "ppo", "--init", str(init), "--out", str(out), "--iterations", "2", "--n-envs", "4",
                 "--warmup", "1", "--eval-every", "2", "--test-tasks", "2", "--minibatch", "256"])  # former names too
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("start: valid completion") and lines[-1].startswith("end: valid completion")
    assert lines[1].startswith("iteration 0:")  # the critic warm-up (no policy step: the test below checks)
    assert lines[2].startswith("iteration 1:") and "valid completion" in lines[2]
    assert "valid" in read and "test" not in read
    start = torch.load(init, weights_only=True)
    with np.load(out, allow_pickle=False) as raw:
        assert sorted(raw.files) == sorted(["norm_mean", "norm_var", "norm_weight", "norm_bias",
                                            *(f"w{i}" for i in range(4)), *(f"b{i}" for i in range(4))])
        np.testing.assert_array_equal(raw["norm_mean"], start["0.running_mean"].numpy())  # frozen statistics
        assert not np.array_equal(raw["w0"], start["1.weight"].numpy())  # iteration 1 moved the policy
    assert torch.load(f"{out}.ckpt.pt", weights_only=True)["iteration"] == 2
    with pytest.raises(SystemExit, match="exists: pass --resume"):  # not over a run's checkpoint unasked
        script.main(["ppo", "--init", str(init), "--out", str(out)])


def test_the_experts_ppo_stage_is_sb3_starting_from_the_dagger_policy():
    """Step 2 runs stable-baselines3's PPO: its policy starts as step 1's exactly, the input
    normalisation keeps step 1's statistics, the value layers alone train during the warm-up,
    and the policy moves after it."""
    from learner import relocation_expert_training as script
    torch.manual_seed(0)
    policy = script.build_policy(33, 32)
    with torch.no_grad():
        policy[0].running_mean.uniform_(-1, 1)
    policy.eval()
    settings = _small(script, iterations=2)
    model = script.sb3_ppo(policy, settings)
    x = torch.randn(7, 33)
    model.policy.set_training_mode(False)
    with torch.no_grad():
        assert torch.allclose(model.policy.get_distribution(x).distribution.logits, torch.log_softmax(policy(x), 1), atol=1e-5)
    lines: list[str] = []
    once = script.ppo_finetune(policy, replace(settings, iterations=1), lines.append)
    assert all(torch.equal(a, b) for a, b in zip(once.parameters(), policy.parameters()))  # warm-up: value layers only
    tuned = script.ppo_finetune(policy, settings, lines.append)
    assert any(not torch.equal(a, b) for a, b in zip(tuned.parameters(), policy.parameters()))
    assert torch.equal(tuned[0].running_mean, policy[0].running_mean)
    assert lines[0].startswith("start: valid completion") and lines[-1].startswith("end: valid completion")


def _whole_and_stopped(script, tmp_path):
    """A small policy, 3-iteration settings, and the checkpoints of a run never stopped (``whole``,
    3 iterations) and of one stopped after 2 (``stopped``)."""
    torch.manual_seed(0)
    policy = script.build_policy(33, 32).eval()
    settings = _small(script, iterations=3)
    whole, stopped = str(tmp_path / "whole.pt"), str(tmp_path / "stopped.pt")
    script.ppo_finetune(policy, settings, lambda _: None, checkpoint=whole)
    script.ppo_finetune(policy, replace(settings, iterations=2), lambda _: None, checkpoint=stopped)
    return policy, settings, whole, stopped


def test_the_experts_ppo_stage_resumed_from_its_checkpoint_ends_as_a_run_never_stopped(tmp_path):
    """Two iterations, stopped, then resumed to three: the checkpoint after the third (SB3's whole
    policy with the value layers, Adam's state, the generators) equals an unstopped run's, and the
    third iteration moved the policy."""
    from learner import relocation_expert_training as script
    policy, settings, whole, stopped = _whole_and_stopped(script, tmp_path)
    after_two = torch.load(stopped, weights_only=True)
    lines: list[str] = []
    script.ppo_finetune(policy, settings, lines.append, checkpoint=stopped, resume=True)
    assert lines[0] == f"resumed after iteration 1 from {stopped}" and lines[1].startswith("iteration 2:")
    a, b = torch.load(whole, weights_only=True), torch.load(stopped, weights_only=True)
    assert a["iteration"] == b["iteration"] == 3 and after_two["iteration"] == 2
    for name in a["policy"]:
        assert torch.equal(a["policy"][name], b["policy"][name]), name
    assert torch.equal(a["torch_rng"], b["torch_rng"]) and a["env_rngs"] == b["env_rngs"]
    moved = [n for n in a["policy"] if not torch.equal(a["policy"][n], after_two["policy"][n])]
    assert any(n.startswith("mlp_extractor.policy_net") for n in moved)
    faster = replace(settings, ppo=replace(settings.ppo, learning_rate=1e-3))
    with pytest.raises(ValueError, match="other settings: ppo.learning_rate 5e-05 \\(now 0.001\\)"):
        script.ppo_finetune(policy, faster, lambda _: None, checkpoint=stopped, resume=True)
    with pytest.raises(ValueError, match="another policy"):
        script.ppo_finetune(script.build_policy(33, 32).eval(), settings, lambda _: None, checkpoint=stopped, resume=True)


def test_a_checkpoint_with_the_former_setting_names_resumes_to_the_same_result(tmp_path):
    """A format-1 checkpoint (settings named ``envs``, ``lr``, ``critic_lr``, ``clip``, ``epochs``,
    ``minibatch``, ``max_kl`` = 1.5 x SB3's ``target_kl``) resumes as its format-2 twin; another
    format is refused by name."""
    from learner import relocation_expert_training as script
    policy, settings, whole, stopped = _whole_and_stopped(script, tmp_path)
    state = torch.load(stopped, weights_only=True)
    assert state["format"] == script.CHECKPOINT_FORMAT == 2 and state["settings"]["ppo.learning_rate"] == 5e-5
    p = settings.ppo
    old = {"envs": p.n_envs, "lr": p.learning_rate, "critic_lr": p.value_learning_rate, "clip": p.clip_range,
           "epochs": p.n_epochs, "minibatch": p.batch_size, "warmup": settings.warmup, "gamma": p.gamma,
           "gae_lambda": p.gae_lambda, "return_scale": settings.return_scale, "max_kl": 0.02, "seed": settings.seed}
    torch.save({**state, "format": 1, "settings": old}, stopped)
    script.ppo_finetune(policy, settings, lambda _: None, checkpoint=stopped, resume=True)
    a, b = torch.load(whole, weights_only=True), torch.load(stopped, weights_only=True)
    assert b["format"] == 2 and a["iteration"] == b["iteration"] == 3
    assert all(torch.equal(a["policy"][name], b["policy"][name]) for name in a["policy"])
    torch.save({**state, "format": 1, "settings": {**old, "critic_lr": 1e-4}}, stopped)
    with pytest.raises(ValueError, match="other settings: ppo.value_learning_rate 0.0001 \\(now 0.001\\)"):
        script.ppo_finetune(policy, settings, lambda _: None, checkpoint=stopped, resume=True)
    torch.save({**state, "format": 7}, stopped)
    with pytest.raises(ValueError, match="checkpoint format 7; this code reads 1 and 2"):
        script.ppo_finetune(policy, settings, lambda _: None, checkpoint=stopped, resume=True)


def test_the_ppo_stage_envs_hold_only_their_current_episodes_env():
    """Each of step 2's envs keeps no env of an earlier episode (one per task drawn grew to 24 GB)."""
    import gc
    import weakref

    from learner.relocation_expert_training import PrivilegedTasks
    tasks = PrivilegedTasks(split_tasks("relocation", "train")[:50], seed=0)
    tasks.reset()
    first = weakref.ref(tasks.env)
    for _ in range(3):
        tasks.reset()
    gc.collect()
    assert first() is None and tasks.env is not None
