"""Vehicle dynamics: the step response is the first-order lag formula, τ = 0 is today's plant bit
for bit, SUMO's own Plexe CC engine model (an independent reference) realises the same
accelerations, the fleet draws are seeded, and bad plant options are one line and exit 2."""

from __future__ import annotations

import numpy as np
import pytest

from carl_sumo.cli import main
from carl_sumo.config import DT_S
from carl_sumo.data import load_events
from carl_sumo.errors import InputError
from carl_sumo.experiments.simulate import run_event, resolve_controller
from carl_sumo.control.channel import Impairments
from carl_sumo.sim.sumo import PlatoonSim, close_sumo, lane_route, start_sumo
from carl_sumo.sim.vehicle import VEHICLE_CLASSES, Plant, Powertrains, parse_fleet

from conftest import NET


def _powertrains(tau: float, dead: int, a_max: float = 3.0, b_max: float = 9.0) -> Powertrains:
    return Powertrains(["car"], np.array([tau]), np.array([dead]), np.array([a_max]),
                       np.array([b_max]), np.array([5.0]), ["cacc"])


@pytest.mark.parametrize("tau,dead", [(0.5, 0), (0.1, 0), (0.3, 2), (0.0, 1)])
def test_step_response_is_the_first_order_lag_with_dead_time(tau, dead):
    pt = _powertrains(tau, dead)
    alpha = DT_S / (tau + DT_S)
    a, got, want = 0.0, [], []
    commands = [1.0] * 30 + [-2.0] * 30
    for k, _ in enumerate(commands):
        got.append(float(pt.step(np.array([commands[k]]))[0]))
        c = commands[k - dead] if k >= dead else 0.0
        a = alpha * c + (1 - alpha) * a
        want.append(a)
    assert np.max(np.abs(np.array(got) - want)) < 1e-9


def test_commands_and_accelerations_are_clipped_to_the_vehicle():
    truck = VEHICLE_CLASSES["truck"]
    pt = _powertrains(0.0, 0, truck.a_max_mps2, truck.b_max_mps2)
    assert pt.step(np.array([3.0]))[0] == truck.a_max_mps2
    assert pt.step(np.array([-9.0]))[0] == -truck.b_max_mps2


def _run(controller: str, impairments: Impairments | None, events) -> list:
    follower_model, ctrl = resolve_controller(controller)
    sim = PlatoonSim(NET, follower_model)
    out = [run_event(sim, e, 5, ctrl, impairments=impairments) for e in events]
    close_sumo()
    return out


def test_a_plant_with_no_lag_and_no_dead_time_is_the_ideal_plant_bit_for_bit():
    events = load_events("default", "test")[:3]
    zero = Impairments(plant=Plant((("car", 1.0),), 0.0, 0.0))
    for controller in ("ploeg:h=0.8", "idm-external"):
        ideal, lagless = _run(controller, None, events), _run(controller, zero, events)
        for a, b in zip(ideal, lagless):
            assert np.array_equal(a.speed, b.speed) and np.array_equal(a.gap, b.gap)


def test_a_lag_changes_the_platoon():
    events = load_events("default", "test")[:1]
    lagged = Impairments(plant=Plant((("car", 1.0),), 0.5, 0.1))
    a, b = _run("ploeg:h=0.8", None, events)[0], _run("ploeg:h=0.8", lagged, events)[0]
    assert not np.allclose(a.speed, b.speed)


CC_VTYPE = """<additional><vType id="cc_ref" carFollowModel="CC" accel="5" decel="9" length="5"
 minGap="2" maxSpeed="50" speedFactor="1" tauEngine="{tau}" lanesCount="1" ccAccel="1.5"
 ccDecel="1.5"/></additional>"""


@pytest.mark.parametrize("tau", [0.5, 0.1])
def test_sumo_plexe_cc_engine_model_realises_the_same_accelerations(tmp_path, tau):
    """SUMO's Plexe CC model with its first-order engine lag, commanded a fixed acceleration
    through libsumo every 0.1 s, is the reference: our Powertrains match it to 1e-9."""
    import libsumo as ls

    vtypes = tmp_path / "cc.add.xml"
    vtypes.write_text(CC_VTYPE.format(tau=tau))
    route = lane_route(NET)
    start_sumo(["-n", str(NET), "-a", str(vtypes), "--step-length", str(DT_S),
                "--no-step-log", "true", "--no-warnings", "true"])
    try:
        ls.route.add("r", list(route.edges))
        ls.vehicle.add("v", "r", "cc_ref", depart="now", departSpeed="20", departPos="10",
                       departLane=route.lanes[0].rsplit("_", 1)[1])
        ls.simulationStep()
        key = "carFollowModel."
        ls.vehicle.setParameter("v", key + "ccac", "1")
        ls.vehicle.setParameter("v", key + "ccds", "40")
        ls.vehicle.setParameter("v", key + "ccfa", "1:0")
        for _ in range(10):
            ls.simulationStep()
        pt = _powertrains(tau, 0, 5.0, 9.0)
        pt.reset(np.array([ls.vehicle.getAcceleration("v")]))
        rng = np.random.default_rng(0)
        worst = 0.0
        for u in rng.uniform(-4.0, 2.0, 80):
            ls.vehicle.setParameter("v", key + "ccfa", f"1:{float(u)!r}")
            ls.simulationStep()
            ours = pt.step(np.array([u]))[0]
            worst = max(worst, abs(ours - ls.vehicle.getAcceleration("v")))
    finally:
        close_sumo()
    assert worst < 1e-9


def test_fleet_draws_are_seeded_by_event_and_seed():
    plant = Plant(parse_fleet("car:0.5,truck:0.5"))
    a, b = plant.draw(20, "e1", 0), plant.draw(20, "e1", 0)
    assert a.classes == b.classes and np.array_equal(a.tau_s, b.tau_s)
    assert a.classes != plant.draw(20, "e2", 0).classes
    for name, tau, dead in zip(a.classes, a.tau_s, a.dead_steps):
        c = VEHICLE_CLASSES[name]
        assert c.tau_s[0] <= tau <= c.tau_s[1]
        assert round(c.dead_time_s[0] / DT_S) <= dead <= round(c.dead_time_s[1] / DT_S)
    assert set(a.classes) == {"car", "truck"}


@pytest.mark.parametrize("options,message", [
    (["--vehicle-lag", "-0.1"], "--vehicle-lag"),
    (["--actuation-delay", "0.15"], "not a multiple"),
    (["--fleet", "car:0.5,bus:0.5"], "unknown vehicle class"),
    (["--fleet", "car:0.5,truck:0.4"], "sum to"),
    (["--fleet", "car:x"], "not a fraction"),
    (["--plant", "real", "--controller", "idm"], "vehicle dynamics"),
])
def test_bad_plant_options_are_one_line_and_exit_2(capsys, options, message):
    args = ["simulate", "--events", "1", "--net", str(NET)]
    if "--controller" not in options:
        args += ["--controller", "ploeg:h=1"]
    assert main(args + options) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("carl-sumo: error:") and message in err and "\n" not in err


def test_a_tuned_law_refuses_a_plant_it_was_not_tuned_for(capsys):
    assert main(["simulate", "--events", "1", "--net", str(NET), "--controller",
                 "ploeg-tuned:h=0.8", "--vehicle-lag", "0.3"]) == 2
    assert "no gains tuned for the plant" in capsys.readouterr().err


def test_plant_validation():
    with pytest.raises(InputError):
        Plant((), None, None)
    with pytest.raises(InputError):
        Plant((("car", 1.0), ("car", 0.0)))
