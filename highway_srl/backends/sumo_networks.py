"""SUMO networks of the four scenarios, built by netconvert from plain XML nodes, edges and connections.

Run `python -m highway_srl.backends.sumo_networks` to regenerate highway_srl/backends/sumo/*.net.xml (needs
the `sumo` extra: eclipse-sumo ships netconvert). The generated files are committed so that the backend
needs only libsumo at run time; if one is missing the backend regenerates it into a cache folder.

Geometry (all lanes straight, parallel to the x axis, 3.5 m wide; coordinates kept as written with
--offset.disable-normalization): SUMO's X is our x. Every edge's geometry line is the left border of its
leftmost lane at Y = 0 (SUMO spreads lanes to the right of the line), so our lane k (0 = leftmost) has its
centre at SUMO Y = -(k + 1/2) * w_L, i.e. our y = -Y - w_L / 2. SUMO numbers lanes from the right, so on an
edge with n lanes our lane k is SUMO lane n - 1 - k. A ramp is a one-lane edge whose line is at
Y = -mainline_lanes * w_L, i.e. exactly where our lane 2 is.

- two-lane / multi-lane: one edge `main` of 2 / 3 lanes.
- merge: `up` (2 lanes) and `ramp` (1 lane, our lane 2) end at x1 = 60 where `mrg` (3 lanes) begins; its
  rightmost lane has no successor at x2 = 160 (a lane drop), `down` (2 lanes) continues.
- exit: `up` (2 lanes) to x1 = 100, `div` (3 lanes) to x2 = 200, then `down` (2 lanes) and the off-ramp
  `off` (1 lane, our lane 2, to 300 and beyond) leave the same node; only div's rightmost lane leads to it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from highway_srl.constants import LANE_WIDTH_M, V_MAX_MPS
from highway_srl.scenarios import OFF_RAMP_END_M, SPECS, scenario_spec

NET_DIR = Path(__file__).with_name("sumo")
X_START_M = -400.0  # mainline start: room for the traffic behind the ego
X_END_M = 1600.0  # mainline end: a 40 s episode at 10 m/s plus the traffic ahead fits with room to spare
# OFF_RAMP_END_M (scenarios.py): the off-ramp edge runs past x3_suc (220 m) so success is reached before its end


@dataclass(frozen=True)
class EdgeSpec:
    id: str
    x_from: float
    x_to: float
    lanes: int
    first_lane: int  # our index of the edge's leftmost lane


def edges_of(scenario: str) -> tuple[EdgeSpec, ...]:
    """The edges of one scenario (its spec's sumo_edges) with our lane numbering; the network's start and
    end where the spec leaves them open. Raises ValueError naming the scenarios."""
    return tuple(EdgeSpec(e.id, X_START_M if e.x_from_m is None else e.x_from_m,
                          X_END_M if e.x_to_m is None else e.x_to_m, e.lanes, e.first_lane)
                 for e in scenario_spec(scenario).sumo_edges)


def links_of(scenario: str) -> tuple[tuple[str, int, str, int], ...]:
    """(from edge, our lane) -> (to edge, our lane): every lane-to-lane link; lanes not listed end there."""
    return scenario_spec(scenario).sumo_links


def _xml(scenario: str) -> tuple[str, str, str]:
    w = LANE_WIDTH_M
    edges = edges_of(scenario)
    nodes: dict[str, tuple[float, float]] = {}

    def node(x: float, y: float) -> str:
        for name, pos in nodes.items():
            if pos == (x, y):
                return name
        name = f"n{len(nodes)}"
        nodes[name] = (x, y)
        return name

    edge_lines = []
    for e in edges:
        y_line = -e.first_lane * w
        # ramps start and end at the mainline's node where they join or leave it (their own node only at the
        # network's ends); their shape keeps them straight at the lane-2 position
        a = node(e.x_from, 0.0 if e.first_lane == 0 or e.x_from != X_START_M else y_line)
        b = node(e.x_to, 0.0 if e.first_lane == 0 or e.x_to not in (X_END_M, OFF_RAMP_END_M) else y_line)
        shape = f'{e.x_from:.2f},{y_line:.2f} {e.x_to:.2f},{y_line:.2f}'
        edge_lines.append(
            f'    <edge id="{e.id}" from="{a}" to="{b}" numLanes="{e.lanes}" speed="{V_MAX_MPS:.2f}" '
            f'width="{w:.2f}" length="{e.x_to - e.x_from:.2f}" shape="{shape}" spreadType="right"/>'
        )
    node_lines = [f'    <node id="{n}" x="{x:.2f}" y="{y:.2f}" type="priority" radius="0" '
                  f'shape="{x:.2f},{y + 0.5:.2f} {x:.2f},{y - 3 * w - 0.5:.2f}"/>' for n, (x, y) in nodes.items()]
    by_id = {e.id: e for e in edges}
    con_lines = []
    for fe, fl, te, tl in links_of(scenario):
        f, t = by_id[fe], by_id[te]
        con_lines.append(
            f'    <connection from="{fe}" to="{te}" fromLane="{f.lanes - 1 - (fl - f.first_lane)}" '
            f'toLane="{t.lanes - 1 - (tl - t.first_lane)}"/>'
        )
    nod = "<nodes>\n" + "\n".join(node_lines) + "\n</nodes>\n"
    edg = "<edges>\n" + "\n".join(edge_lines) + "\n</edges>\n"
    con = "<connections>\n" + "\n".join(con_lines) + "\n</connections>\n"
    return nod, edg, con


def _sumo_tool(name: str) -> str:
    try:
        import sumo  # the eclipse-sumo wheel

        path = Path(sumo.SUMO_HOME) / "bin" / name
        if path.exists():
            return str(path)
    except ImportError:
        pass
    found = shutil.which(name)
    if found is None:
        raise RuntimeError(f"{name} not found; install the sumo extra: pip install 'highway-srl[sumo]'")
    return found


def netconvert_binary() -> str:
    return _sumo_tool("netconvert")


def sumo_binary() -> str:
    return _sumo_tool("sumo")


def build_network(scenario: str, out: Path) -> Path:
    """Write scenario's .net.xml to out (a file path) with netconvert; returns out."""
    nod, edg, con = _xml(scenario)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        (t / "n.nod.xml").write_text(nod)
        (t / "e.edg.xml").write_text(edg)
        (t / "c.con.xml").write_text(con)
        cmd = [
            netconvert_binary(),
            "--node-files", "n.nod.xml",
            "--edge-files", "e.edg.xml",
            "--connection-files", "c.con.xml",
            "--offset.disable-normalization", "true",
            "--no-internal-links", "true",  # lanes meet end to end; nobody drives through a junction area
            "--no-turnarounds", "true",
            "--junctions.corner-detail", "0",
            "--geometry.remove", "false",
            "--output.street-names", "false",
            "--output-file", "out.net.xml",
        ]
        res = subprocess.run(cmd, capture_output=True, text=True, cwd=t)
        if res.returncode != 0:
            raise RuntimeError(f"netconvert failed for {scenario}:\n{res.stderr}")
        text = (t / "out.net.xml").read_text()
    # drop the header comment (a time stamp and the temporary paths) so that regenerating is reproducible
    start, end = text.find("<!-- generated on"), text.find("-->")
    if start >= 0 and end > start:
        text = text[:start] + f"<!-- {scenario}: generated by highway_srl/backends/sumo_networks.py -->" + text[end + 3:]
    out.write_text(text)
    return out


def network_path(scenario: str) -> Path:
    """The committed network of a scenario, or a freshly built one in a cache folder if it is missing."""
    edges_of(scenario)  # validates the name
    path = NET_DIR / f"{scenario}.net.xml"
    if path.exists():
        return path
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "highway-srl" / "sumo"
    cached = cache / f"{scenario}.net.xml"
    return cached if cached.exists() else build_network(scenario, cached)


def main(argv: list[str] | None = None) -> int:
    out_dir = Path(argv[0]) if argv else NET_DIR
    for scenario in SPECS:
        path = build_network(scenario, out_dir / f"{scenario}.net.xml")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
