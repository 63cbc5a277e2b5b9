"""`highway-srl play`: the Manual baseline (§4.2), a person drives the ego with the arrow keys.

Keys, read at the paper's decision rate (8 Hz, one δt = 0.125 s step per decision): up Faster, down Slower,
left LaneLeft, right LaneRight, nothing Idle (a key pressed and released within one tick still counts);
Esc or closing the window stops, and an unfinished episode is not logged. The ego follows the paper's
action set A through the road's own rules (rules/raw.py), without any safety check, and a lane change
once started carries on until the other arrow is pressed (a tap commits, as a driver's indicator would).

The run folder holds what every method's does, so human runs enter the same tables:
  config.json     {"config": {"method": "manual", scenario, traffic, adversarial, profile, adversary, seeds, ...},
                  version, commit}
  episodes.jsonl  one line per finished episode, the fields of a training episode (train.py): seed, step,
                  return (the paper's training reward: r_RM, -320 on collision), length, collision,
                  avg_speed, success, deploy_reward (R_r)
  metrics.json    the deployment summary in evaluate's format: C_r, average speed, R_r (and R_s on ramps)
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import torch

from highway_srl.constants import DT_S, STYLE_NAMES, VEHICLE_LENGTH_M, VEHICLE_WIDTH_M
from highway_srl.experiments.evaluate import summarise
from highway_srl.experiments.runs import (
    append_jsonl, check_output_folder, holds_other_files, provenance, read_jsonl, write_json,
)
from highway_srl.rules import scenario_reward
from highway_srl.rules.episode import EpisodeStats, advance
from highway_srl.rules.raw import FIVE_ACTIONS, LANE_LEFT, LANE_RIGHT, RawSafetyLayer
from highway_srl.rules.safe_actions import FASTER, IDLE, SLOWER
from highway_srl.sim import World
from highway_srl.sim.render import EGO_COLOUR, STYLE_COLOURS, VIEW_AHEAD_M, VIEW_BEHIND_M

DECISION_HZ = round(1.0 / DT_S)  # 8
PIXELS_PER_M = 10
HUD_PX = 56
MARGIN_M = 2.0


def require_pygame():
    try:
        import pygame
    except ImportError:
        raise ValueError("play needs pygame, which is not installed: pip install highway-srl[play]") from None
    return pygame


class Keys:
    """Arrow keys held down, and arrows tapped since the last tick, from pygame KEYDOWN/KEYUP events."""

    def __init__(self, pygame):
        self.pg = pygame
        self.arrows = {pygame.K_UP: FASTER, pygame.K_DOWN: SLOWER, pygame.K_LEFT: LANE_LEFT, pygame.K_RIGHT: LANE_RIGHT}
        self.held: set[int] = set()
        self.tapped: set[int] = set()

    def feed(self, event) -> None:
        if event.type == self.pg.KEYDOWN and event.key in self.arrows:
            self.held.add(event.key)
            self.tapped.add(event.key)
        elif event.type == self.pg.KEYUP:
            self.held.discard(event.key)

    def action(self) -> int:
        """The tick's action (index into FIVE_ACTIONS): a lane change before a speed change; nothing = Idle."""
        pressed = self.held | self.tapped
        self.tapped = set()
        for key in (self.pg.K_LEFT, self.pg.K_RIGHT, self.pg.K_UP, self.pg.K_DOWN):
            if key in pressed:
                return self.arrows[key]
        return IDLE


class Screen:
    """Top-down view of env 0 around the ego: lanes, change windows, lane ends, vehicles; speed and time."""

    def __init__(self, pygame, road):
        self.pg, self.road = pygame, road
        self.width = int((VIEW_BEHIND_M + VIEW_AHEAD_M) * PIXELS_PER_M)
        self.road_px = int((road.num_lanes * road.lane_width_m + 2 * MARGIN_M) * PIXELS_PER_M)
        self.surface = pygame.display.set_mode((self.width, self.road_px + HUD_PX))
        pygame.display.set_caption("highway-srl play: arrows drive, Esc stops")
        try:
            self.font = pygame.font.Font(None, 22)
        except Exception:  # noqa: BLE001 - no font support: draw without text
            self.font = None

    def _px(self, x: float, y: float, ego_x: float) -> tuple[float, float]:
        return ((x - ego_x + VIEW_BEHIND_M) * PIXELS_PER_M, (y + 0.5 * self.road.lane_width_m + MARGIN_M) * PIXELS_PER_M)

    def draw(self, world, lines: list[str], collision: bool = False) -> None:
        pg, road, w = self.pg, self.road, self.road.lane_width_m
        s = world.state
        ego_x = float(s.x[0, 0])
        lo, hi = ego_x - VIEW_BEHIND_M, ego_x + VIEW_AHEAD_M
        self.surface.fill((96, 140, 80))
        for k in range(road.num_lanes):
            a, b = max(road.lane_start_m[k], lo), min(road.lane_end_m[k], hi)
            if a < b:
                x0, y0 = self._px(a, (k - 0.5) * w, ego_x)
                x1, y1 = self._px(b, (k + 0.5) * w, ego_x)
                pg.draw.rect(self.surface, (120, 120, 120), pg.Rect(x0, y0, x1 - x0, y1 - y0))
            if road.lane_drop[k] and lo < road.lane_end_m[k] < hi:
                pg.draw.line(self.surface, (0, 0, 0), self._px(road.lane_end_m[k], (k - 0.5) * w, ego_x),
                             self._px(road.lane_end_m[k], (k + 0.5) * w, ego_x), 4)
        for k in range(road.num_lanes - 1):
            c0, c1 = road.change_window_m[k]
            yb = (k + 0.5) * w
            for xa in range(int(lo) - int(lo) % 6, int(hi), 6):  # dashed where crossing is allowed, solid elsewhere
                solid = not (c0 <= xa < c1)
                end = xa + (6 if solid else 3)
                pg.draw.line(self.surface, (40, 40, 40) if solid else (240, 240, 240), self._px(xa, yb, ego_x),
                             self._px(end, yb, ego_x), 2)
        for n in range(s.x.shape[1]):
            x, y, h = float(s.x[0, n]), float(s.y[0, n]), float(s.heading[0, n])
            if not lo - 10 < x < hi + 10:
                continue
            c, sn = math.cos(h), math.sin(h)
            half_l, half_w = 0.5 * VEHICLE_LENGTH_M, 0.5 * VEHICLE_WIDTH_M
            corners = [self._px(x + c * dx - sn * dy, y + sn * dx + c * dy, ego_x)
                       for dx, dy in ((half_l, half_w), (half_l, -half_w), (-half_l, -half_w), (-half_l, half_w))]
            colour = EGO_COLOUR if n == 0 else STYLE_COLOURS[STYLE_NAMES[int(s.style[0, n])]]
            pg.draw.polygon(self.surface, pg.Color(colour), corners)
            pg.draw.polygon(self.surface, (0, 0, 0), corners, 2 if n == 0 else 1)
        if collision:
            pg.draw.circle(self.surface, (220, 0, 0), self._px(ego_x, float(s.y[0, 0]), ego_x), 14, 4)
        pg.draw.rect(self.surface, (20, 20, 20), pg.Rect(0, self.road_px, self.width, HUD_PX))
        if self.font is not None:
            for i, text in enumerate(lines[:2]):
                self.surface.blit(self.font.render(text, True, (230, 230, 230)), (10, self.road_px + 8 + 22 * i))
        pg.display.flip()


def play(
    scenario: str = "two-lane",
    traffic: str = "C",
    out: str | Path = "manual",
    *,
    adversarial: bool = False,
    episodes: int = 1,
    seed: int = 0,
    fps: float = DECISION_HZ,
    wait_for_key: bool = True,
    on_tick: Callable[[int, int], None] | None = None,
) -> dict:
    """Drive `episodes` episodes by hand and write the run folder `out`; returns metrics.json's content.

    fps: decisions per second (the paper's 8; 0 = as fast as possible, for scripted tests).
    wait_for_key: each episode starts at the first key press. on_tick(episode, step), if given, runs before
    each decision (tests post scripted key events there).
    """
    out = Path(out)
    check_output_folder(out)
    if (out / "config.json").exists():
        raise FileExistsError(f"{str(out)!r} already holds a run; choose another --out")
    if holds_other_files(out):  # a run's episodes.jsonl or metrics.json would be mixed with the person's
        raise ValueError(f"--out {str(out)!r} holds files but no run (config.json); choose an empty or new folder")
    if episodes < 1:
        raise ValueError(f"episodes must be positive, got {episodes}")
    pygame = require_pygame()
    world = World(scenario, traffic, adversarial, num_envs=1, seed=seed)  # validates scenario and traffic
    layer = RawSafetyLayer(world.road, five_actions=True, hold_lane_change=True)
    config = {"method": "manual", "scenario": scenario, "traffic": traffic, "adversarial": adversarial,
              "profile": layer.mapped.profile, "adversary": world.adversary, "seeds": [seed], "episodes": episodes, "decision_hz": fps}
    open_display(pygame, wait_for_key)  # before the run folder: a refusal leaves nothing behind
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "config.json", {"config": config, **provenance()})
        log = out / "episodes.jsonl"
        log.touch()
        pygame.font.init()
        screen = Screen(pygame, world.road)
        keys = Keys(pygame)
        clock = pygame.time.Clock()
        steps_total = 0
        for ep in range(episodes):
            if ep > 0:
                world.reset()
            layer.reset()
            layer.observe(world)
            if wait_for_key and not _wait_for_start(pygame, screen, world, ep, episodes):
                break
            row = _drive_episode(pygame, world, layer, screen, keys, clock, fps, lambda t: on_tick and on_tick(ep, t))
            if row is None:
                break
            steps_total += row["length"]
            append_jsonl(log, [{"seed": seed, "step": steps_total, **row}])
    finally:
        pygame.quit()
    rows = read_jsonl(log)
    return write_manual_metrics(out, config, rows)


KEYLESS_DRIVERS = ("dummy", "offscreen")  # SDL video drivers that draw nowhere and read no keys


def open_display(pygame, wait_for_key: bool) -> None:
    """pygame's display (no audio: pygame.init() would open a sound device), or a one-line ValueError where
    SDL has no display, or only a driver that reads no keys (dummy, offscreen: SDL falls back to offscreen
    when DISPLAY names no running server), on which waiting for the first key press would wait forever."""
    try:
        pygame.display.init()
    except pygame.error as err:
        raise ValueError(f"play cannot open a window: {err}") from None
    driver = pygame.display.get_driver()
    if wait_for_key and driver in KEYLESS_DRIVERS:
        pygame.quit()
        raise ValueError(f"play needs a window that takes key presses, and SDL's video driver {driver!r} has "
                         "none (SDL_VIDEODRIVER set so, or DISPLAY names no running X server)")


def _wait_for_start(pygame, screen, world, ep: int, episodes: int) -> bool:
    while True:
        for event in pygame.event.get():
            if event.type == pygame.QUIT or (event.type == pygame.KEYDOWN and event.key == pygame.K_ESCAPE):
                return False
            if event.type == pygame.KEYDOWN:
                return True
        screen.draw(world, [f"episode {ep + 1} of {episodes}: press any key to start",
                            "up Faster, down Slower, left/right change lane, nothing Idle; Esc stops"])
        pygame.time.wait(30)


def _drive_episode(pygame, world, layer, screen, keys, clock, fps, on_tick) -> dict | None:
    """One episode at `fps` decisions per second; the episode's log fields, or None if the person stopped."""
    scenario = world.scenario
    # float64 sums: the numbers a person's episode always had (Python floats), not the batched float32
    stats = EpisodeStats(scenario, 1, world.device, world.max_steps, dtype=torch.float64)
    for t in range(world.max_steps):
        on_tick(t)
        for event in pygame.event.get():
            if event.type == pygame.QUIT or (event.type == pygame.KEYDOWN and event.key == pygame.K_ESCAPE):
                return None
            keys.feed(event)
        action = keys.action()
        events, step, flags = advance(world, layer, torch.tensor([action]))
        mapped = layer.mapped.last.primary  # the paper's view: the reward and R_r every method is scored by
        reward = scenario_reward(scenario, mapped.r_rm, events.collision, **flags.reward_inputs())
        stats.add(events, flags, step.primary, world.ego_speed, reward)
        collided = bool(stats.collision[0])
        screen.draw(world, [f"t {(t + 1) * DT_S:5.1f} s   speed {float(world.ego_speed[0]):4.1f} m/s   "
                            f"{FIVE_ACTIONS[action]}", "COLLISION" if collided else ""], collision=collided)
        if fps:
            clock.tick(fps)
        if bool(events.terminated[0] | events.truncated[0]):
            break
    row = stats.finish(torch.ones(1, dtype=torch.bool))[0]
    return {"return": round(row.ret, 4), "length": row.length, "collision": row.collision,
            "avg_speed": round(row.avg_speed, 4), "success": row.success, "deploy_reward": round(row.deploy_reward, 4)}


def write_manual_metrics(out: Path, config: dict, rows: list[dict]) -> dict:
    """metrics.json in evaluate's report format, from the logged episodes."""
    report = {"run": str(out), "method": "manual", "scenario": config["scenario"], "adversarial": config["adversarial"],
              "backend": "ours", "episodes_per_level": len(rows), "levels": {}, **provenance()}
    if rows:
        results = {
            "collided": torch.tensor([r["collision"] for r in rows]),
            "success": torch.tensor([r["success"] for r in rows]),
            "avg_speed": torch.tensor([r["avg_speed"] for r in rows]),
            "deploy_reward": torch.tensor([r["deploy_reward"] for r in rows]),
        }
        report["levels"][config["traffic"]] = summarise(results, config["scenario"])
    write_json(out / "metrics.json", report)
    return report
