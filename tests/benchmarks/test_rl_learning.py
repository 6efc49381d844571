"""benchmarks/rl_learning.py: the random policy replays the same episodes on the same seeds (what makes it
a fair baseline for PPO), and the learning curve bins every training episode once."""

from benchmarks import rl_learning


def test_the_random_baseline_is_the_same_on_the_same_seeds():
    first = rl_learning._evaluate(None, (1000,))
    again = rl_learning._evaluate(None, (1000,))
    assert first == again
    assert first["lengths"][0] <= 300 and first["rewards"][0] < 0
    assert 0 < first["set_point_counts"] < 17_800  # random set points, anywhere in the range


def test_the_learning_curve_bins_every_episode_by_where_it_ended():
    train = {
        "steps": 1000,
        "episode_end_steps": [300, 600, 650, 1000],
        "episode_rewards": [-300, -200, -100, -50],
    }
    assert rl_learning.curve(train, bins=2) == [(500, -300.0, 1), (1000, (-200 - 100 - 50) / 3, 3)]
