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


@pytest.mark.parametrize("method", ["sr-rl", "rm-rl", "mp-rl", "lm-rl", "et-rl"])
def test_baseline_greedy_policy_beats_its_random_policy_in_deployment_reward(method, short_config, greedy_vs_random):
    trainer, _ = _train(short_config(method))
    greedy, random = greedy_vs_random(trainer.method, trainer.learner)
    assert not greedy["collided"].any()
    assert greedy["deploy_reward"].mean() > random["deploy_reward"].mean() + 40
    assert greedy["avg_speed"].mean() > random["avg_speed"].mean() + 2.0


def test_plain_rl_learns_to_drive_fast_but_not_yet_to_avoid_collisions(short_config, greedy_vs_random):
    # Plain RL has no shield: in 1600 steps only a handful of training episodes end, all in collisions, so it
    # has not learnt what a collision costs and its greedy R_r is not above random's (a random walk over A
    # slows to ~1.5 m/s and never hits anything). What it has learnt is its reward's speed term.
    trainer, _ = _train(short_config("rl"))
    greedy, random = greedy_vs_random(trainer.method, trainer.learner)
    assert greedy["avg_speed"].mean() > random["avg_speed"].mean() + 4.0
