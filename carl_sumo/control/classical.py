"""The classical laws by name: one dispatch for every command that runs a platoon.

``ploeg*``, ``acc*`` and ``mpf`` are the constant-time-gap laws of :mod:`carl_sumo.control.cacc`;
``mpc`` (``mpc-tuned``: its weights tuned for a plant) is the distributed MPC of
:mod:`carl_sumo.control.mpc`. A platoon runs either through
the same interface (``reset``, ``know_vehicles``, ``connect``, ``acceleration``), and the chains
of CACC vehicles in traffic (the study, the scenarios) through that of
:class:`carl_sumo.control.cacc.PloegChains`."""

from __future__ import annotations

from carl_sumo.control.cacc import PloegChains, PloegController, is_ploeg_name, parse_ploeg, \
    ploeg_controller
from carl_sumo.control.mpc import MPCChains, MPCController, is_mpc_name, mpc_chains, \
    mpc_controller, parse_mpc
from carl_sumo.control.ploeg_names import tuned_gap
from carl_sumo.errors import InputError


def is_classical_name(name: str) -> bool:
    """Whether ``name`` names a classical law (a constant-time-gap law or the MPC)."""
    return is_ploeg_name(name) or is_mpc_name(name)


def classical_controller(name: str, plant: str = "ideal") -> PloegController | MPCController:
    """The platoon controller of a classical law's name (a ``-tuned`` name: the gains tuned for
    ``plant``); InputError, one line, for a bad name."""
    if is_mpc_name(name):
        return mpc_controller(name, plant)
    if is_ploeg_name(name):
        return ploeg_controller(name, plant=plant)
    raise InputError(f"{name!r} is not a classical law (ploeg, acc, mpf, mpc)")


def classical_chains(name: str, plant: str = "ideal") -> PloegChains | MPCChains:
    """The chains controller of a classical law's name (study, scenarios); InputError, one
    line, for a bad name."""
    if is_mpc_name(name):
        return mpc_chains(name, plant)
    if is_ploeg_name(name):
        return PloegChains(parse_ploeg(name, plant=plant), name)
    raise InputError(f"{name!r} is not a classical law (ploeg, acc, mpf, mpc)")


def time_gap_of(name: str) -> tuple[float, float]:
    """(s0 m, h s) of a classical law's name: the spacing s0 + h·v it keeps in a chain."""
    if is_mpc_name(name):
        from carl_sumo.control.mpc import STANDSTILL_GAP_M

        if name.split(":")[0] == "mpc-tuned":  # its gap, whichever plant's weights it runs
            return STANDSTILL_GAP_M, tuned_gap(name)
        return STANDSTILL_GAP_M, parse_mpc(name).time_gap_s
    p = parse_ploeg(name)
    return p.standstill_gap_m, p.time_gap_s
