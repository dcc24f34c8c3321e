"""The learner's optimiser over flattened parameters, its batch prefetching and its determinism."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from gpl_dist.config import TrainingConfig
from gpl_dist.domains import get_domain
from gpl_dist.models.build import build_model, state_dict_to_numpy
from gpl_dist.records import WorkUnit
from learner.batches import TensorView
from learner.trainer import Learner
from storage import BufferReader, ShardWriter, commit_round
from tests.test_rollout import make_worker


def _view(tmp_path, rounds=1, task_ids=(1, 2, 3)):
    """A buffer of real multi-room attempts (an untrained policy, 3 tasks, 2 corrections)."""
    root = tmp_path / "run"
    writer = ShardWriter(root, "r")
    worker = make_worker("multiroom", num_corrections=2)
    for r in range(rounds):
        unit = WorkUnit(round_index=r, unit_index=0, task_ids=tuple(task_ids), split="train", seed=r, policy_version=0)
        attempts = worker.collect(unit.task_ids, unit.split, seed=unit.seed, round_index=r)
        commit_round(root, r, [writer.write_unit(unit, attempts, worker_id="w")])
    return BufferReader(root).load_training_view(trajectory_stride=get_domain("multiroom").trajectory_stride)


def _cfg(**kw):
    """One CPU thread: these tests check bitwise properties (a GPU sums in a different order each
    run; test_a_round_on_every_device_here_matches_the_cpu covers the GPU)."""
    return TrainingConfig(**{"num_epochs_per_round": 1, "batch_size": 64, "num_threads": 1, "device": "cpu", **kw})


def test_parameters_are_views_of_one_flat_tensor_and_train(tmp_path):
    view = _view(tmp_path)
    learner = Learner(build_model(get_domain("multiroom"), seed=0), _cfg())
    flat = learner.flat_parameters
    params = list(learner.model.parameters())
    assert flat.numel() == sum(p.numel() for p in params)
    for p in params:
        assert p.untyped_storage().data_ptr() == flat.untyped_storage().data_ptr()
        assert p.grad.untyped_storage().data_ptr() == learner.flat_grads.untyped_storage().data_ptr()
    before = state_dict_to_numpy(learner.model)
    learner.train_round(view)
    after = state_dict_to_numpy(learner.model)
    assert all(not np.array_equal(before[k], after[k]) for k in before)  # every tensor was updated
    # a fresh model loads the trained values (state_dict copies out of the flat storage)
    fresh = build_model(get_domain("multiroom"))
    fresh.load_state_dict(learner.model.state_dict())
    assert all(torch.equal(a, b.cpu()) for a, b in zip(fresh.state_dict().values(), learner.model.state_dict().values()))


def test_training_is_deterministic(tmp_path):
    view = _view(tmp_path, rounds=2)
    runs = []
    for _ in range(2):
        learner = Learner(build_model(get_domain("multiroom"), seed=3), _cfg(num_epochs_per_round=2), seed=5)
        stats = learner.train_round(view)
        runs.append((stats, state_dict_to_numpy(learner.model)))
    (s1, w1), (s2, w2) = runs
    assert s1.loss == s2.loss and s1.num_steps == s2.num_steps == 2 * -(-view.num_tuples // 64)
    assert all(np.array_equal(w1[k], w2[k]) for k in w1)


def test_prefetched_batches_train_exactly_as_batches_built_in_line(tmp_path):
    """The round's batches are built on a second thread: the weights and the loss are bitwise those
    of stepping through the same epoch order with batches built in line, one after another."""
    tv = TensorView.from_view(_view(tmp_path, rounds=2))
    cfg = _cfg(num_epochs_per_round=2, batch_size=48)
    ahead = Learner(build_model(get_domain("multiroom"), seed=3), cfg, seed=5)
    stats = ahead.train_round(tv)
    inline = Learner(build_model(get_domain("multiroom"), seed=3), cfg, seed=5)
    inline.model.train()
    losses = []
    for _ in range(cfg.num_epochs_per_round):
        order = inline._epoch_order(tv)
        losses = [inline.step(tv, idx) for idx in order.split(cfg.batch_size) if idx.numel() >= 2]
    assert stats.num_steps == 2 * len(losses) > 4
    last_epoch = sum(loss * n for (loss, _), n in zip(losses, [i.numel() for i in order.split(48) if i.numel() >= 2]))
    assert stats.loss == pytest.approx(last_epoch / tv.num_states, rel=1e-6)  # summed in float32 products there
    w_ahead, w_inline = state_dict_to_numpy(ahead.model), state_dict_to_numpy(inline.model)
    assert all(np.array_equal(w_ahead[k], w_inline[k]) for k in w_ahead)  # BatchNorm statistics too
    ahead.close()
    assert ahead._builder is None


def test_a_batch_indexed_from_the_host_equals_one_indexed_where_the_view_lives(tmp_path):
    """A view on a GPU builds each batch's index structure from host copies (``host_index``):
    the batch is the same as one indexed in place (here both on the CPU, the path the GPU takes)."""
    tv = TensorView.from_view(_view(tmp_path, rounds=2))
    hosted = dataclasses.replace(tv, host_index=(tv.attempt_rows.clone(), tv.context_rows.clone()))
    idx = torch.randperm(tv.num_states, generator=torch.Generator().manual_seed(1))[:40]
    (o1, l1, c1, r1), (o2, l2, c2, r2) = tv.batch(idx), hosted.batch(idx)
    assert c1.trajectories.shape[0] > 0  # the batch has earlier attempts to index
    assert torch.equal(o1, o2) and torch.equal(l1, l2) and torch.equal(r1, r2)
    for f in ("instruction_ids", "trajectories", "correction_ids", "slots", "correction_values"):
        a, b = getattr(c1, f), getattr(c2, f)
        assert a is not None and torch.equal(a, b), f


def test_correction_spread_reports_a_dead_correction_module(tmp_path):
    from learner.batches import TensorView
    from learner.driver import format_round
    from learner.rounds import RoundMetrics

    tv = TensorView.from_view(_view(tmp_path))
    learner = Learner(build_model(get_domain("multiroom"), seed=0), _cfg())
    cond = tv.batch(torch.arange(tv.num_states))[2]
    assert learner.correction_spread(cond) > 0  # a live module: attempts' summaries differ
    with torch.no_grad():  # every unit of the pair MLP's last layer dead (as happened in a relocation run)
        last = learner.model.pair[-2]
        last.weight.zero_()
        last.bias.fill_(-1.0)
    assert learner.correction_spread(cond) == 0.0
    line = format_round(RoundMetrics(round_index=3, collected_tuples=10, failed_tasks=(), collection_seconds=1.0,
                                     load_seconds=0.1, completion_by_corrections=(0.1,), buffer_tuples=10, loss=1.0,
                                     accuracy=0.5, train_seconds=1.0, train_steps=1, correction_spread=0.0))
    assert "cannot use corrections" in line
    no_corrections = Learner(build_model(get_domain("multiroom"), "instruction_only", seed=0), _cfg())
    assert no_corrections.correction_spread(cond) is None


def test_encoder_health_counts_dead_units_and_the_round_line_warns_of_a_dead_encoding(tmp_path):
    from learner.batches import TensorView
    from learner.driver import format_round
    from learner.health import encoder_health
    from learner.rounds import RoundMetrics

    tv = TensorView.from_view(_view(tmp_path))
    learner = Learner(build_model(get_domain("multiroom"), seed=0), _cfg())
    stats = learner.train_round(tv)
    health = {h.encoder: h for h in stats.encoder_health}
    assert set(health) == {"instruction", "correction", "trajectory", "pair"}
    sizes = get_domain("multiroom").model_sizes  # ReLU units: the MLP layers (the trajectory's state MLP too)
    assert health["correction"].units == sum(sizes.correction_mlp) and health["correction"].output_units == 4
    assert health["trajectory"].units == sum(sizes.traj_state_mlp) + sum(sizes.traj_mlp)
    assert not any(h.output_dead for h in health.values())
    with torch.no_grad():  # the correction encoding dies whole, as in multi-room suite seed 3's round 0
        last = learner.model.correction.mlp[-2]
        last.weight.zero_()
        last.bias.fill_(-1.0)
    cond = tv.batch(torch.arange(tv.num_states))[2]
    dead = {h.encoder: h for h in encoder_health(learner.model, cond)}
    assert dead["correction"].output_dead and dead["correction"].dead_output_units == 4
    assert dead["instruction"] == health["instruction"]  # the other encoders are counted as before
    assert learner.model.training is False  # the count leaves the model's mode as it was
    m = RoundMetrics(round_index=0, collected_tuples=10, failed_tasks=(), collection_seconds=1.0, load_seconds=0.1,
                     completion_by_corrections=(0.1,), buffer_tuples=10, loss=1.0, accuracy=0.5, train_seconds=1.0,
                     train_steps=1, correction_spread=1.0, encoder_health=tuple(dead.values()))
    line = format_round(m)
    assert f"c {dead['correction'].dead_units}/20" in line.split("|")[0]
    assert "all 4 output units of the correction encoder are dead" in line
    assert RoundMetrics.from_dict(json.loads(json.dumps(m.to_dict()))) == m  # metrics.jsonl round trip
    assert dead["correction"].constant and dead["correction"].dead_layers >= 1
    # a linear encoding has no ReLU output to die, but it is constant once a hidden layer dies whole
    # (the instruction encoder of two multi-room seeds with the shipped network)
    linear = Learner(build_model(get_domain("multiroom"), seed=0, linear_encodings=True), _cfg())
    assert all(h.output_units == 0 for h in encoder_health(linear.model, cond))
    with torch.no_grad():
        hidden = linear.model.instruction.mlp[0]
        hidden.weight.zero_()
        hidden.bias.fill_(-1.0)
    instruction = {h.encoder: h for h in encoder_health(linear.model, cond)}["instruction"]
    assert instruction.constant and not instruction.output_dead and instruction.dead_units >= 16
    warned = format_round(dataclasses.replace(m, encoder_health=(instruction,)))
    assert "every unit of a hidden layer of the instruction encoder is dead" in warned
    # an input constant by design (the retry control's correction) is noted, not warned about
    noted = format_round(dataclasses.replace(m, encoder_health=(dataclasses.replace(instruction, encoder="correction"),)),
                         ("correction",))
    assert "warning" not in noted and "constant by design" in noted


def test_mivoa_health_counts_constant_lstm_units_and_a_mivoa_round_records_it(tmp_path):
    """MIVOA's LSTM has no never-positive units: a unit of its instruction vector is dead when it is
    the same for every instruction of the probe, and the vector dead whole is a dead layer."""
    from learner.driver import format_round
    from learner.health import encoder_health
    from learner.rounds import RoundMetrics

    tv = TensorView.from_view(_view(tmp_path, task_ids=(1, 40, 200, 700)), previous_steps=True)  # 4 instructions
    mivoa = Learner(build_model(get_domain("multiroom"), "mivoa", seed=0), _cfg())
    stats = mivoa.train_round(tv)
    (health,) = stats.encoder_health
    hidden = get_domain("multiroom").model_sizes.instruction_mlp[-1]
    assert (health.encoder, health.units, health.output_units) == ("instruction", hidden, hidden)
    assert health.dead_units < hidden and not health.constant
    cond = tv.batch(torch.arange(tv.num_states))[2]
    with torch.no_grad():  # the output gate shut for every word: h = o * tanh(c) = 0 whatever the words
        lstm = mivoa.model.instruction.lstm
        lstm.weight_ih_l0[3 * hidden:].zero_()
        lstm.weight_hh_l0[3 * hidden:].zero_()
        lstm.bias_ih_l0[3 * hidden:].fill_(-1e4)
    (dead,) = encoder_health(mivoa.model, cond)
    assert dead.dead_units == hidden and dead.output_dead and dead.constant and dead.dead_layers == 1
    with torch.no_grad():  # one unit's output gate open again: that unit varies, the others stay dead
        lstm.bias_ih_l0[3 * hidden].fill_(0.0)
        lstm.weight_ih_l0[3 * hidden].normal_()
    (one,) = encoder_health(mivoa.model, cond)
    assert one.dead_units == hidden - 1 and not one.constant
    m = RoundMetrics(round_index=0, collected_tuples=10, failed_tasks=(), collection_seconds=1.0, load_seconds=0.1,
                     completion_by_corrections=(0.1,), buffer_tuples=10, loss=1.0, accuracy=0.5, train_seconds=1.0,
                     train_steps=1, correction_spread=None, encoder_health=(dead,))
    assert f"all {hidden} output units of the instruction encoder are dead" in format_round(m)


@pytest.mark.parametrize("domain_name,tasks,end_aligned", [("multiroom", (1, 2, 3), False), ("relocation", (0, 7), True),
                                                         ("multiroom", (1, 2, 3), True)])
def test_learner_conditions_on_what_the_worker_acted_on(tmp_path, domain_name, tasks, end_aligned):
    """Collection and training build each attempt's conditioning alike (same trajectory samples).

    The worker's own model records the conditioning of every attempt it rolls out; the learner's
    batch of the stored tuples, read back from the buffer with the same anchoring, must encode
    to the same vectors.
    """
    domain = get_domain(domain_name)
    worker = make_worker(domain_name, num_corrections=2, trajectory_ends_at_last_state=end_aligned)
    seen: list[torch.Tensor] = []
    encode = worker.model.encode_conditioning
    worker.model.encode_conditioning = lambda cond: seen.append(encode(cond)) or seen[-1]
    unit = WorkUnit(round_index=0, unit_index=0, task_ids=tasks, split="train", seed=3, policy_version=0)
    attempts = worker.collect(unit.task_ids, unit.split, seed=unit.seed, round_index=0)
    assert len(seen) == 1 + max(a.attempt_index for a in attempts) and len(seen) > 1
    # call k conditioned the tasks that made an attempt k, in task order
    z_worker = {}
    for k, z in enumerate(seen):
        active = [a.task_id for a in attempts if a.attempt_index == k]
        assert z.shape[0] == len(active)
        z_worker.update({(t, k): z[j] for j, t in enumerate(active)})

    root = tmp_path / "run"
    commit_round(root, 0, [ShardWriter(root, "r").write_unit(unit, attempts, worker_id="w")])
    view = BufferReader(root).load_training_view(10**9, domain.trajectory_stride, end_aligned)
    assert view.trajectories.shape[1] == domain.trajectory_samples
    tv = TensorView.from_view(view)
    first_states = torch.from_numpy(np.flatnonzero(view.timesteps == 0))
    _, _, cond, rows = tv.batch(first_states)
    with torch.inference_mode():
        z_learner = encode(cond)
    for n, state in enumerate(first_states.tolist()):
        a = view.attempt_rows[state]
        key = (int(view.task_id[a]), int(view.attempt_index[a]))
        torch.testing.assert_close(z_learner[rows[n]], z_worker[key], rtol=0, atol=1e-6)
    last_states = view.observations[view.timesteps == domain.steps_per_attempt - 1]
    assert np.array_equal(view.trajectories[:, -1], last_states) == end_aligned


def test_a_round_on_every_device_here_matches_the_cpu(tmp_path):
    """On a GPU machine the view moves to the GPU once and a round there follows the CPU's (up to
    the GPU's float32 convolutions); on a CPU machine ``TensorView.to`` round-trips exactly."""
    tv = TensorView.from_view(_view(tmp_path, rounds=2))
    assert tv.to(torch.device("cpu")) is tv
    assert tv.nbytes == sum(getattr(tv, f).nbytes for f in ("observations", "expert_actions", "attempt_rows",
                                                             "instruction_ids", "correction_ids", "context_rows",
                                                             "trajectories", "attempt_task_ids", "attempt_rewards"))
    results = {}
    for device in ["cpu"] + (["cuda"] if torch.cuda.is_available() else []):
        learner = Learner(build_model(get_domain("multiroom"), seed=0), _cfg(device=device, num_epochs_per_round=2))
        assert learner._on_device(tv).observations.device.type == device
        stats = learner.train_round(tv)
        results[device] = (stats.loss, stats.accuracy, state_dict_to_numpy(learner.model))
    for device, (loss, accuracy, weights) in results.items():
        assert loss == pytest.approx(results["cpu"][0], rel=1e-3)
        assert accuracy == pytest.approx(results["cpu"][1], abs=0.02)
        for k, w in weights.items():
            np.testing.assert_allclose(w, results["cpu"][2][k], rtol=0, atol=2e-3, err_msg=f"{device}: {k}")


def test_previous_steps_of_a_view_follow_each_attempt(tmp_path):
    view = _view(tmp_path, rounds=2)
    assert TensorView.from_view(view).previous_rows is None  # found only for a model that reads them
    tv = TensorView.from_view(view, previous_steps=True)
    prev, actions = tv.previous_rows.numpy(), tv.previous_actions.numpy()
    t, rows = view.timesteps, view.attempt_rows
    first = t == 0
    assert (prev[first] == np.flatnonzero(first)).all() and (actions[first] == -1).all()
    later = np.flatnonzero(~first)
    assert later.size and (rows[prev[later]] == rows[later]).all() and (t[prev[later]] == t[later] - 1).all()
    assert (actions[later] == view.actions[prev[later]]).all()
    shuffled = np.random.default_rng(0).permutation(view.num_tuples)  # any order of states gives the same steps
    idx = torch.from_numpy(shuffled[:50])
    step = tv.previous(idx)
    assert torch.equal(step.observations, tv.observations[tv.previous_rows[idx]])


@pytest.mark.parametrize("domain_name", ["multiroom", "relocation"])
def test_baselines_train_and_are_evaluated_through_the_one_rollout_loop(tmp_path, domain_name):
    """MIVOA (instruction and full information), the full-information baseline (relocation's as
    numbers) and GPR collect, train and meta-test serially: the baselines one attempt per task;
    MIVOA's previous step, relocation's numbers and GPR's summed rewards are read in every stage
    (the models raise without them)."""
    from gpl_dist.config import load_config
    from learner.driver import run_training
    from learner.evaluate import evaluate_run

    base = "multiroom-smoke.yaml" if domain_name == "multiroom" else "relocation.yaml"
    for variant in ("mivoa", "mivoa_full_information", "full_information", "gpr"):
        cfg = load_config(Path(__file__).resolve().parent.parent / "configs" / base, {
            "model.variant": variant, "training.num_rounds": "2", "env.max_train_tasks": "3", "collection.num_workers": "1",
            "training.num_epochs_per_round": "1", "eval.max_tasks": "2", "eval.seeds": "[0]", "buffer.capacity_tuples": "100000"})
        run = tmp_path / variant
        result = run_training(cfg, run, serial=True, progress=False)
        assert [m.round_index for m in result.history] == [0, 1] and all(np.isfinite(m.loss) for m in result.history)
        if variant != "gpr":
            assert all(len(m.completion_by_corrections) == 1 for m in result.history)  # one attempt per task
        evaluation, _ = evaluate_run(run)
        # a method without corrections makes one attempt per task: one completion figure
        assert evaluation.num_tasks == 2 and len(evaluation.completion) == (1 if variant != "gpr" else 6)
        view = BufferReader(run / "buffer").load_training_view()
        assert view.reward_sum.shape == view.completion.shape and np.isfinite(view.reward_sum).all()


@pytest.mark.parametrize("domain_name,variant", [("multiroom", "gpl"), ("multiroom", "gpr"), ("relocation", "gpr"),
                                                 ("relocation", "full_information"), ("multiroom", "mivoa"),
                                                 ("relocation", "mivoa"), ("multiroom", "mivoa_full_information")])
def test_the_learner_feeds_every_method_what_the_worker_acted_on(tmp_path, domain_name, variant):
    """Per state, the logits the worker acted with equal the logits of the learner's batch of the
    stored tuples (through ``Learner``'s own input preparation): the same conditioning, summed
    rewards, numeric full information and previous steps in collection and in training."""
    domain = get_domain(domain_name)
    worker = make_worker(domain_name, num_corrections=2, variant=variant,
                         trajectory_ends_at_last_state=domain_name == "relocation")
    acted: list[torch.Tensor] = []
    act = worker.model.action_logits
    worker.model.action_logits = lambda obs, z, previous=None: acted.append(act(obs, z, previous)) or acted[-1]
    tasks = (1, 2, 3)
    unit = WorkUnit(round_index=0, unit_index=0, task_ids=tasks, split="train", seed=5, policy_version=0)
    attempts = worker.collect(unit.task_ids, unit.split, seed=unit.seed, round_index=0)
    steps = domain.steps_per_attempt
    logits_worker = {}
    for k in range(1 + max(a.attempt_index for a in attempts)):
        active = [a.task_id for a in attempts if a.attempt_index == k]
        for t in range(steps):
            for j, task in enumerate(active):
                logits_worker[(task, k, t)] = acted[k * steps + t][j]

    root = tmp_path / "run"
    commit_round(root, 0, [ShardWriter(root, "r").write_unit(unit, attempts, worker_id="w")])
    view = BufferReader(root).load_training_view(10**9, domain.trajectory_stride, domain_name == "relocation")
    learner = Learner(build_model(domain, variant, seed=9), _cfg())
    tv = learner._with_inputs(TensorView.from_view(view, previous_steps=worker.model.uses_previous_step))
    idx = torch.arange(tv.num_states)
    obs, _, cond, rows, _, previous = learner._gather(tv, idx)
    with torch.inference_mode():
        logits_learner = worker.model(obs, cond, rows, previous)
    for i in range(tv.num_states):
        a = view.attempt_rows[i]
        key = (int(view.task_id[a]), int(view.attempt_index[a]), int(view.timesteps[i]))
        torch.testing.assert_close(logits_learner[i], logits_worker[key], rtol=0, atol=1e-5)


@pytest.mark.parametrize("domain_name,variant", [("multiroom", "gpl"), ("relocation", "gpl"), ("multiroom", "gpr"),
                                                 ("relocation", "full_information"), ("multiroom", "no_trajectory"),
                                                 ("multiroom", "instruction_only"), ("multiroom", "mivoa")])
def test_the_conditioning_thread_trains_bitwise_as_one_thread(tmp_path, domain_name, variant):
    """``training.conditioning_thread`` runs each step's conditioning on a second thread: for every
    kind of network (GPL's variants, the numeric full information, GPR, MIVOA) the round trains
    to bitwise the same weights, BatchNorm statistics, loss and accuracy as one thread does."""
    domain = get_domain(domain_name)
    worker = make_worker(domain_name, num_corrections=2, variant=variant,
                         trajectory_ends_at_last_state=domain_name == "relocation")
    root = tmp_path / "run"
    unit = WorkUnit(round_index=0, unit_index=0, task_ids=(1, 2, 3), split="train", seed=2, policy_version=0)
    attempts = worker.collect(unit.task_ids, unit.split, seed=unit.seed, round_index=0)
    commit_round(root, 0, [ShardWriter(root, "r").write_unit(unit, attempts, worker_id="w")])
    view = BufferReader(root).load_training_view(trajectory_stride=domain.trajectory_stride,
                                                 trajectory_end_aligned=domain_name == "relocation")
    results = []
    for thread in (False, True):
        model = build_model(domain, variant, seed=3, policy_batchnorm=True, conv_batchnorm=True)
        learner = Learner(model, _cfg(batch_size=96, conditioning_thread=thread), seed=1)
        stats = learner.train_round(view)
        learner.close()
        results.append((stats.loss, stats.accuracy, stats.num_steps, state_dict_to_numpy(learner.model)))
    (l1, a1, n1, w1), (l2, a2, n2, w2) = results
    assert (l1, a1, n1) == (l2, a2, n2) and n1 >= 2
    assert all(np.array_equal(w1[k], w2[k]) for k in w1)


def _fingerprint_in_a_fresh_process(**env: str) -> str:
    import os
    import subprocess
    import sys

    code = "from learner.cpu import numerics_fingerprint as f; print(f(1))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120,
                         cwd=Path(__file__).resolve().parent.parent, env={**os.environ, **env})
    return out.stdout.strip()


def test_the_numerics_fingerprint_is_stable_here_and_tells_other_arithmetic_apart():
    """Two processes of this machine agree; one on other kernels, as another CPU would pick them
    (MKL's CPU-independent code path and torch's unvectorised kernels), does not; the caller's
    generator is left as it was."""
    from learner.cpu import numerics_fingerprint

    torch.manual_seed(5)
    expected = torch.rand(3)
    torch.manual_seed(5)
    numerics_fingerprint.cache_clear()  # computed, not read from the cache of an earlier test
    here = numerics_fingerprint(1)
    assert torch.equal(torch.rand(3), expected)
    assert len(here) == 12 and int(here, 16) >= 0
    assert _fingerprint_in_a_fresh_process() == here
    assert _fingerprint_in_a_fresh_process(MKL_CBWR="COMPATIBLE", ATEN_CPU_CAPABILITY="default") != here


@pytest.mark.parametrize("thread", [False, True])
def test_bf16_autocast_trains_where_native_and_is_refused_elsewhere(tmp_path, monkeypatch, thread):
    """``training.autocast=bf16`` trains under bf16 autocast on a CPU with native bf16 (other
    weights than fp32's, the same on a second run: the bf16 kernels are deterministic too, on
    both threads of ``conditioning_thread``), and on a CPU without it is refused in one line
    before anything trains. The CPU kind this machine lacks is the one that is patched in."""
    import learner.cpu
    from gpl_dist.config import ConfigError

    view = _view(tmp_path)

    def trained(autocast: str):
        learner = Learner(build_model(get_domain("multiroom"), seed=0, conv_batchnorm=True),
                          _cfg(autocast=autocast, conditioning_thread=thread), seed=1)
        stats = learner.train_round(view)
        learner.close()
        return stats, state_dict_to_numpy(learner.model)

    native = learner.cpu.native_bf16()
    for cpu_has_bf16 in (native, not native):
        monkeypatch.setattr(learner.cpu, "native_bf16", lambda v=cpu_has_bf16: v)
        if not cpu_has_bf16:
            with pytest.raises(ConfigError, match="training.autocast=bf16 needs a CPU with native bf16"):
                trained("bf16")
            continue
        (s32, w32), (s16, w16), (s16b, w16b) = trained("none"), trained("bf16"), trained("bf16")
        assert np.isfinite(s16.loss) and s16.num_steps == s32.num_steps >= 2
        assert any(not np.array_equal(w32[k], w16[k]) for k in w32)  # bf16 arithmetic, not fp32's
        assert all(w.dtype == np.float32 for w in w16.values() if w.dtype.kind == "f")  # fp32 master weights
        assert s16.loss == s16b.loss and all(np.array_equal(w16[k], w16b[k]) for k in w16)


def test_train_refuses_bf16_autocast_on_a_cpu_without_native_bf16_before_anything_is_written(tmp_path, monkeypatch):
    """``gpl-dist train --set training.autocast=bf16`` on a CPU without native bf16 stops in its
    preflight: one line, no run dir written (this machine's CPU kind is patched to the other)."""
    import learner.cpu
    from gpl_dist.cli import main

    monkeypatch.setattr(learner.cpu, "native_bf16", lambda: False)
    run = tmp_path / "run"
    smoke = Path(__file__).resolve().parents[1] / "configs" / "multiroom-smoke.yaml"
    code = main(["train", "--config", str(smoke), "--serial", "--run-dir", str(run),
                 "--set", "training.autocast=bf16"])
    assert code != 0 and not run.exists()
