"""What each of the ego's collisions was, read from the world's state as the colliding step left it.

Why: a collision-free rate says how often, not what happened. At the gridlocked levels a share of the
episodes ends in a collision; whether the ego drove into a car ahead, was hit from behind, touched a car
beside it, or left the road (a lane end, a barrier), and who was changing lanes, says where the cause lies:
the policy, the rule layer, or the traffic. Collected through run_episodes' after_step hook in every
evaluation on our simulator (eval.json's levels[...]["collisions"], the study's collisions table,
scripts/collision_census.py), so the episodes are exactly the deployment's.

Classification (documented in docs/paper-notes.md, "Collision census"): the SV that overlaps the ego, the
nearest if several; in the ego's frame, "side" if the SV's centre is offset sideways by more than half a
car width (they met side-on or at an angle), else "front" (the ego ran into it) or "rear" (it ran into the
ego) by the sign of the longitudinal offset; "road" if no SV overlaps (a lane end, a barrier across a
boundary, the road's edge). A vehicle is changing lanes if its target lane is not its lane or its centre
is more than 0.5 m off its lane's centre; an SV's forced (group-3) cut-in is named as such.
"""

from __future__ import annotations

import collections

import torch

from highway_srl.constants import VEHICLE_WIDTH_M
from highway_srl.rules.avoidable import OFF_CENTRE_M, ego_avoidable
from highway_srl.sim.box_geometry import boxes_overlap


def classify(world, envs: torch.Tensor) -> list[dict]:
    """One record per env index in envs (M,): kind (front, rear, side, road), ego_changing, sv ('changing',
    'forced cut-in' or 'keeping lane'; None for road), the ego's and the SV's speeds (m/s) and, for a
    vehicle, its index in the world (sv_index)."""
    s, w = world.state, world.road.lane_width_m
    b = envs.to(s.x.device)
    x0, y0, h0 = s.x[b, :1], s.y[b, :1], s.heading[b, :1]
    hit = boxes_overlap(x0, y0, h0, s.x[b, 1:], s.y[b, 1:], s.heading[b, 1:])  # (M, N - 1)
    dist = torch.where(hit, (s.x[b, 1:] - x0).abs() + (s.y[b, 1:] - y0).abs(), torch.inf)
    j = dist.argmin(1) + 1  # the nearest overlapping SV (column 0 is the ego)
    c, sn = torch.cos(h0[:, 0]), torch.sin(h0[:, 0])
    dx, dy = s.x[b, j] - x0[:, 0], s.y[b, j] - y0[:, 0]
    lon, lat = dx * c + dy * sn, -dx * sn + dy * c

    def changing(i):
        off = (s.y[b, i] - s.lane[b, i].float() * w).abs() > OFF_CENTRE_M
        return (s.target_lane[b, i] != s.lane[b, i]) | off

    ego_changing, sv_changing = changing(torch.zeros_like(j)), changing(j)
    records = []
    for m in range(b.numel()):
        rec = {"ego_changing": bool(ego_changing[m]), "ego_speed": float(s.v[b[m], 0])}
        if not bool(hit[m].any()):
            rec.update(kind="road", sv=None, sv_speed=None)
        else:
            kind = "side" if abs(float(lat[m])) > 0.5 * VEHICLE_WIDTH_M else ("front" if float(lon[m]) > 0 else "rear")
            sv = "forced cut-in" if bool(s.forced[b[m], j[m]]) else ("changing" if bool(sv_changing[m]) else "keeping lane")
            rec.update(kind=kind, sv=sv, sv_speed=float(s.v[b[m], j[m]]), sv_index=int(j[m]))
        records.append(rec)
    return records


class Census:
    """Collects classify() records of the ego's collisions, per traffic level, through run_episodes'
    after_step hook: `run_episodes(world, method, learner, after_step=census.level("C"))` (evaluate_run does
    this for every level on our simulator and writes the summary into eval.json's levels)."""

    def __init__(self) -> None:
        self.records: dict[str, list[dict]] = collections.defaultdict(list)

    def level(self, traffic: str):
        self.records.setdefault(traffic, [])  # a level without collisions is reported too

        def after_step(world, events, alive) -> None:
            new = events.collision & alive  # this step's collisions of episodes still running
            if bool(new.any()):
                self.records[traffic].extend(classify(world, new.nonzero().squeeze(1)))
        return after_step

    def summary(self) -> dict:
        """summarise() of each level's records."""
        return {traffic: summarise(recs) for traffic, recs in self.records.items()}


def summarise(records: list[dict]) -> dict:
    """Collisions, counts by kind, by kind and who was changing lanes, the counts of the study's table
    (while the ego changed lanes, SV changing, SV in a forced cut-in) and mean speeds at contact."""
    by_kind = collections.Counter(r["kind"] for r in records)
    by_detail = collections.Counter(
        f"{r['kind']}; ego {'changing' if r['ego_changing'] else 'keeping lane'}" + (f"; SV {r['sv']}" if r["sv"] else "")
        for r in records)
    return {"collisions": len(records), "by_kind": dict(by_kind.most_common()),
            "by_detail": dict(by_detail.most_common()),
            "while_ego_changing": sum(r["ego_changing"] for r in records),
            "sv_changing": sum(r["sv"] == "changing" for r in records),
            "sv_forced_cut_in": sum(r["sv"] == "forced cut-in" for r in records),
            "mean_ego_speed": _mean([r["ego_speed"] for r in records]),
            "mean_sv_speed": _mean([r["sv_speed"] for r in records if r["sv_speed"] is not None])}


def _mean(values: list[float]) -> float | None:
    return round(sum(values) / len(values), 2) if values else None


# --------------------------------------------------------------------------- through which decision
FORBIDDEN, LANE_CHANGE_CYCLE, CREEP, OTHER = (
    "unshielded: a forbidden action executed", "lane change kept the speed, R*1 = 0",
    "Faster or Idle allowed, gap < 0.5 m", "other")
DECISION_CLASSES = (FORBIDDEN, LANE_CHANGE_CYCLE, CREEP, OTHER)  # in the order classify tries them
CREEP_GAP_M = 0.5  # below this bumper gap the printed safe distance is about zero near standstill
CLASS_WINDOW = 8  # decisions (1 s) the decision class reads
# decisions (3 s) the ego-avoidable verdict reads: where the hit car entered the ego's path and whether the
# ego moved sideways toward it; 1 s missed an adversarial cut-in begun alongside 1.1 s before the contact
VERDICT_WINDOW = 24


class DecisionTrace:
    """What the rule layer allowed and what was executed in the last `window` steps before each collision,
    kept through run_episodes' on_transition hook (evaluate_run, scripts/collision_trace.py).

    Why: the census says what was hit; a shielded method's collision also has a decision the shield let
    through, and which one says where the gap is (Table 1, the control mapping, the safe distance). Each
    collision gets the first of DECISION_CLASSES that the env's last CLASS_WINDOW decisions match: an action the
    method's own safe mask forbade (a method without the gate: what it ran into is its policy's, not the
    shield's); a lane change (LaneChange; LaneLeft / LaneRight of A) allowed and executed while R*1 = 0
    (Table 1 allows it on R*2 ∧ R*4 alone and the paper's control mapping holds the speed through it);
    Faster or Idle allowed and executed with R*1 = 1 at a bumper gap under CREEP_GAP_M; other.
    `records`: one dict per collision, in order: env, step, class, and the decisions (one dict per step).

    after_step(world, events, alive), run_episodes' other hook, adds the ego-avoidable verdict
    (rules.avoidable): it keeps the world's positions and speeds of the last `window` steps, classifies each
    new collision (classify: kind, who was changing lanes, the vehicle hit) and gives every decision row the
    hit vehicle's offsets (dx, dy) and speed (v_sv) in the state the decision was taken in; the record gets
    kind, ego_changing, sv_changing, ego_avoidable (bool) and reason. verdicts() counts them.

    A loop that must not read the device every step (the trainer's compact step) calls keep_decision and
    keep_state each step (device clones only), judge_ended where episodes end, before the reset (the records
    of that step's collisions, judged, handed over and not kept), and episodes_restart after it."""

    def __init__(self, method, window: int = VERDICT_WINDOW) -> None:
        if window < 1:
            raise ValueError(f"window must be positive, got {window}")
        self.method, self.step, self.records = method, 0, []
        self._recent: collections.deque = collections.deque(maxlen=window)
        self._states: collections.deque = collections.deque(maxlen=window + 1)  # (step, x, y, v, h) after a step
        self._start: torch.Tensor | None = None  # (B,) each env's first decision of its episode (episodes_restart)

    def __call__(self, view, t, alive) -> None:
        self.keep_decision(view, t.decision)
        new = t.events.collision & alive
        if bool(new.any()):  # an analysis hook: one host read per step, as the census's
            self._record(new.nonzero().flatten().tolist())

    def keep_decision(self, view, decision) -> None:
        """Keep this step's decision (clones on the device; no host read)."""
        model = view.select(decision.use_second)
        snap = view.snapshot
        self._recent.append({"step": self.step, **{k: v.clone() for k, v in (  # buffers may be reused
            ("action", decision.action), ("mask", self.method.safe_mask(model)), ("r1", model.r_star[:, 0]),
            ("gap1", model.gaps_m[:, 0]), ("v", snap.ego_vx), ("v1", model.vehicles.vx[:, 0]), ("x", snap.ego_x),
            ("y", snap.ego_y), ("h", snap.ego_heading), ("lane", snap.ego_lane), ("m", model.m_l_ego))}})
        self.step += 1

    def _record(self, envs: list[int]) -> None:
        names = self.method.action_names
        for env in envs:
            first = 0 if self._start is None else int(self._start[env])  # decisions of this episode only
            rows = [{"step": r["step"], "action": names[int(r["action"][env])],
                     "allowed": [n for i, n in enumerate(names) if bool(r["mask"][env, i])],
                     **{k: float(r[k][env]) for k in ("gap1", "v", "v1", "x", "y", "h")},
                     "r1": bool(r["r1"][env]), "lane": int(r["lane"][env]), "m": bool(r["m"][env])}
                    for r in self._recent if r["step"] >= first]
            self.records.append({"env": env, "step": self.step - 1, "class": classify_decisions(rows[-CLASS_WINDOW:]),
                                 "decisions": rows})

    def after_step(self, world, events, alive) -> None:
        """Judge this step's collisions (the records __call__ just made) against the kept states."""
        self.keep_state(world)
        new = events.collision & alive
        if bool(new.any()):
            self._judge_envs(world, new.nonzero().flatten())

    def keep_state(self, world) -> None:
        """Keep the world's positions, speeds and headings after this step (device clones; no host read)."""
        s = world.state
        self._states.append((self.step - 1, s.x.clone(), s.y.clone(), s.v.clone(), s.heading.clone()))

    def _judge_envs(self, world, envs: torch.Tensor) -> None:
        by_env = {rec["env"]: rec for rec in self.records if rec["step"] == self.step - 1 and "kind" not in rec}
        for env, hit in zip(envs.tolist(), classify(world, envs)):
            rec = by_env.get(env)
            if rec is not None:
                self._judge(rec, hit)

    def episodes_restart(self, world, done: torch.Tensor) -> None:
        """The envs where done (B,) bool were reset after this step's keep_state: their next decision starts an
        episode (earlier ones are not its), taken in the world's state as the reset left it, which replaces
        the kept one (the other envs' states are unchanged by the reset). Device operations only."""
        s = world.state
        if self._states:
            self._states[-1] = (self._states[-1][0], s.x.clone(), s.y.clone(), s.v.clone(), s.heading.clone())
        start = self._start if self._start is not None else torch.zeros_like(done, dtype=torch.long)
        self._start = torch.where(done, torch.full_like(start, self.step), start)

    def judge_ended(self, world, collision: torch.Tensor) -> list[dict]:
        """For a loop that reads the device only where episodes end (the trainer's compact step): after
        keep_decision and keep_state of a step, the judged records of its collisions (collision (B,) bool),
        handed over rather than kept. The world must still hold the colliding state (before any reset)."""
        if not bool(collision.any()):
            return []
        envs = collision.nonzero().flatten()
        first = len(self.records)
        self._record(envs.tolist())
        self._judge_envs(world, envs)
        new = self.records[first:]
        del self.records[first:]
        return new

    def _judge(self, rec: dict, hit: dict) -> None:
        states = {step: rest for step, *rest in self._states}
        env, j = rec["env"], hit.get("sv_index")
        for row in rec["decisions"]:
            before = states.get(row["step"] - 1)  # the state the decision was taken in
            if j is None or before is None:
                row.update(dx=None, dy=None, v_sv=None, h_sv=None)
                continue
            x, y, v, h = before
            row.update(dx=float(x[env, j] - x[env, 0]), dy=float(y[env, j] - y[env, 0]), v_sv=float(v[env, j]),
                       h_sv=float(h[env, j]))
        sv_changing = hit["sv"] in ("changing", "forced cut-in")
        avoidable, reason = ego_avoidable(hit["kind"], hit["ego_changing"], sv_changing, rec["decisions"])
        rec.update(kind=hit["kind"], ego_changing=hit["ego_changing"], sv_changing=sv_changing,
                   ego_avoidable=avoidable, reason=reason)

    def verdicts(self) -> dict:
        """The judged collisions: ego_avoidable and unavoidable counts and the count of each reason."""
        judged = [rec for rec in self.records if "ego_avoidable" in rec]
        return {"ego_avoidable": sum(rec["ego_avoidable"] for rec in judged),
                "unavoidable": sum(not rec["ego_avoidable"] for rec in judged),
                "by_reason": dict(collections.Counter(rec["reason"] for rec in judged).most_common())}

    def counts(self) -> dict[str, int]:
        """Every collision's class, counted (all of DECISION_CLASSES, zeros included)."""
        out = dict.fromkeys(DECISION_CLASSES, 0)
        for rec in self.records:
            out[rec["class"]] += 1
        return out


def classify_decisions(rows: list[dict]) -> str:
    """The first of DECISION_CLASSES that a collision's last decisions (DecisionTrace's rows) match."""
    if any(r["action"] not in r["allowed"] for r in rows):
        return FORBIDDEN
    if any(r["action"].startswith("Lane") and not r["r1"] for r in rows):  # A*'s LaneChange or A's two
        return LANE_CHANGE_CYCLE
    if any(r["action"] in ("Faster", "Idle") and r["r1"] and r["gap1"] < CREEP_GAP_M for r in rows):
        return CREEP
    return OTHER


def show_decisions(record: dict) -> str:
    """A DecisionTrace record as text: the collision, then its last decisions one line each."""
    verdict = "" if "reason" not in record else \
        f"; {'ego-avoidable' if record['ego_avoidable'] else 'unavoidable'}: {record['reason']}"
    lines = [f"env {record['env']}: collision in step {record['step']} ({record['class']}{verdict})"]
    for r in record["decisions"]:
        lines.append(f"  step {r['step']:3d} x {r['x']:7.1f} y {r['y']:5.2f} lane {r['lane']} m*_L {int(r['m'])} "
                     f"v {r['v']:5.2f} | ahead: gap {r['gap1']:6.2f} m v {r['v1']:5.2f} R*1 {int(r['r1'])} | "
                     f"allowed {','.join(r['allowed']):<28s} executed {r['action']}")
    return "\n".join(lines)
