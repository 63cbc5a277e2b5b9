"""Issue 15: a rate's axis never runs past 100 %, and points on the ceiling are drawn whole."""

import matplotlib

from highway_srl.study.figures import cap_rate_axis

matplotlib.use("Agg")


def test_a_rate_axis_ends_at_its_ceiling_and_points_on_it_are_not_clipped():
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.scatter([5.0, 7.0, 9.0], [60.0, 95.0, 100.0])
    assert ax.get_ylim()[1] > 100.0  # matplotlib's margin: the bug the cap removes
    cap_rate_axis(ax, 100.0)
    assert ax.get_ylim()[1] == 100.0 and ax.get_ylim()[0] <= 60.0
    assert not ax.collections[0].get_clip_on()
    plt.close(fig)
