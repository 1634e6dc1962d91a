"""Off-policy training does the same number of gradient updates per env step whatever the
number of envs (issue #36, Deliver 7): SB3's default, one update per vector step, halves it
with 2 envs."""

import pytest

from scorbot_gym.rl import TrainConfig
from scorbot_gym.rl.training import build_model, make_training_env

pytestmark = pytest.mark.rl


@pytest.mark.parametrize(
    ("n_envs", "ratio", "schedule"),
    [(1, 1.0, (1, 1)), (2, 1.0, (1, 2)), (4, 0.5, (1, 2)), (1, 0.5, (2, 1)), (2, 0.25, (2, 1))],
)
def test_update_schedule_gives_the_ratio_whatever_n_envs(n_envs, ratio, schedule):
    config = TrainConfig(n_envs=n_envs, updates_per_env_step=ratio)
    assert config.update_schedule() == schedule
    train_freq, gradient_steps = schedule
    assert gradient_steps / (train_freq * n_envs) == ratio


@pytest.mark.parametrize(("n_envs", "ratio"), [(2, 0.3), (3, 0.5), (1, 0.0), (1, -1.0)])
def test_a_ratio_n_envs_cannot_give_is_a_one_line_error(n_envs, ratio):
    with pytest.raises(ValueError, match="updates_per_env_step") as err:
        TrainConfig(n_envs=n_envs, updates_per_env_step=ratio).validate()
    assert "\n" not in str(err.value)


def test_sac_is_built_with_the_schedule_for_two_envs():
    from stable_baselines3.common.vec_env import DummyVecEnv

    config = TrainConfig(objects=["box"], n_envs=2, net_arch=[8], tensorboard=False).validate()
    venv = DummyVecEnv([lambda: make_training_env(config)] * 2)
    try:
        model = build_model(config, venv, None)
        assert (model.train_freq.frequency, model.gradient_steps) == (1, 2)
    finally:
        venv.close()
