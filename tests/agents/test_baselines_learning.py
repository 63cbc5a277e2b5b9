"""Each learning baseline trains through the shared trainer and beats its own random policy (1600 steps).

'Random' is the same method with ε = 1: uniform actions through its own shield or expert, if it has one.
Deployment is 16 episodes of two-lane level A on traffic the training never saw, greedy against random
on the same 16 seeds.
"""

import pytest

from highway_srl.agents.trainer import Trainer

pytestmark = pytest.mark.slow


def _train(config):
    trainer = Trainer(config)
    episodes = []
    while trainer.env_steps < trainer.config.steps:
        episodes += trainer.step()
    return trainer, episodes


@pytest.mark.parametrize("method", ["sr-rl", "mp-rl", "et-rl"])
def test_shielded_baseline_greedy_policy_beats_its_random_policy_in_deployment_reward(method, short_config,
                                                                                        greedy_vs_random):
    trainer, _ = _train(short_config(method))
    greedy, random = greedy_vs_random(trainer.method, trainer.learner)
    assert not greedy["collided"].any()
    assert greedy["deploy_reward"].mean() > random["deploy_reward"].mean() + 40
    assert greedy["avg_speed"].mean() > random["avg_speed"].mean() + 2.0


@pytest.mark.parametrize("method", ["rm-rl", "lm-rl"])
def test_unshielded_baseline_learns_its_speed_term_in_1600_steps(method, short_config, greedy_vs_random):
    # RM-RL and LM-RL have no shield; under the paper's control profile (the default) nothing outside the
    # learner keeps them from a collision, and 1600 steps are too few to learn what one costs: measured at
    # 2e45d25, greedy collided in 4/16 (rm-rl) and 11/16 (lm-rl) level-A episodes, R_r 142 and -72 against
    # random's 150. What they have learnt is their reward's speed term (7.8 and 9.7 m/s against 1.5).
    trainer, _ = _train(short_config(method))
    greedy, random = greedy_vs_random(trainer.method, trainer.learner)
    assert greedy["avg_speed"].mean() > random["avg_speed"].mean() + 4.0


def test_plain_rl_learns_to_drive_fast_but_not_yet_to_avoid_collisions(short_config, greedy_vs_random):
    # Plain RL has no shield: in 1600 steps only a handful of training episodes end, all in collisions, so it
    # has not learnt what a collision costs and its greedy R_r is not above random's (a random walk over A
    # slows to ~1.5 m/s and never hits anything). What it has learnt is its reward's speed term.
    trainer, _ = _train(short_config("rl"))
    greedy, random = greedy_vs_random(trainer.method, trainer.learner)
    assert greedy["avg_speed"].mean() > random["avg_speed"].mean() + 4.0
