"""Random sweep of the safe-distance rule R_SVi against a brute-force worst-case simulation.

    .venv/bin/python scripts/sd_sweep.py                 # 10^6 cases, about half a minute on 2 cores
    .venv/bin/python scripts/sd_sweep.py --cases 100000 --seed 1

Cases: gap U[0, 40] m, both speeds U[0, 15] m/s, SV ahead or behind with probability 1/2, brakes
(6, 6) m/s^2 for half the cases and U[3, 9] each for the other half, δt = 0.125 s. Two worst cases are
simulated (highway_srl/rules/worst_case.py, 1 ms grid, exact kinematics, speeds clamped at 0):
  faster   the follower accelerates during δt: 3.5 m/s^2 when the ego follows (it may have chosen Faster),
           0 when the SV follows -- the promise the default rule keeps;
  paper    the follower keeps its speed during δt -- the paper's own model.
A violation is R = 1 and a collision; conservativeness is the share of collision-free cases with R = 0.
"""

from __future__ import annotations

import argparse
import time

import torch

from highway_srl.constants import DT_S, EGO_ACCEL_MAX_MPS2
from highway_srl.rules.safe_distance import rule_indicator, safe_distance
from highway_srl.rules.worst_case import worst_case_collides


def sample(n: int, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    u = lambda lo, hi: lo + (hi - lo) * torch.rand(n, generator=g, dtype=torch.float64)  # noqa: E731
    paper_brakes = torch.rand(n, generator=g) < 0.5
    return {
        "gap": u(0.0, 40.0),
        "v_ego": u(0.0, 15.0),
        "v_other": u(0.0, 15.0),
        "front": torch.rand(n, generator=g) < 0.5,
        "ego_brake": torch.where(paper_brakes, 6.0, u(3.0, 9.0)),
        "other_brake": torch.where(paper_brakes, 6.0, u(3.0, 9.0)),
        "paper_brakes": paper_brakes,
    }


def counterexample(c: dict[str, torch.Tensor], bad: torch.Tensor, min_gap: torch.Tensor, accel) -> str:
    if not bool(bad.any()):
        return "none"
    i = int(torch.where(bad, min_gap, torch.full_like(min_gap, float("inf"))).argmin())
    front = bool(c["front"][i])
    need = float(safe_distance(c["v_ego"][i], c["v_other"][i], front=front, ego_brake=c["ego_brake"][i],
                               other_brake=c["other_brake"][i], reaction_accel=accel(front)))
    return (f"SV {'ahead' if front else 'behind'}, gap {float(c['gap'][i]):.3f} m, v_ego {float(c['v_ego'][i]):.3f} m/s, "
            f"v_sv {float(c['v_other'][i]):.3f} m/s, |a_ego| {float(c['ego_brake'][i]):.3f}, "
            f"|a_sv| {float(c['other_brake'][i]):.3f} m/s^2: literal R = 1, worst case reaches gap "
            f"{float(min_gap[i]):.3f} m; the sound rule needs gap > {need:.3f} m")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=1_000_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dt", type=float, default=1e-3, help="brute-force time step (s)")
    args = p.parse_args()
    torch.set_num_threads(max(1, torch.get_num_threads()))
    t0 = time.time()
    c = sample(args.cases, args.seed)
    kw = dict(front=c["front"], ego_brake=c["ego_brake"], other_brake=c["other_brake"], reaction_s=DT_S)
    rules = {
        "default": rule_indicator(c["gap"], c["v_ego"], c["v_other"], **kw),
        "literal": rule_indicator(c["gap"], c["v_ego"], c["v_other"], literal=True, **kw),
    }
    models = {
        "faster": (None, lambda front: EGO_ACCEL_MAX_MPS2 if front else 0.0),
        "paper": (0.0, lambda front: 0.0),
    }
    outcome = {name: worst_case_collides(c["gap"], c["v_ego"], c["v_other"], reaction_accel=acc, dt_s=args.dt, **kw)
               for name, (acc, _) in models.items()}
    elapsed = time.time() - t0

    print(f"cases checked: {args.cases:,} (seed {args.seed}, brute force every {args.dt * 1e3:g} ms, {elapsed:.1f} s)")
    print(f"{'rule':8} {'worst case':10} {'violations':>11} {'(6/6 brakes)':>13} {'conservative':>13} {'R=1 share':>10}")
    for rule_name, r in rules.items():
        for model_name, (collides, _) in outcome.items():
            viol = r & collides
            free = ~collides
            cons = (~r & free).sum().item() / max(1, free.sum().item())
            print(f"{rule_name:8} {model_name:10} {viol.sum().item():>11,} {(viol & c['paper_brakes']).sum().item():>13,} "
                  f"{cons:>13.2%} {r.double().mean().item():>10.2%}")
    for model_name, (collides, min_gap) in outcome.items():
        bad = rules["literal"] & collides
        accel = models[model_name][1]
        print(f"literal counterexample ({model_name}, deepest): {counterexample(c, bad, min_gap, accel)}")
        print(f"literal counterexample ({model_name}, 6/6 brakes): "
              f"{counterexample(c, bad & c['paper_brakes'], min_gap, accel)}")


if __name__ == "__main__":
    main()
