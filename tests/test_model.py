import numpy as np
import pytest
import torch

from gpl_dist.domains import get_domain
from gpl_dist.models.build import build_model, load_numpy_state, state_dict_to_numpy
from gpl_dist.models.layers import Conditioning
from gpl_dist.models.mivoa import PreviousStep
from gpl_dist.variants import VARIANTS as METHODS

VARIANTS = list(METHODS)  # every row of the variant table


def random_states(domain, shape, g):
    """Random observations that respect the domain's per-channel codes."""
    if domain.obs_categories is None:
        return g.normal(size=shape + domain.obs_shape).astype(domain.obs_dtype)
    highs = np.array(domain.obs_categories)
    return (g.random(shape + domain.obs_shape) * highs).astype(domain.obs_dtype)


def random_conditioning(domain, a, k, seed=0):
    g = np.random.default_rng(seed)
    vocab = domain.vocabulary
    traj = random_states(domain, (a * k, domain.trajectory_samples), g)
    filled = np.arange(k)[None, :] < g.integers(0, k + 1, (a, 1))
    slots = np.where(filled, np.arange(a * k).reshape(a, k), -1)
    values = None
    if domain.full_information_values is not None:
        values = torch.from_numpy(np.stack([domain.full_information_values(int(t)) for t in g.integers(0, 100, a)]))
    return Conditioning(
        instruction_ids=torch.from_numpy(g.integers(2, vocab.size, (a, vocab.max_tokens))),
        trajectories=torch.from_numpy(traj),
        correction_ids=torch.from_numpy(g.integers(2, vocab.size, (a * k, vocab.max_tokens))),
        slots=torch.from_numpy(slots),
        instruction_values=values,
        correction_values=torch.from_numpy((g.normal(size=a * k) * 100).astype(np.float32)),
    )


def random_obs(domain, b, seed=1):
    return torch.from_numpy(random_states(domain, (b,), np.random.default_rng(seed)))


@pytest.mark.parametrize("domain_name", ["multiroom", "relocation"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_forward_shapes(domain_name, variant):
    d = get_domain(domain_name)
    model = build_model(d, variant, seed=0).eval()
    cond = random_conditioning(d, a=5, k=4)
    rows = torch.tensor([0, 0, 1, 4, 3, 2, 2])
    previous = PreviousStep(random_obs(d, 7, seed=2), torch.tensor([-1, 0, 1, 2, -1, 1, 0])) if model.uses_previous_step else None
    logits = model(random_obs(d, 7), cond, rows, previous)
    assert logits.shape == (7, d.num_actions) and torch.isfinite(logits).all()
    z = model.encode_conditioning(cond)
    assert z.shape == (5, model.conditioning_dim)


def _z(model, cond):
    with torch.no_grad():
        return model.encode_conditioning(cond)


def _replace(cond, **kw):
    fields = dict(instruction_ids=cond.instruction_ids, trajectories=cond.trajectories,
                  correction_ids=cond.correction_ids, slots=cond.slots, instruction_values=cond.instruction_values,
                  correction_values=cond.correction_values)
    fields.update(kw)
    return Conditioning(**fields)


def test_variants_ignore_what_they_should():
    d = get_domain("multiroom")
    cond = random_conditioning(d, a=6, k=3)
    cond = _replace(cond, slots=torch.arange(18).reshape(6, 3))
    other_corr = torch.flip(cond.correction_ids, dims=[1]).clone()
    other_corr[:, 0] = 5
    other_traj = torch.zeros_like(cond.trajectories)
    other_instr = torch.full_like(cond.instruction_ids, 3)

    gpl = build_model(d, "gpl", seed=0).eval()
    assert not torch.allclose(_z(gpl, cond), _z(gpl, _replace(cond, correction_ids=other_corr)))
    assert not torch.allclose(_z(gpl, cond), _z(gpl, _replace(cond, trajectories=other_traj)))
    assert not torch.allclose(_z(gpl, cond), _z(gpl, _replace(cond, instruction_ids=other_instr)))

    no_traj = build_model(d, "no_trajectory", seed=0).eval()
    assert torch.allclose(_z(no_traj, cond), _z(no_traj, _replace(cond, trajectories=other_traj)))

    no_instr = build_model(d, "no_instruction", seed=0).eval()
    assert torch.allclose(_z(no_instr, cond), _z(no_instr, _replace(cond, instruction_ids=other_instr)))

    instr_only = build_model(d, "instruction_only", seed=0).eval()
    assert torch.allclose(_z(instr_only, cond), _z(instr_only, _replace(cond, correction_ids=other_corr)))

    latest = build_model(d, "latest_correction", seed=0).eval()
    older_changed = cond.correction_ids.clone()
    older_changed[cond.slots[:, :2].flatten()] = 7
    assert torch.allclose(_z(latest, cond), _z(latest, _replace(cond, correction_ids=older_changed)))
    newest_changed = cond.correction_ids.clone()
    newest_changed[cond.slots[:, 2]] = 7
    assert not torch.allclose(_z(latest, cond), _z(latest, _replace(cond, correction_ids=newest_changed)))


def test_empty_history_gives_zero_correction_embedding():
    d = get_domain("multiroom")
    model = build_model(d, "gpl", seed=0).eval()
    cond = random_conditioning(d, a=3, k=0)
    z = _z(model, cond)
    assert z.shape == (3, model.conditioning_dim)
    assert torch.count_nonzero(z[:, model.instruction.out_dim:]) == 0


def test_linear_encodings_keep_the_corrections_visible_where_relu_outputs_died():
    """Multi-room's correction and trajectory encodings are 4 units wide; when all 4 ReLUs die (a
    training seed did), every correction encodes alike. Linear outputs cannot die."""
    d = get_domain("multiroom")
    relu, linear = build_model(d, seed=0).eval(), build_model(d, seed=0, linear_encodings=True).eval()
    assert relu.state_dict().keys() == linear.state_dict().keys()  # same parameters, same initialisation
    for a, b in zip(relu.state_dict().values(), linear.state_dict().values()):
        assert torch.equal(a, b)
    for encoder in (linear.instruction.mlp, linear.correction.mlp, linear.trajectory.mlp, linear.pair):
        assert isinstance(encoder[-1], torch.nn.Linear)
    assert isinstance(relu.correction.mlp[-1], torch.nn.ReLU)
    cond = random_conditioning(d, a=4, k=1, seed=3)
    # one attempt each, the same earlier trajectory, four different corrections
    cond = _replace(cond, slots=torch.arange(4).reshape(4, 1),
                    trajectories=cond.trajectories[:1].expand_as(cond.trajectories).clone())
    with torch.no_grad():  # every output unit of the correction encoder's last layer pushed off
        relu.correction.mlp[-2].bias.fill_(-100.0)
        linear.correction.mlp[-1].bias.fill_(-100.0)
    z_relu = _z(relu, cond)[:, relu.instruction.out_dim:]
    z_linear = _z(linear, cond)[:, linear.instruction.out_dim:]
    assert torch.allclose(z_relu, z_relu[:1].expand_as(z_relu))  # the corrections are invisible
    assert not torch.allclose(z_linear, z_linear[:1].expand_as(z_linear))


def test_conv_batchnorm_normalises_every_grid_convolution_and_acts_per_state_at_rollout_time():
    """The authors' code puts a BatchNorm after each 2-D convolution of its grid encoders; the
    switch adds exactly those (policy and trajectory), leaves every other parameter's initial
    value alone, and in eval mode acts on each state alone."""
    d = get_domain("multiroom")
    plain, normed = build_model(d, seed=0), build_model(d, seed=0, conv_batchnorm=True)
    for encoder, channels in ((normed.state, d.model_sizes.state_channels),
                              (normed.trajectory.state, d.model_sizes.traj_state_channels)):
        assert [n.num_features for n in encoder.norms] == list(channels)
    assert plain.state.norms is None and plain.trajectory.state.norms is None
    extra = set(normed.state_dict()) - set(plain.state_dict())
    assert extra and all(".norms." in k for k in extra)
    assert all(torch.equal(v, normed.state_dict()[k]) for k, v in plain.state_dict().items())
    _train_a_few_steps(normed, d, steps=3)
    for norm in (normed.state.norms[0], normed.trajectory.state.norms[1]):  # both paths were normalised
        assert not torch.allclose(norm.running_mean, torch.zeros_like(norm.running_mean))
    _assert_acts_per_state(normed, d, num_states=12)
    # the MIVOA baseline's grid encoder gets the same normalisation (comparable baselines)
    mivoa = build_model(d, "mivoa", seed=0, conv_batchnorm=True)
    assert [n.num_features for n in mivoa.state.norms] == list(d.model_sizes.state_channels)
    assert build_model(d, "mivoa", seed=0).state.norms is None


def _pushed_below_zero(model, encoder: str):
    """``model`` with every hidden pre-activation of ``encoder``'s MLP shifted by -100: the uniform
    shift that training gave the dead layers (docs/results.md)."""
    mods = {"instruction": model.instruction.mlp, "correction": model.correction.mlp,
            "trajectory": model.trajectory.mlp, "pair": model.pair}
    with torch.no_grad():
        mods[encoder][0].bias -= 100.0
    return model


def _with_values(cond, d, variant: str):
    """``cond`` with the numbers ``variant`` reads: full information's values, or GPR's reward sums."""
    if variant == "full_information":
        return _replace(cond, instruction_values=torch.rand(cond.slots.shape[0], len(d.full_information_values(0))))
    if variant == "gpr":
        return _replace(cond, correction_values=torch.randn(cond.correction_ids.shape[0]) * 50)
    return cond


@pytest.mark.parametrize("domain_name,variant", [("multiroom", "gpl"), ("relocation", "full_information"),
                                                 ("relocation", "gpr")])
def test_encoder_layernorm_keeps_each_encoding_visible_where_its_hidden_relus_died(domain_name, variant):
    """Training pushed every hidden pre-activation of multi-room's 16-unit instruction layer (one
    seed) and trajectory layer (another) below zero: that encoding was then the same for every input.
    A LayerNorm before each hidden ReLU of the four conditioning MLPs removes such a shift per sample."""
    d = get_domain(domain_name)

    def fresh():
        return (build_model(d, variant, seed=0, linear_encodings=True).eval(),
                build_model(d, variant, seed=0, linear_encodings=True, encoder_layernorm=True).eval())

    plain, normed = fresh()
    mlps = (normed.instruction.mlp, normed.correction.mlp, normed.trajectory.mlp, normed.pair)
    hidden = [len(d.model_sizes.instruction_mlp), len(d.model_sizes.correction_mlp), len(d.model_sizes.traj_mlp),
              len(d.model_sizes.pair_mlp)]
    assert [sum(isinstance(m, torch.nn.LayerNorm) for m in mlp) for mlp in mlps] == [n - 1 for n in hidden]
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in (*plain.modules(), *normed.head.modules()))
    norms = {n for n, m in normed.named_modules() if isinstance(m, torch.nn.LayerNorm)}
    kept = [p for n, p in normed.named_parameters() if n.rsplit(".", 1)[0] not in norms]
    assert all(torch.equal(a, b) for a, b in zip(plain.parameters(), kept, strict=True))  # same initial weights
    cond = _with_values(_replace(random_conditioning(d, a=6, k=1, seed=5), slots=torch.arange(6).reshape(6, 1)),
                        d, variant)  # one correction each
    width = normed.instruction.out_dim
    parts = {"instruction": slice(0, width), "correction": slice(width, None), "trajectory": slice(width, None),
             "pair": slice(width, None)}
    for encoder, part in parts.items():
        if encoder != "instruction" and not normed.uses_corrections:
            continue
        plain, normed = fresh()
        for model in (plain, normed):
            assert _z(model, cond)[:, part].std(0).max() > 1e-4, encoder  # alive: inputs encode apart
        dead = _z(_pushed_below_zero(plain, encoder), cond)[:, part]
        alive = _z(_pushed_below_zero(normed, encoder), cond)[:, part]
        if encoder in ("instruction", "pair"):  # the whole encoding is constant
            assert torch.allclose(dead, dead[:1].expand_as(dead)), encoder
        assert alive.std(0).max() > 1e-4, encoder
    _assert_acts_per_state(normed, d, num_states=12)
    one = _with_values(random_conditioning(d, a=1, k=1, seed=6), d, variant)  # a training batch may hold one row
    assert normed.train()(random_obs(d, 4, seed=1), one, torch.zeros(4, dtype=torch.long)).shape == (4, d.num_actions)


def test_unreferenced_rows_do_not_matter():
    d = get_domain("multiroom")
    model = build_model(d, "gpl", seed=0).eval()
    cond = random_conditioning(d, a=4, k=3)
    cond = _replace(cond, slots=torch.tensor([[0, -1, -1], [3, -1, -1], [6, -1, -1], [9, -1, -1]]))
    junk = cond.correction_ids.clone()
    junk[[1, 2, 4, 5, 7, 8, 10, 11]] = 9
    assert torch.allclose(_z(model, cond), _z(model, _replace(cond, correction_ids=junk)))


@pytest.mark.parametrize("domain_name", ["multiroom", "relocation"])
def test_loss_on_fixed_batch_falls(domain_name):
    d = get_domain(domain_name)
    torch.manual_seed(0)
    model = build_model(d, "gpl", seed=0)
    cond = random_conditioning(d, a=16, k=3)
    obs = random_obs(d, 256)
    rows = torch.arange(256) % 16
    labels = torch.from_numpy(np.random.default_rng(3).integers(0, d.num_actions, 256))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    model.train()
    losses = []
    for _ in range(150):
        loss = torch.nn.functional.cross_entropy(model(obs, cond, rows), labels)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.7 * losses[0], (losses[0], losses[-1])


def test_weights_round_trip_through_numpy():
    d = get_domain("multiroom")
    a, b = build_model(d, seed=0), build_model(d, seed=1)
    assert not torch.equal(a.head[-1].weight, b.head[-1].weight)
    load_numpy_state(b, state_dict_to_numpy(a))
    assert torch.equal(a.head[-1].weight, b.head[-1].weight)
    assert all(isinstance(v, np.ndarray) for v in state_dict_to_numpy(a).values())


def test_shared_earlier_attempt_is_encoded_once_and_gives_same_result():
    d = get_domain("multiroom")
    model = build_model(d, "gpl", seed=0).eval()
    cond = random_conditioning(d, a=2, k=2)
    cond = _replace(cond, slots=torch.tensor([[0, 1], [0, 1]]))
    dup = _replace(cond, trajectories=torch.cat([cond.trajectories[:2]] * 2),
                   correction_ids=torch.cat([cond.correction_ids[:2]] * 2), slots=torch.tensor([[0, 1], [2, 3]]))
    assert torch.allclose(_z(model, cond), _z(model, dup), atol=1e-6)


def _reference_grid_encoder(enc, obs):
    """``enc`` computed the textbook way: one-hot channels-first input through ``nn.Conv2d`` layers."""
    from torch import nn
    x = torch.cat([nn.functional.one_hot(obs[..., c].long(), n) for c, n in
                   enumerate(enc.categories)], dim=-1).float().permute(0, 3, 1, 2)
    for conv in enc.convs:
        o, d = conv.out_dim, conv.proj.weight.shape[1]
        # proj rows are the taps (0,0), (0,1), (1,0), (1,1), each a block of o filters
        weight = conv.proj.weight.view(2, 2, o, d).permute(2, 3, 0, 1)
        x = torch.relu(nn.functional.conv2d(x, weight, conv.bias))
    return enc.mlp(x.permute(0, 2, 3, 1).flatten(1))


@pytest.mark.parametrize("channels", [(8, 8), (4, 4), (3,)])
def test_grid_encoder_is_a_conv2d_over_one_hot_channels(channels):
    """The lookup-based first layer and the shifted-sum convolutions compute exactly Conv2d's function."""
    from gpl_dist.models.layers import GridStateEncoder
    d = get_domain("multiroom")
    torch.manual_seed(0)
    enc = GridStateEncoder(d.obs_shape, d.obs_categories, channels, (32,))
    obs = random_obs(d, 64)
    got = enc(obs)
    upstream = torch.linspace(-1, 1, got.numel()).view_as(got)
    (got * upstream).sum().backward()
    fast_grads = [p.grad.clone() for p in enc.parameters()]
    enc.zero_grad()
    want = _reference_grid_encoder(enc, obs)
    (want * upstream).sum().backward()
    assert torch.allclose(got, want, atol=1e-5)
    for fast, ref in zip(fast_grads, [p.grad for p in enc.parameters()]):
        assert torch.allclose(fast, ref, atol=1e-4)


def test_first_conv_backward_is_bitwise_the_tap_by_tap_sum():
    """The first layer's table gradient equals bit for bit the sum written as the definition reads:
    for each output cell and tap, its gradient added into the row of the cell that tap reads, in
    cell order (each cell's four taps side by side, from a zero-padded output gradient): the same
    numbers added in the same order."""
    from torch import nn

    from gpl_dist.models.layers import _TAPS, GridStateEncoder, _FirstConv2x2
    d = get_domain("multiroom")
    torch.manual_seed(0)
    enc = GridStateEncoder(d.obs_shape, d.obs_categories, (8, 8), (32,))
    rows = enc.group_rows(random_obs(d, 40))
    table = enc.group_tables().detach().requires_grad_()
    out = _FirstConv2x2.apply(table, rows)
    upstream = torch.randn(out.shape, generator=torch.Generator().manual_seed(1))
    (grad_table,) = torch.autograd.grad(out, table, upstream)
    b, h, w, g = rows.shape
    padded = nn.functional.pad(upstream, (0, 0, 1, 1, 1, 1))  # cell (i, j) feeds output (i - di, j - dj)
    per_cell = torch.cat([padded[:, 1 - di:1 - di + h, 1 - dj:1 - dj + w] for di, dj in _TAPS], dim=-1)
    want = torch.zeros_like(table)
    for j in range(g):
        want.index_add_(0, rows[..., j].reshape(-1), per_cell.reshape(-1, table.shape[1]))
    assert per_cell.abs().sum() > 0 and grad_table.abs().sum() > 0
    assert torch.equal(grad_table, want)


def test_conv1d_channels_last_matches_conv1d():
    from torch import nn

    from gpl_dist.models.layers import conv1d_k2_channels_last
    torch.manual_seed(0)
    conv = nn.Conv1d(16, 4, kernel_size=2)
    x = torch.randn(9, 7, 16, requires_grad=True)
    got = conv1d_k2_channels_last(conv, x)
    want = conv(x.transpose(1, 2)).transpose(1, 2)
    assert got.shape == (9, 6, 4)
    assert torch.allclose(got, want, atol=1e-6)
    g_fast = torch.autograd.grad(got.square().sum(), [x, conv.weight, conv.bias])
    g_ref = torch.autograd.grad(want.square().sum(), [x, conv.weight, conv.bias])
    for a, b in zip(g_fast, g_ref):
        assert torch.allclose(a, b, atol=1e-5)


def test_channel_groups_cover_every_channel_once_within_the_row_limit():
    from gpl_dist.models.layers import channel_groups
    cats = (8, 7, 3, 7, 7, 2)
    groups = channel_groups(cats)
    assert [c for g in groups for c in g] == list(range(len(cats)))
    assert all(np.prod([cats[c] for c in g]) <= 1024 for g in groups)
    assert channel_groups((5000, 3)) == [(0,), (1,)]  # a channel larger than the limit stands alone


def test_policy_batchnorm_is_opt_in_and_acts_per_state_at_rollout_time():
    d = get_domain("relocation")
    plain = build_model(d, seed=0)
    normed = build_model(d, seed=0, policy_batchnorm=True)
    count = lambda m: sum(isinstance(x, torch.nn.BatchNorm1d) for x in m.head.modules())  # noqa: E731
    assert count(plain) == 0 and count(normed) == 3  # one per hidden layer of MLP(256, 256, 256)
    # runs saved without the field were trained without it; the two architectures never mix silently
    with pytest.raises(RuntimeError):
        normed.load_state_dict(plain.state_dict())
    # a few training steps move the running statistics away from their initial (0, 1)
    _train_a_few_steps(normed, d, steps=5)
    assert not torch.allclose(normed.head[0][1].running_mean, torch.zeros(256))
    _assert_acts_per_state(normed, d, num_states=48)


def _train_a_few_steps(model, d, steps: int) -> None:
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    cond, rows = random_conditioning(d, a=6, k=3), torch.arange(48) % 6
    for step in range(steps):
        loss = model(random_obs(d, 48, seed=step), cond, rows).logsumexp(1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()


def _assert_acts_per_state(model, d, num_states: int) -> None:
    """In eval mode a state's action distribution must not depend on which other states share its
    batch (workers batch over whatever tasks are still running)."""
    model.eval()
    cond, rows = random_conditioning(d, a=6, k=3), torch.arange(num_states) % 6
    obs = random_obs(d, num_states, seed=9)
    with torch.no_grad():
        together = model(obs, cond, rows)
        alone = torch.cat([model(obs[i:i + 1], cond, rows[i:i + 1]) for i in range(num_states)])
    torch.testing.assert_close(together, alone, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("domain_name", ["multiroom", "relocation"])
def test_mivoa_reads_the_instruction_the_previous_state_and_the_previous_action(domain_name):
    """Each of MIVOA's three inputs changes its logits; the instruction's vector is the mean of the
    LSTM's states over its words (padding skipped); it needs the previous step to act."""
    d = get_domain(domain_name)
    model = build_model(d, "mivoa", seed=0).eval()
    assert not model.uses_corrections and model.uses_previous_step
    vocab = d.vocabulary
    words = torch.from_numpy(np.random.default_rng(0).integers(2, vocab.size, (3, 5)))
    ids = torch.full((3, vocab.max_tokens), vocab.pad_id, dtype=torch.long)
    ids[:, :5] = words
    cond = _replace(random_conditioning(d, a=3, k=1), instruction_ids=ids)
    rows, obs = torch.tensor([0, 1, 2]), random_obs(d, 3)
    prev = PreviousStep(random_obs(d, 3, seed=5), torch.tensor([0, 1, 2]))
    other_ids = ids.clone()
    other_ids[:, 4] = (ids[:, 4] + 1 - 2) % (vocab.size - 2) + 2  # another word, never padding
    with torch.no_grad():
        base = model(obs, cond, rows, prev)
        changed = [model(obs, cond, rows, PreviousStep(random_obs(d, 3, seed=6), prev.actions)),
                   model(obs, cond, rows, PreviousStep(prev.observations, torch.full((3,), -1))),
                   model(obs, _replace(cond, instruction_ids=other_ids), rows, prev)]
        lstm = model.instruction
        expected = lstm.lstm(lstm.embedding(words))[0].mean(1)  # the mean over the 5 words, not the padding
        torch.testing.assert_close(model.encode_conditioning(cond), expected)
    for other in changed:
        assert (other - base).abs().max() > 1e-5
    with pytest.raises(ValueError, match="previous"):
        model(obs, cond, rows)


def test_relocation_full_information_reads_the_block_and_the_target_as_numbers():
    """The paper's relocation oracle gets which block to move and the goal's coordinates: numbers
    through an MLP, not words; other domains and variants keep text."""
    from gpl_dist.envs.relocation_core import make_task

    d = get_domain("relocation")
    task = make_task(7)
    values = d.full_information_values(7)
    assert values.dtype == np.float32 and values.shape == (5,)
    assert values[:3].argmax() == task.block and values[:3].sum() == 1 and tuple(values[3:]) == pytest.approx(task.target)
    model = build_model(d, "full_information", seed=0).eval()
    assert model.numeric_full_information
    assert not build_model(d, "gpl").numeric_full_information
    assert not build_model(get_domain("multiroom"), "full_information").numeric_full_information
    cond = random_conditioning(d, a=2, k=0)
    moved = cond.instruction_values.clone()
    moved[:, 3] += 0.3  # another target x
    with torch.no_grad():
        z = model.encode_conditioning(cond)
        assert not torch.allclose(z, model.encode_conditioning(_replace(cond, instruction_values=moved)))
        other_words = _replace(cond, instruction_ids=torch.roll(cond.instruction_ids, 1, dims=1))
        torch.testing.assert_close(z, model.encode_conditioning(other_words))  # the text is not read
    with pytest.raises(ValueError, match="reads numbers"):
        model.encode_conditioning(_replace(cond, instruction_values=None))


@pytest.mark.parametrize("domain_name", ["multiroom", "relocation"])
def test_gpr_reads_each_earlier_attempts_summed_reward_in_place_of_its_correction(domain_name):
    d = get_domain(domain_name)
    model = build_model(d, "gpr", seed=0).eval()
    assert model.uses_corrections
    cond = random_conditioning(d, a=4, k=2)
    cond = _replace(cond, slots=torch.arange(8).reshape(4, 2))  # every attempt has two earlier ones
    with torch.no_grad():
        z = model.encode_conditioning(cond)
        other_reward = model.encode_conditioning(_replace(cond, correction_values=cond.correction_values + 50.0))
        other_text = model.encode_conditioning(_replace(cond, correction_ids=torch.roll(cond.correction_ids, 1, 1)))
    assert not torch.allclose(z, other_reward)
    torch.testing.assert_close(z, other_text)  # the correction's words are not read
    with pytest.raises(ValueError, match="summed reward"):
        model.encode_conditioning(_replace(cond, correction_values=None))


@pytest.mark.parametrize("variant", ["gpl", "no_trajectory", "gpr"])
def test_correction_width_sets_the_correction_encoding_and_defaults_to_the_domains(variant):
    d = get_domain("multiroom")
    default, wide = build_model(d, variant, seed=0), build_model(d, variant, seed=0, correction_width=32)
    assert default.correction.out_dim == d.model_sizes.correction_mlp[-1] == 4
    assert wide.correction.out_dim == 32
    # only the correction encoder's last layer and the pair MLP's first layer (which reads it) change shape
    changed = {k for k, v in default.state_dict().items() if v.shape != wide.state_dict()[k].shape}
    assert changed and all(k.startswith(("correction.", "pair.")) for k in changed)
    cond = random_conditioning(d, a=5, k=4)
    logits = wide(random_obs(d, 7), cond, torch.tensor([0, 0, 1, 4, 3, 2, 2]))
    assert logits.shape == (7, d.num_actions) and torch.isfinite(logits).all()
    # a run's config reaches the model through the one mapping
    from gpl_dist.config import ModelConfig
    from gpl_dist.models.build import build_model_from_config
    assert build_model_from_config(d, ModelConfig(variant=variant, correction_width=32)).correction.out_dim == 32


def test_leaky_encoders_have_the_relu_networks_units_and_a_never_positive_unit_still_learns():
    """``model.encoder_activation: leaky_relu``: the same parameters and counted units as ReLU; a
    unit that is never positive counts as dead in the health line, yet its weights get a gradient
    (ReLU's get none)."""
    from gpl_dist.config import ConfigError, load_config
    from learner.health import encoder_health

    domain = get_domain("multiroom")
    relu = build_model(domain, seed=0, linear_encodings=True)
    leaky = build_model(domain, seed=0, linear_encodings=True, encoder_activation="leaky_relu")
    assert {k: v.shape for k, v in relu.state_dict().items()} == {k: v.shape for k, v in leaky.state_dict().items()}
    assert any(isinstance(m, torch.nn.LeakyReLU) for m in leaky.instruction.modules())
    assert not any(isinstance(m, torch.nn.LeakyReLU) for m in leaky.state.modules())  # the policy's own encoder stays ReLU
    cond = random_conditioning(domain, a=4, k=3)
    grads = {}
    for name, model in (("relu", relu), ("leaky", leaky)):
        with torch.no_grad():
            hidden = model.instruction.mlp[0]
            hidden.weight.zero_()
            hidden.bias.fill_(-1.0)  # every hidden unit of the instruction MLP is never positive
        health = {h.encoder: h for h in encoder_health(model, cond)}
        assert health["instruction"].constant and health["instruction"].dead_units >= 16
        model.train()
        model.encode_conditioning(cond).sum().backward()
        grads[name] = float(model.instruction.mlp[0].weight.grad.abs().sum())
    assert grads["relu"] == 0.0 and grads["leaky"] > 0.0
    with pytest.raises(ConfigError, match="model.encoder_activation"):
        load_config(None, {"model.encoder_activation": "tanh"})
