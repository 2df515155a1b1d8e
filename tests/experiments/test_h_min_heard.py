"""h_min against the vehicles heard (``string-stability --h-min-heard``): the theory's r = 1 is
Ploeg's, hearing more shortens the gap on the links that hear them all, and SUMO agrees on
either side of the analytic h_min at its peak frequency."""

from __future__ import annotations

import numpy as np

from carl_sumo.cli import main
from carl_sumo.control.channel import Impairments
from carl_sumo.control.transfer import gamma_links_discrete, h_min_links
from carl_sumo.experiments import h_min_heard
from carl_sumo.experiments.string_stability import SineTest, measure
from carl_sumo.sim.vehicle import Plant

from conftest import NET


def test_hearing_more_vehicles_shortens_the_gap_of_the_links_that_hear_them_all():
    ploeg = h_min_heard.h_range_analytic(1, 0.2, 0.7, 0.1, 0.1)
    assert abs(ploeg[0] - h_min_links(0.2, 0.7, 0.1, 1, (1.0,), n=4,
                                      omega=h_min_heard.DENSE_OMEGAS)) < 2e-3
    assert ploeg[1] == float("inf")
    two, three = (h_min_heard.h_range_analytic(r, 0.2, 0.7, 0.1, 0.1) for r in (2, 3))
    assert three[0] < two[0] < ploeg[0] - 0.1
    assert 1.0 < three[1] < float("inf")  # a long gap is not string stable again


def test_sumo_agrees_either_side_of_the_analytic_h_min():
    """r = 3 on τ = 0.1 s with a 0.1 s V2V delay: 20 ms below the analytic h_min a link that
    hears all three amplifies at the theory's peak frequency, 20 ms above none does."""
    r, tau, delay = 3, 0.1, 0.1
    h = h_min_heard.h_range_analytic(r, 0.2, 0.7, tau, delay)[0]
    n = h_min_heard.followers(r)
    below = np.abs(gamma_links_discrete(h_min_heard.DENSE_OMEGAS, n, h - 0.02, 0.2, 0.7, tau, 0,
                                        1, h_min_heard.WEIGHTS[r]))[r:]
    omega = float(h_min_heard.DENSE_OMEGAS[below.max(axis=0).argmax()])
    imp = Impairments(delay_s=delay, plant=Plant((("car", 1.0),), tau, 0.0))
    gains = [np.max(measure(h_min_heard.law_name(r, gap, 0.2, 0.7), [omega], n, SineTest(), imp,
                            str(NET))["per_link"][r:])
             for gap in (h - 0.02, h + 0.02)]
    assert gains[0] > 1.0 >= gains[1]


def test_the_table_refuses_a_controller_without_gains(capsys, tmp_path):
    assert main(["string-stability", "--controller", "idm", "--h-min-heard",
                 str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert "--h-min-heard take the gains of one ploeg or acc" in err and err.count("\n") == 1
    assert not (tmp_path / "t").exists()
