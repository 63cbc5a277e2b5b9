"""Table 1 of the paper (§3.4), typed in once: the golden rows the rules' and the agents' tests check against.

Imported by name (tests/rules is on sys.path through its conftest and tests/agents' conftest).
"""

# No., R*_SV1, R*_SV3, R*_SV2, R*_SV4 -> a_F, a_S, a_I, a_L   (the paper's column order)
TABLE_1 = """
 1  1 1 1 1  1 1 1 1
 2  1 1 1 0  1 1 1 0
 3  1 1 0 1  1 1 1 0
 4  1 1 0 0  1 1 1 0
 5  1 0 1 1  1 0 1 1
 6  1 0 1 0  1 0 1 0
 7  1 0 0 1  1 0 1 0
 8  1 0 0 0  1 0 1 0
 9  0 1 1 1  0 1 0 1
10  0 1 1 0  0 1 0 0
11  0 1 0 1  0 1 0 0
12  0 1 0 0  0 1 0 0
13  0 0 1 1  0 0 0 1
14  0 0 1 0  0 0 1 0
15  0 0 0 1  0 0 1 0
16  0 0 0 0  0 0 1 0
"""


def rows():
    for line in TABLE_1.strip().splitlines():
        no, r1, r3, r2, r4, a_f, a_s, a_i, a_l = (int(v) for v in line.split())
        yield no, (r1, r2, r3, r4), {"Faster": a_f, "Slower": a_s, "Idle": a_i, "LaneChange": a_l}
