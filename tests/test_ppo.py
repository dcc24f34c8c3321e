"""The project's one PPO (``learner.ppo``): its two switches on a small SB3 run of CartPole."""

import gymnasium

from learner.ppo import PPOSettings, make_sb3_ppo, value_parameters

SETTINGS = PPOSettings(n_envs=1, n_steps=64, batch_size=64, n_epochs=1, learning_rate=1e-4)  # one Adam step per update


def _ppo(settings: PPOSettings):
    from stable_baselines3.common.vec_env import DummyVecEnv

    env = DummyVecEnv([lambda: gymnasium.make("CartPole-v1")])
    return make_sb3_ppo(env, settings, episode_steps=500, seed=0, pi=[16])


def _moves(model, learn_steps: int) -> tuple[float, float]:
    """Largest change of a policy parameter and of a value parameter over ``learn_steps`` env steps."""
    value = {id(q) for q in value_parameters(model.policy)}
    before = {name: q.detach().clone() for name, q in model.policy.named_parameters()}
    model.learn(total_timesteps=learn_steps)
    moved = {"policy": 0.0, "value": 0.0}
    for name, q in model.policy.named_parameters():
        kind = "value" if id(q) in value else "policy"
        moved[kind] = max(moved[kind], float((q.detach() - before[name]).abs().max()))
    return moved["policy"], moved["value"]


def test_updates_switched_off_leave_every_weight_as_it_was():
    model = _ppo(PPOSettings(**{**SETTINGS.__dict__, "value_learning_rate": 0.05}))
    model.updating = False
    assert _moves(model, 128) == (0.0, 0.0) and model.num_timesteps == 128  # it sampled, it did not update
    assert model.policy.optimizer.state_dict()["state"] == {}
    model.updating = True
    assert min(_moves(model, 64)) > 0.0


def test_the_value_layers_keep_their_own_learning_rate():
    """Adam's first step moves each parameter by about its rate: the value layers' 0.05, the rest 1e-4."""
    model = _ppo(PPOSettings(**{**SETTINGS.__dict__, "value_learning_rate": 0.05}))
    groups = model.policy.optimizer.param_groups
    assert [len(g["params"]) for g in groups] == [len(list(model.policy.parameters())) - 4, 4]  # 2 value layers
    policy_move, value_move = _moves(model, 64)
    assert [g["lr"] for g in groups] == [1e-4, 0.05]  # after SB3 set the schedule's rate
    assert 0.0 < policy_move <= 1e-4 * 1.001 and 0.04 < value_move <= 0.05 * 1.001


def test_without_a_value_rate_it_is_sb3s_own_optimiser():
    model = _ppo(SETTINGS)
    assert len(model.policy.optimizer.param_groups) == 1
    policy_move, value_move = _moves(model, 64)
    assert 0.0 < policy_move <= 1e-4 * 1.001 and 0.0 < value_move <= 1e-4 * 1.001


def test_the_value_parameters_are_those_only_the_value_reads():
    model = _ppo(PPOSettings(**{**SETTINGS.__dict__, "value_layers": 2, "value_hidden": 8}))
    value = {id(q) for q in value_parameters(model.policy)}
    names = {name for name, q in model.policy.named_parameters() if id(q) in value}
    assert names == {"mlp_extractor.value_net.0.weight", "mlp_extractor.value_net.0.bias",
                     "mlp_extractor.value_net.2.weight", "mlp_extractor.value_net.2.bias",
                     "value_net.weight", "value_net.bias"}  # CartPole's flatten extractor has no parameters
    assert model.policy.mlp_extractor.value_net[2].out_features == 8
