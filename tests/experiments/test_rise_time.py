"""§4.2, "Rise time of episode reward: the number of training steps required for the episode return to reach
90% of its peak value", on the smoothed return; golden values by hand."""

from highway_srl.experiments.training_metrics import SMOOTH_EPISODES, rise_time, training_metrics

STEPS = [100, 200, 300, 400, 500]


def test_rise_time_is_the_first_step_at_90_percent_of_the_peak():
    # peak 200: level 180, first reached at step 400 (190); the range variant's level is 20 + 0.9 x 180 = 182
    assert rise_time(STEPS, [20.0, 100.0, 170.0, 190.0, 200.0]) == 400
    # min 100, peak 200: 90 % of the peak (180) at step 300, min + 90 % of the range (190) only at step 500
    smoothed = [100.0, 150.0, 185.0, 188.0, 200.0]
    assert rise_time(STEPS, smoothed) == 300
    assert rise_time(STEPS, smoothed, from_min=True) == 500


def test_rise_time_counts_reaching_the_level_exactly():
    assert rise_time(STEPS, [0.0, 90.0, 95.0, 100.0, 100.0]) == 200


def test_rise_time_with_a_negative_peak_is_within_ten_percent_of_its_magnitude():
    # peak -100: the level is -110 (peak - 0.1 |peak|), first reached at step 300
    assert rise_time(STEPS, [-320.0, -200.0, -105.0, -100.0, -150.0]) == 300


def test_rise_time_with_a_curve_that_starts_at_its_peak_is_the_first_step():
    assert rise_time(STEPS, [50.0, 10.0, 20.0, 30.0, 40.0]) == 100


def test_training_metrics_report_both_rise_times_per_seed_and_mean():
    # a return of 0 for 20 episodes then 100: the 20-episode average climbs 5 per episode from the 21st on
    episodes = [{"seed": 0, "step": 10 * (i + 1), "return": 0.0 if i < SMOOTH_EPISODES else 100.0,
                 "collision": False, "avg_speed": 5.0} for i in range(2 * SMOOTH_EPISODES)]
    m = training_metrics(episodes, [0])
    seed = m["per_seed"]["0"]
    # the average reaches 90 (of the peak 100) at the 18th episode of returns 100, episode 38, step 380;
    # the min is 0, so the range variant gives the same step here
    assert seed["rise_time_steps"] == 380 and seed["rise_time_range_steps"] == 380
    assert m["mean"]["rise_time_steps"] == 380 and m["mean"]["rise_time_range_steps"] == 380
