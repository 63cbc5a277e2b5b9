"""The paper's constants (Tables 2-4, §4.1) in one place.

Every other module reads its defaults from here, so a value from the paper is written once.
Units are in the names: _m metres, _s seconds, _mps m/s, _mps2 m/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass

# Table 2 and §4.1
DT_S = 0.125  # simulation step and reaction time δt
EPISODE_STEPS = 320
LANE_WIDTH_M = 3.5  # w_L
V_MAX_MPS = 10.0  # v_x,max, the ego's speed limit and the road's posted limit
D_MAX_M = 50.0  # perception range d_max
VEHICLE_LENGTH_M = 5.0  # L
VEHICLE_WIDTH_M = 2.0  # B
EGO_ACCEL_MAX_MPS2 = 3.5  # a_EV,A,max
EGO_BRAKE_MAX_MPS2 = 6.0  # |a_EV,D,max|
SV_BRAKE_MAX_MPS2 = 6.0  # |a_SV,D,max| used by the SD rule unless configured otherwise
D_ML_M = 1.75  # lane-centreline tolerance d_ML
EPS_P_M = 0.5  # rule mapping corner-point threshold ε_p
EPS_D_M = 0.6  # rule mapping centre-point threshold ε_d
SV_INIT_SPEED_MPS = (5.0, 6.0)  # surrounding traffic starts at U[5, 6] m/s

# Table 2 (learning)
LEARNING_RATE = 1e-4
GAMMA = 0.99
BATCH_SIZE = 256
TOTAL_STEPS = 500_000
OBS_DIM = 37  # 25 vehicle numbers + C_ID, m_L*, T_ID*, v* + R*_SV1..4 + RM state one-hot (u1..u4)


@dataclass(frozen=True)
class DrivingStyle:
    """One column of Table 3."""

    name: str
    desired_headway_m: float  # DH: L, 2L, 3L
    speed_violation: float  # SVR: desired speed = (1 + SVR) * v_max
    lane_change: bool  # ALC
    adversarial_prob: float  # ABP


STYLES: tuple[DrivingStyle, ...] = (
    DrivingStyle("aggressive", 1 * VEHICLE_LENGTH_M, +0.30, True, 1 / 9),
    DrivingStyle("normal", 2 * VEHICLE_LENGTH_M, -0.30, False, 0.0),
    DrivingStyle("cautious", 3 * VEHICLE_LENGTH_M, 0.0, True, 1 / 27),
)
STYLE_NAMES = tuple(s.name for s in STYLES)


@dataclass(frozen=True)
class TrafficLevel:
    """One row of Table 4: number of surrounding vehicles and initial headway range (bumper to bumper)."""

    name: str
    num_vehicles: int
    headway_m: tuple[float, float]


TRAFFIC_LEVELS: dict[str, TrafficLevel] = {
    "A": TrafficLevel("A", 8, (20.0, 30.0)),
    "B": TrafficLevel("B", 16, (15.0, 25.0)),
    "C": TrafficLevel("C", 24, (10.0, 20.0)),
    "D": TrafficLevel("D", 32, (8.0, 16.0)),
    "E": TrafficLevel("E", 40, (6.0, 12.0)),
    "F": TrafficLevel("F", 44, (5.0, 10.0)),
}

SCENARIOS = ("two-lane", "multi-lane", "merge", "exit")

# The rule layer and the adversary of every entry point (train, evaluate, reproduce, the study, the Gymnasium
# and SB3 envs) and the defaults of the library's World and SafetyLayer (what bench sim and play run): the
# reproduction's, so that a result from any of them compares with the paper's tables. Defaults rather than
# required arguments: with one value everywhere, leaving an argument out runs what every entry point runs (no
# default misleads), and any other value is named where it is passed.
# "paper": Eqs. 31-35 as printed (rules.PROFILES); "paper": §4.3's cut-ins as printed (sim.adversary.ADVERSARIES).
DEFAULT_PROFILE = "paper"
DEFAULT_ADVERSARY = "paper"

# Adversarial cut-in (group 3): |d_trig - d_SVi| is drawn from these per SV and episode.
ADVERSARIAL_TRIGGER_OFFSETS_M = (0.0, 5.0, 10.0)
