"""A falsifier case replayed under the safe profile, step by step: the ego's and the nearest SV's centre,
heading, speed and body corners (rules.mappings.corner_points), for the last steps before the collision.

    python scripts/case_corners.py tests/rules/cases/CASE.json [--last 12]

Where a recorded action is forbidden, the first allowed of the falsifier's cautious order is taken (as
`falsify --replay` with substitution does). Prints one line a step.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from highway_srl.experiments import falsify as fz  # noqa: E402
from highway_srl.rules.mappings import corner_points  # noqa: E402
from highway_srl.rules.pipeline import SafetyLayer  # noqa: E402


def trace(path: str, last: int) -> list[str]:
    case = fz.load_case(Path(path))
    world = fz.case_world(case)
    layer = SafetyLayer(world.road, profile="safe")
    recorded, order = torch.tensor(case.actions), torch.tensor(fz.CAUTIOUS_ORDER)
    view, lines = layer.observe(world), []
    for step in range(len(case.actions)):
        action, mask = recorded[step:step + 1], view.primary.mask
        if not bool(mask[0, action[0]]):
            action = order[mask[0, order].nonzero()[0]]
        lane, speed = layer.act(action)
        events = world.step(lane, speed)
        s = world.state
        x, y, h = s.x[0], s.y[0], s.heading[0]
        j = int(((x[1:] - x[0]) ** 2 + (y[1:] - y[0]) ** 2).argmin()) + 1
        _, ey = corner_points(x[0], y[0], h[0])
        _, sy = corner_points(x[j], y[j], h[j])
        if step >= len(case.actions) - last:
            lines.append(f"{step} action={int(action)} target={int(lane)} ego y={y[0]:.2f} h={h[0]:+.3f} "
                         f"v={s.v[0, 0]:.2f} corners_y={[round(float(c), 2) for c in ey]} | "
                         f"SV {j} dx={x[j] - x[0]:+.2f} "
                         f"y={y[j]:.2f} h={h[j]:+.3f} v={s.v[0, j]:.2f} corners_y={[round(float(c), 2) for c in sy]} "
                         f"collision={bool(events.collision[0])}")
        if bool(events.collision[0] | events.terminated[0]):
            break
        view = layer.observe(world)
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="case_corners.py", description=__doc__.splitlines()[0])
    p.add_argument("case", help="a falsifier case (JSON)")
    p.add_argument("--last", type=int, default=12, help="steps to print before the end (default 12)")
    args = p.parse_args(argv)
    if not Path(args.case).is_file():
        p.error(f"{args.case}: no such case file")
    print("\n".join(trace(args.case, args.last)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
