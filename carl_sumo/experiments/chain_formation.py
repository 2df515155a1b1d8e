"""Chains of CACC vehicles in mixed traffic: who follows whom, and what each CACC vehicle sees.

A chain is a run of consecutive CACC vehicles in one lane, each within the V2V range of the one
ahead (:func:`form_chains`); a human or a longer gap ends it. The observations come from SUMO's
``getLeader`` (:func:`cacc_observations`), and at a zipper merge a vehicle on the other feeding
lane nearer to the merge point counts as the vehicle ahead (:func:`merging_lanes`,
:func:`zipper_ahead`; :func:`zipper_aheads` for all of them, with the distance to the merge
point of those that have such a vehicle ahead). Used by the study loop of
:mod:`carl_sumo.study.run`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np


def form_chains(vehicles: Sequence[str], ahead: Sequence[tuple[str, float] | None],
                range_m: float) -> list[list[int]]:
    """Chains of consecutive CACC vehicles, head first, as indices into ``vehicles``.

    ``vehicles`` are the CACC vehicles on the network; ``ahead[i]`` is (id, bumper gap m) of the
    vehicle SUMO reports ahead of vehicle i in its lane, or None. Vehicle i follows j in a chain
    when j is CACC and the gap is at most ``range_m``; where two CACC vehicles report the same
    vehicle ahead (two lanes joining), the nearer one follows it. Every vehicle is in one chain.
    """
    index = {v: i for i, v in enumerate(vehicles)}
    claimed: dict[int, tuple[float, int]] = {}
    for i, item in enumerate(ahead):
        if item is None:
            continue
        j = index.get(item[0])
        if j is None or j == i or item[1] > range_m:
            continue
        best = claimed.get(j)
        if best is None or item[1] < best[0]:
            claimed[j] = (item[1], i)
    follower = {j: i for j, (_, i) in claimed.items()}
    linked = set(follower.values())
    chains, seen = [], set()
    for head in range(len(vehicles)):
        if head in linked:
            continue
        chain, cur = [head], head
        while cur in follower and follower[cur] not in seen:
            cur = follower[cur]
            chain.append(cur)
        seen.update(chain)
        chains.append(chain)
    chains.extend([i] for i in range(len(vehicles)) if i not in seen)  # cycles (not physical)
    return chains


def cacc_observations(cids: Sequence[str], speeds: Sequence[float],
                      accels: Sequence[float | None], ahead: Sequence[tuple[str, float] | None],
                      speed_of: dict[str, float], min_gap: dict[str, float],
                      sensor_range_m: float) -> tuple[np.ndarray, list[tuple[str, float] | None]]:
    """Observations o_i = [v, a, d, Δv] (m, 4) of CACC vehicles and their vehicle ahead.

    ``ahead[i]`` is SUMO's ``getLeader`` answer (id, gap without the follower's minGap) or None;
    d = that gap + minGap (bumper to bumper, m), Δv = v_ahead - v (m/s). Without a vehicle ahead
    within the sensing range, d = ``sensor_range_m`` and Δv = 0. Returns the observations and
    (id, bumper gap) of the vehicle ahead of each (None if none), for :func:`form_chains`.
    """
    obs = np.empty((len(cids), 4))
    chain_ahead: list[tuple[str, float] | None] = []
    for row, (vid, v, a, item) in enumerate(zip(cids, speeds, accels, ahead)):
        obs[row, 0] = v
        obs[row, 1] = a if a is not None else 0.0
        if item is None or item[0] == "":
            obs[row, 2], obs[row, 3] = sensor_range_m, 0.0
            chain_ahead.append(None)
        else:
            gap = item[1] + min_gap[vid]
            obs[row, 2], obs[row, 3] = gap, speed_of[item[0]] - v
            chain_ahead.append((item[0], gap))
    return obs, chain_ahead


def merging_lanes(net: str) -> dict[str, tuple[str, ...]]:
    """For every lane that shares its successor lane with other lanes (a zipper merge, such as
    ``i80_merge_0`` and ``i80_merge_1`` into ``i80_main_0``): those other lanes."""
    import sumolib

    feeders: dict[str, list[str]] = {}
    for edge in sumolib.net.readNet(str(net)).getEdges():
        for lane in edge.getLanes():
            for conn in lane.getOutgoing():
                feeders.setdefault(conn.getToLane().getID(), []).append(lane.getID())
    out: dict[str, tuple[str, ...]] = {}
    for lanes in feeders.values():
        if len(lanes) > 1:
            for lane in lanes:
                out[lane] = tuple(x for x in lanes if x != lane)
    return out


def zipper_ahead(ls, vid: str, lane: str, siblings: tuple[str, ...],
                 item: tuple[str, float] | None, min_gap_m: float,
                 range_m: float) -> tuple[str, float] | None:
    """The vehicle ahead of a CACC vehicle approaching a zipper merge, in ``getLeader`` form.

    SUMO's ``getLeader`` sees only the vehicle's own lane; a vehicle on a sibling lane that is
    nearer to the merge point will enter the same lane first, so it is a virtual vehicle ahead
    with gap = (ego's distance to the lane end) - (its distance to the lane end) - its length
    (as SUMO's zipper model does for its own drivers). Returns whichever of that and ``item`` is
    nearer; ties in distance to the merge point go to the smaller id.
    """
    get_pos, get_length = ls.vehicle.getLanePosition, ls.lane.getLength
    ego_rest = get_length(lane) - get_pos(vid)
    if ego_rest > range_m:
        return item
    best: tuple[str, float] | None = None
    for sibling in siblings:
        sib_length = get_length(sibling)
        for foe in ls.lane.getLastStepVehicleIDs(sibling):
            foe_rest = sib_length - get_pos(foe)
            if foe_rest < ego_rest or (foe_rest == ego_rest and foe < vid):
                gap = ego_rest - foe_rest - ls.vehicle.getLength(foe) - min_gap_m
                if best is None or gap < best[1]:
                    best = (foe, gap)
    if best is None or (item is not None and item[0] != "" and item[1] <= best[1]):
        return item
    return best


def zipper_aheads(ls, cids: Sequence[str], ahead: list[tuple[str, float] | None],
                  merging: dict[str, tuple[str, ...]], min_gap: dict[str, float],
                  range_m: float) -> dict[str, float]:
    """:func:`zipper_ahead` for every CACC vehicle ``cids`` on a merging lane, ``ahead`` (its
    ``getLeader`` answers) updated in place. Returns, for the vehicles whose vehicle ahead is now
    one on the other feeding lane, their distance to the merge point (m): the end of their lane."""
    merge_m: dict[str, float] = {}
    for row, vid in enumerate(cids):
        lane = ls.vehicle.getLaneID(vid)
        if lane in merging:
            own = ahead[row]
            ahead[row] = zipper_ahead(ls, vid, lane, merging[lane], own, min_gap[vid], range_m)
            if ahead[row] is not own:
                merge_m[vid] = ls.lane.getLength(lane) - ls.vehicle.getLanePosition(vid)
    return merge_m
