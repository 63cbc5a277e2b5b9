"""Top-down pictures of an episode: lanes, zones, vehicles coloured by style (with a legend), the ego
highlighted; the picture is cropped to the road (its height follows the number of lanes).

Frames are plain NumPy records taken from env 0 of a world, so rendering never slows a batched run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from highway_srl.constants import STYLE_NAMES, VEHICLE_LENGTH_M, VEHICLE_WIDTH_M
from highway_srl.sim.road import Road

STYLE_COLOURS = {"aggressive": "#d62728", "normal": "#1f77b4", "cautious": "#2ca02c"}
EGO_COLOUR = "#ffbf00"
ZONE_COLOURS = ["#f2f2f2", "#e4eefb", "#e9f7e4", "#fbeee4"]
VIEW_BEHIND_M, VIEW_AHEAD_M = 40.0, 70.0


@dataclass
class Frame:
    step: int
    x: np.ndarray  # (N,) vehicle 0 = ego
    y: np.ndarray
    heading: np.ndarray
    style: np.ndarray
    speed: np.ndarray
    collision: bool = False
    text: list[str] = field(default_factory=list)


def capture(world, env: int = 0, collision: bool = False, text: list[str] | None = None) -> Frame:
    """Take env `env` of a World as a Frame."""
    s = world.state
    g = lambda t: t[env].detach().cpu().numpy().copy()  # noqa: E731
    return Frame(int(s.t[env]), g(s.x), g(s.y), g(s.heading), g(s.style), g(s.v), bool(collision), list(text or []))


def _draw(ax, road: Road, frame: Frame) -> None:
    import matplotlib.patches as patches

    ax.clear()
    ego_x = float(frame.x[0])
    lo, hi = ego_x - VIEW_BEHIND_M, ego_x + VIEW_AHEAD_M
    w = road.lane_width_m
    for i, (name, (z0, z1)) in enumerate(road.zones.items()):
        a, b = max(z0, lo), min(z1, hi)
        if a < b:
            ax.add_patch(patches.Rectangle((a, -0.5 * w), b - a, road.num_lanes * w, color=ZONE_COLOURS[i % 4], zorder=0))
            ax.text(a + 1, (road.num_lanes - 0.5) * w + 1.4, name.replace("_", " "), fontsize=9, color="#444")
    for k in range(road.num_lanes):
        a, b = max(road.lane_start_m[k], lo), min(road.lane_end_m[k], hi)
        if a < b:
            ax.add_patch(patches.Rectangle((a, (k - 0.5) * w), b - a, w, color="#cfcfcf", zorder=1))
        if road.lane_drop[k] and lo < road.lane_end_m[k] < hi:
            ax.plot([road.lane_end_m[k]] * 2, [(k - 0.5) * w, (k + 0.5) * w], color="k", lw=3, zorder=2)
    for k in range(road.num_lanes - 1):
        yb = (k + 0.5) * w
        c0, c1 = road.change_window_m[k]
        ax.plot([lo, hi], [yb, yb], color="white", lw=1, ls=(0, (4, 4)), zorder=2)
        for a, b in ((lo, min(c0, hi)), (max(c1, lo), hi)):  # no crossing outside the window: solid line
            if a < b:
                ax.plot([a, b], [yb, yb], color="#444", lw=1.5, zorder=2)
    for n in range(len(frame.x)):
        if not lo - 10 < frame.x[n] < hi + 10:
            continue
        colour = EGO_COLOUR if n == 0 else STYLE_COLOURS[STYLE_NAMES[int(frame.style[n])]]
        h = float(frame.heading[n])
        cx, cy = float(frame.x[n]), float(frame.y[n])
        # Rectangle anchors at a corner: rotate the centre offset to place the centre right
        dx = -0.5 * VEHICLE_LENGTH_M * math.cos(h) + 0.5 * VEHICLE_WIDTH_M * math.sin(h)
        dy = -0.5 * VEHICLE_LENGTH_M * math.sin(h) - 0.5 * VEHICLE_WIDTH_M * math.cos(h)
        ax.add_patch(patches.Rectangle((cx + dx, cy + dy), VEHICLE_LENGTH_M, VEHICLE_WIDTH_M, angle=math.degrees(h),
                                       facecolor=colour, edgecolor="k", lw=1.5 if n == 0 else 0.5, zorder=3))
    if frame.collision:
        ax.plot(frame.x[0], frame.y[0], marker="X", color="red", markersize=18, zorder=4)
    ax.set_xlim(lo, hi)
    ax.set_ylim((road.num_lanes - 0.5) * w + ROAD_MARGIN_M, -0.5 * w - ROAD_MARGIN_M)  # lane 0 on top: y down = right
    ax.set_aspect("equal")
    ax.set_yticks([])
    ax.set_xlabel("x (m)", fontsize=9)
    ax.tick_params(labelsize=9)
    info = [f"t = {frame.step * 0.125:5.2f} s", f"ego {frame.speed[0]:4.1f} m/s"]
    ax.set_title("   ".join(info + frame.text[:1]) + ("\n" + "   ".join(frame.text[1:]) if frame.text[1:] else ""),
                 fontsize=10, loc="left")
    ax.legend(handles=_legend_handles(), loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=4, fontsize=9,
              frameon=False, handlelength=1.2, borderaxespad=0.2)


ROAD_MARGIN_M = 2.5  # room beside the outer lanes for zone names
FIG_WIDTH_IN = 10.0
HEADER_IN, FOOTER_IN = 0.75, 0.45  # title (two lines) + legend above the road, x axis below


def _legend_handles():
    import matplotlib.patches as patches

    handles = [patches.Patch(facecolor=EGO_COLOUR, edgecolor="k", label="ego")]
    handles += [patches.Patch(facecolor=STYLE_COLOURS[name], edgecolor="k", lw=0.5, label=f"{name} driver")
                for name in STYLE_NAMES]
    return handles


def _figure(road: Road):
    """A figure as wide as FIG_WIDTH_IN whose axes hold exactly the road's height at the view's scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    road_m = road.num_lanes * road.lane_width_m + 2 * ROAD_MARGIN_M
    axes_in = FIG_WIDTH_IN * 0.96 * road_m / (VIEW_BEHIND_M + VIEW_AHEAD_M)
    height = axes_in + HEADER_IN + FOOTER_IN
    fig, ax = plt.subplots(figsize=(FIG_WIDTH_IN, height), dpi=90)
    fig.subplots_adjust(left=0.02, right=0.98, bottom=FOOTER_IN / height, top=1 - HEADER_IN / height)
    return plt, fig, ax


def frame_figure(road: Road, frame: Frame):
    """(pyplot, figure, axes) with the frame drawn; the caller closes the figure."""
    plt, fig, ax = _figure(road)
    _draw(ax, road, frame)
    return plt, fig, ax


def frame_array(road: Road, frame: Frame) -> np.ndarray:
    """The frame as an (H, W, 3) uint8 image."""
    plt, fig, ax = frame_figure(road, frame)
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return image


def save_png(road: Road, frame: Frame, path: str | Path) -> Path:
    plt, fig, ax = frame_figure(road, frame)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def save_gif(road: Road, frames: list[Frame], path: str | Path, fps: int = 8, on_frame=None) -> Path:
    """Animated GIF of the frames (PIL writes it; one matplotlib canvas is reused for speed).

    on_frame(i), if given, is called after frame i is drawn (progress display)."""
    from PIL import Image

    plt, fig, ax = _figure(road)
    images = []
    for i, frame in enumerate(frames):
        _draw(ax, road, frame)
        fig.canvas.draw()
        images.append(Image.fromarray(np.asarray(fig.canvas.buffer_rgba())[..., :3]))
        if on_frame is not None:
            on_frame(i)
    plt.close(fig)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0)
    return path
