"""World(processes=P): the envs stepped in worker processes run the same episodes as one process, bit for bit."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import fields

import pytest
import torch

from highway_srl.sim import HOLD_LANE, World
from highway_srl.sim.ego_driver import idm_ego
from highway_srl.sim.events import STEP_EVENT_DTYPES
from highway_srl.sim.processes import slices

ENVS = 7  # not a multiple of the processes: slices of unequal size


def _pair(scenario, adversary=None, traffic="D", processes=3):
    kw = dict(adversarial=adversary is not None, adversary=adversary or "mild", num_envs=ENVS, seed=5,
              max_steps=60)  # episodes end within the tests: resets are stepped too
    return World(scenario, traffic, **kw), World(scenario, traffic, processes=processes, **kw)


def _same(a: World, b: World, where: str) -> None:
    for f in fields(a.state):
        assert torch.equal(getattr(a.state, f.name), getattr(b.state, f.name)), f"{where}: state.{f.name}"


def _same_events(ea, eb, where: str) -> None:
    for f in fields(ea):
        assert torch.equal(getattr(ea, f.name), getattr(eb, f.name)), f"{where}: events.{f.name}"


def _commands(world: World, t: int):
    lane, speed = idm_ego(world)
    if t % 9 == 0:  # lane commands now and then, so that changes are made and refused
        lane = (world.ego_lane + 1) % 2
    if t % 9 == 2:  # and a lateral hold in the middle of a change
        lane = torch.full_like(lane, HOLD_LANE)
    return lane, speed


@pytest.mark.parametrize("scenario,adversary", [("two-lane", None), ("multi-lane", "mild"), ("merge", "paper"),
                                                ("exit", "paper")])
def test_processes_run_the_episodes_of_one_process_bit_for_bit(scenario, adversary):
    a, b = _pair(scenario, adversary)
    try:
        _same(a, b, "spawn")
        for t in range(150):
            lane, speed = _commands(a, t)
            _same_events(a.step_and_reset(lane, speed), b.step_and_reset(lane, speed), f"step {t}")
        _same(a, b, "after 150 steps")
        assert int(a.state.episode.sum()) > 0, "no env reached a reset: the test would not check resets"
    finally:
        b.close()


def test_every_entry_point_and_setting_reaches_the_workers():
    a, b = _pair("two-lane", "mild")
    try:
        for w in (a, b):  # settings changed after construction go with each call
            w.static = True
            w.max_steps = 40
        for t in range(30):
            lane, speed = _commands(a, t)
            _same_events(a.step(lane, speed), b.step(lane, speed), f"static step {t}")
        mask = torch.tensor([True, False, True, False, False, True, False])
        a.reset_where(mask), b.reset_where(mask)
        _same(a, b, "reset_where")
        for w in (a, b):
            w.static, w.adversarial = False, False
        for t in range(60):
            lane, speed = _commands(a, t)
            ea, eb = a.step(lane, speed), b.step(lane, speed)
            _same_events(ea, eb, f"step {t}")
            a.reset(ea.terminated | ea.truncated), b.reset(eb.terminated | eb.truncated)
        a.reset(), b.reset()
        _same(a, b, "reset of every env")
    finally:
        b.close()


def test_the_state_edited_or_replaced_here_is_what_the_workers_step():
    a, b = _pair("merge")
    other = World("merge", "D", num_envs=ENVS, seed=99)
    try:
        for w in (a, b):
            w.state.v[:, 0] = 3.0  # an edit in place, as tests and tools make
        a.state, b.state = other.state.clone(), other.state.clone()  # as a resumed trainer does
        for t in range(40):
            lane, speed = _commands(a, t)
            _same_events(a.step_and_reset(lane, speed), b.step_and_reset(lane, speed), f"step {t}")
        _same(a, b, "after replacing the state")
        with pytest.raises(ValueError, match="state field x has shape"):
            b.state = World("merge", "D", num_envs=ENVS + 1, seed=0).state
    finally:
        b.close()


def test_a_view_steps_its_envs_of_the_world_in_place():
    whole, part = World("exit", "D", num_envs=ENVS, seed=2), World("exit", "D", num_envs=ENVS, seed=2)
    view = part.envs_view(2, 5)
    for t in range(30):
        lane, speed = _commands(whole, t)
        whole.step_and_reset(lane, speed)
        view.step_and_reset(lane[2:5], speed[2:5])
    for f in fields(whole.state):
        assert torch.equal(getattr(whole.state, f.name)[2:5], getattr(part.state, f.name)[2:5]), f.name
    assert torch.equal(part.state.t[:2], torch.zeros(2, dtype=torch.long)), "envs outside the view moved"
    with pytest.raises(ValueError, match="envs_view needs 0 <= lo < hi <= 7"):
        part.envs_view(3, 3)


def test_the_workers_event_buffers_have_the_fields_and_dtypes_of_a_step():
    events = World("merge", "C", num_envs=3, seed=1).step(torch.zeros(3, dtype=torch.long), torch.full((3,), 20.0))
    assert {f.name: getattr(events, f.name).dtype for f in fields(events)} == STEP_EVENT_DTYPES


def test_slices_cover_the_batch_in_near_equal_parts():
    assert slices(7, 3) == [(0, 2), (2, 4), (4, 7)]
    assert slices(4096, 2) == [(0, 2048), (2048, 4096)]
    assert slices(5, 5) == [(i, i + 1) for i in range(5)]


@pytest.mark.parametrize("kwargs,message", [
    (dict(processes=0), "processes must be an integer between 1 and num_envs"),
    (dict(processes=ENVS + 1), "processes must be an integer between 1 and num_envs"),
    (dict(processes=2.0), "processes must be an integer"),
    (dict(processes=2, compile="eager"), "processes > 1 steps eager worlds on the CPU"),
])
def test_bad_processes_are_refused_in_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message):
        World("two-lane", "C", num_envs=ENVS, **kwargs)


def test_a_killed_worker_is_an_error_not_a_hang_and_close_ends_them():
    w = World("two-lane", "C", num_envs=ENVS, processes=3)
    pids = w.worker_pids
    assert len(pids) == 2, "this process steps the first slice, one worker each of the others"
    os.kill(pids[1], signal.SIGKILL)
    with pytest.raises(RuntimeError, match=r"world process .* exited"):
        w.step_and_reset(w.ego_lane, torch.full((ENVS,), 20.0))
    assert not [pid for pid in pids if _running(pid)], "a worker was left running"
    with pytest.raises(RuntimeError, match="closed"):
        w.step(w.ego_lane, torch.full((ENVS,), 20.0))
    w.close()  # twice is fine


def test_an_interrupt_during_a_step_closes_the_world_instead_of_leaving_it_half_stepped(monkeypatch):
    w = World("two-lane", "C", num_envs=ENVS, processes=2)
    pids = w.worker_pids
    plain = World.step_and_reset

    def interrupted(world, lane, speed):  # this process's own slice (a view) is hit by Ctrl-C
        if world.num_envs < ENVS:
            raise KeyboardInterrupt
        return plain(world, lane, speed)

    monkeypatch.setattr(World, "step_and_reset", interrupted)  # after the fork: the worker steps as before
    with pytest.raises(KeyboardInterrupt):
        w.step_and_reset(w.ego_lane, torch.full((ENVS,), 20.0))
    with pytest.raises(RuntimeError, match="closed"):  # not a step on top of a half-stepped state
        w.step(w.ego_lane, torch.full((ENVS,), 20.0))
    assert not [pid for pid in pids if _running(pid)], "a worker was left running"


CHILD = """
import sys, time, torch
from highway_srl.sim import World
w = World("two-lane", "C", num_envs=4, processes=3)
w.step_and_reset(w.ego_lane, torch.full((4,), 20.0))
print(" ".join(map(str, w.worker_pids)), flush=True)
time.sleep(60)
"""


def test_workers_end_when_their_parent_is_killed():
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    parent = subprocess.Popen([sys.executable, "-c", CHILD], stdout=subprocess.PIPE, text=True, env=env)
    try:
        pids = [int(p) for p in parent.stdout.readline().split()]
        assert len(pids) == 2
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 15
    alive = pids
    while alive and time.monotonic() < deadline:
        time.sleep(0.2)
        alive = [pid for pid in alive if _running(pid)]
    assert not alive, f"workers {alive} outlived their parent"


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[-1][0] != "Z"  # a zombie has ended (its reaper is gone)
    except FileNotFoundError:
        return False
