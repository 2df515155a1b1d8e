from pathlib import Path

from carl_sumo.sim.network import NET_FILE, build_network, network_body
from carl_sumo.sim.sumo import lane_route


def test_regenerated_network_matches_committed(tmp_path: Path):
    out = build_network(out=tmp_path / "i80.net.xml")
    assert network_body(out) == network_body(NET_FILE)


def test_i80_has_six_lanes_an_onramp_merge_and_6km():
    import sumolib

    net = sumolib.net.readNet(str(NET_FILE))
    route = lane_route(NET_FILE, ngsim_lane=2)
    assert route.edges == ("i80_approach", "i80_merge", "i80_main")
    assert route.length_m >= 6000.0
    assert [net.getEdge(e).getLaneNumber() for e in route.edges] == [6, 7, 6]
    ramp = net.getEdge("powell_onramp")
    assert ramp.getToNode().getID() == net.getEdge("i80_merge").getFromNode().getID()
    # NGSIM lane 2 is SUMO index 4 on 6-lane edges, 5 on the merge edge (auxiliary lane = 0)
    assert route.lanes == ("i80_approach_4", "i80_merge_5", "i80_main_4")
    assert lane_route(NET_FILE, ngsim_lane=1).lanes[0] == "i80_approach_5"
