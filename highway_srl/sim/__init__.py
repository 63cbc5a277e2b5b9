"""Batched highway world (no knowledge of the rules or the agents)."""

from highway_srl.sim.road import Road, make_road
from highway_srl.sim.snapshot import LANE_END, NO_VEHICLE, Snapshot
from highway_srl.sim.events import StageFlags, StepEvents
from highway_srl.sim.device import check_device
from highway_srl.sim.world import World
from highway_srl.sim.ego import HOLD_LANE

__all__ = ["Road", "make_road", "Snapshot", "LANE_END", "NO_VEHICLE", "World", "StepEvents", "StageFlags", "check_device",
           "HOLD_LANE"]
