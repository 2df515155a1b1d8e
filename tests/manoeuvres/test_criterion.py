"""The event-by-event bar of issue 35 (carl_sumo.manoeuvres.criterion) on real SUMO runs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from carl_sumo.data import load_events
from carl_sumo.learn.policy import read_policy_payload
from carl_sumo.manoeuvres.spec import ScenarioSpec
from carl_sumo.manoeuvres.criterion import criterion_lines, manoeuvre_criterion
from carl_sumo.manoeuvres.tables import (PLANT_CONTROLLERS, PRODUCT_BASE, result_of,
                                             run_jobs)

from conftest import NET

N = 4
EVENTS = ("sumo42_f1672_l1659_fr5731", "sumo42_f722_l715_fr3000", "sumo42_f1918_l1895_fr6420",
          "sumo42_f734_l727_fr3000", "sumo42_f2321_l2303_fr7763")  # a human cuts in at N = 4


@pytest.fixture(scope="module")
def cut_in_runs():
    pytest.importorskip("libsumo")
    events = load_events("default", "test", event_ids=list(EVENTS))
    spec = ScenarioSpec("cut-in", seed=0)
    names = ("ploeg-tuned:h=0.8", "idm")
    rows = run_jobs([(name, spec, None, events) for name in names], N, str(NET),
                    workers=1, chunks=1)
    return [result_of(name, spec, r, N) for name, r in zip(names, rows)]


def test_a_controller_against_itself_differs_nowhere(cut_in_runs):
    cacc = cut_in_runs[0]
    c = manoeuvre_criterion(cacc, cacc)
    assert c["paired_events"] == sum(e["manoeuvre_metrics"]["done"] for e in cacc["events"]) > 0
    assert c["collisions_where_reference_none"] == c["ttc_where_reference_none"] == 0
    assert c["peak_decel_mps2"]["difference"] == 0.0
    assert c["peak_decel_mps2"]["worse_events"] == c["peak_decel_mps2"]["better_events"] == 0


def test_the_differences_are_the_per_event_ones(cut_in_runs):
    cacc, idm = cut_in_runs
    c = manoeuvre_criterion(idm, cacc)
    by_id = {e["event_id"]: e["manoeuvre_metrics"] for e in cacc["events"]}
    diffs = [e["manoeuvre_metrics"]["peak_decel_mps2"] - by_id[e["event_id"]]["peak_decel_mps2"]
             for e in idm["events"]
             if e["manoeuvre_metrics"]["done"] and by_id[e["event_id"]]["done"]]
    d = c["peak_decel_mps2"]
    assert d["events"] == len(diffs) == c["paired_events"]
    assert d["difference"] == pytest.approx(np.mean(diffs))
    assert d["worse_events"] == sum(x > 0 for x in diffs)
    if len(diffs) >= 2:
        assert d["lo"] <= d["difference"] <= d["hi"]
    reverse = manoeuvre_criterion(cacc, idm)
    assert reverse["peak_decel_mps2"]["difference"] == pytest.approx(-d["difference"])
    assert reverse["collisions_where_reference_none"] == c["reference_collisions_where_none"]
    assert len(criterion_lines(c)) == 3


def test_collisions_and_close_calls_count_only_where_the_reference_has_none():
    def run(name, rows):
        return {"controller": name, "events": [
            {"event_id": i, "manoeuvre_metrics": {"done": done, "collisions": coll,
                                                  "min_ttc_s": ttc, "peak_decel_mps2": 1.0,
                                                  "settle_s": math.inf}}
            for i, (done, coll, ttc) in enumerate(rows)]}
    mine = run("a", [(True, 1, 0.5), (True, 1, 1.0), (True, 0, 3.0), (False, 2, 0.1)])
    ref = run("b", [(True, 0, 2.0), (True, 1, 1.0), (True, 0, 1.2), (True, 0, 9.0)])
    c = manoeuvre_criterion(mine, ref)
    assert c["paired_events"] == 3
    assert (c["collisions_where_reference_none"], c["reference_collisions_where_none"]) == (1, 0)
    assert c["collision_events_where_reference_none"] == [0]
    assert (c["ttc_where_reference_none"], c["reference_ttc_where_none"]) == (1, 1)
    assert c["settle_s"]["events"] == 0 and math.isnan(c["settle_s"]["difference"])


def test_the_suites_product_start_is_the_shipped_products_base():
    """The scenario suite's row for the product's start (``mpf-tuned`` at its gap) is the law the
    shipped product runs its learned term on (the options that shape that term alone: a washout
    ``wo``, ``hf``, or a learned gap ``gp``, ``gl``, ``gb``, ``gh``), so the two rows differ by that
    term alone; the one-predecessor law it extends comes before it."""
    from carl_sumo.control.channel import plant_impairments
    from carl_sumo.control.ploeg_names import tuned_law
    from carl_sumo.experiments.suite import PRODUCT_MPF
    from carl_sumo.resources import PRODUCT

    payload = read_policy_payload(Path("policies") / PRODUCT)
    base = payload["agent_config"]["base"].split(":")
    start = tuned_law(PRODUCT_MPF, plant=plant_impairments("real").plant_key).split(":")
    learned_term_only = ("wo", "hf", "gp", "gl", "gb", "gh")
    assert [p for p in base if p.split("=")[0] not in learned_term_only] == start
    law = {p for p in PRODUCT_BASE.split(":")[1:] if p.split("=")[0] not in learned_term_only}
    assert law < set(base)  # the one-predecessor law's keys
    real = PLANT_CONTROLLERS["real"]
    assert real.index(PRODUCT_BASE) + 1 == real.index(PRODUCT_MPF) == real.index(PRODUCT) - 1
