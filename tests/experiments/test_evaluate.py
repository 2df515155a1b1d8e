"""``carl-sumo evaluate`` (the paper suite, --quick, end to end), the bootstrap, and replay."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from carl_sumo.cli import main
from carl_sumo.errors import InputError
from carl_sumo.sim.metrics import METRIC_KEYS, aggregate, bootstrap_ci, paired_difference
from carl_sumo.experiments.suite import classical_models, discover_model, figure_event
from carl_sumo.experiments.suite_stats import CSV_COLUMNS

from conftest import NET, REPO_ROOT, braking_event

POLICIES = REPO_ROOT / "policies"
SHIPPED = ("ca_td3_10", "ca_ddpg_10", "td3_1", "ddpg_1", "maddpg_10", "maddpg_20", "ca_td3_20",
           "ca_ddpg_20", "ca_td3_ploeg_10")


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def extra_seed(src: Path, dst: Path, seed: int) -> None:
    """A second training seed of a policy: the same network with perturbed weights."""
    payload = torch.load(src, weights_only=True)
    gen = torch.Generator().manual_seed(seed)
    payload["actor"] = {k: v + 0.05 * torch.randn(v.shape, generator=gen) if v.is_floating_point()
                        else v for k, v in payload["actor"].items()}
    payload["metadata"] = {**payload["metadata"], "seed": seed}
    torch.save(payload, dst)


@pytest.fixture(scope="module")
def quick_suite(tmp_path_factory) -> Path:
    """The --quick suite, run once: policies copied, TD3 and CA-TD3 with a second seed (and a
    duplicate of TD3's shipped one)."""
    root = tmp_path_factory.mktemp("suite")
    policies = root / "policies"
    seeds = policies / "seeds"
    seeds.mkdir(parents=True)
    for stem in SHIPPED:
        shutil.copy(POLICIES / f"{stem}.pt", policies / f"{stem}.pt")
    extra_seed(POLICIES / "td3_1.pt", seeds / "td3_1_seed1.pt", 1)
    extra_seed(POLICIES / "ca_td3_10.pt", seeds / "ca_td3_10_seed1.pt", 1)
    shutil.copy(POLICIES / "td3_1.pt", seeds / "td3_1_seed7.pt")  # the shipped seed again: left out
    shutil.copy(POLICIES / "td3_1.pt", policies / "td3_1_seed3.pt")  # not in seeds/: not a seed
    out = root / "results"
    code = main(["evaluate", "--suite", "paper", "--quick", "--seeds", "--out", str(out),
                 "--policies", str(policies), "--net", str(NET), "--workers", "2"])
    assert code == 0
    return out


CLASSICAL = classical_models()  # SUMO's CACC, the textbook and the tuned Ploeg curves
TABLES = {  # file stem -> (rows, platoon lengths)
    "table1_default_test": (9 + len(CLASSICAL), {1, 10}),
    "table2_generalization": (20 + 2 * len(CLASSICAL), {10, 20}),
    "table3_stop_and_go": (8 + len(CLASSICAL), {10}),
    "cross_site_default_train": (9 + len(CLASSICAL), {1, 10}),
}


def test_quick_suite_writes_every_table_figure_and_readme(quick_suite):
    names = {p.name for p in quick_suite.iterdir()}
    for stem in TABLES:
        assert {f"{stem}.md", f"{stem}.csv"} <= names
    figures = sorted(n for n in names if n.endswith(".png"))
    assert figures == ["fig_accel_norm_profile.png", "fig_ecdf_default_test.png",
                       "fig_frontier_default_test.png", "fig_time_space_default.png", "fig_time_space_stop_and_go.png",
                       "fig_timeseries_default.png", "fig_timeseries_stop_and_go.png"]
    for name in figures:
        data = (quick_suite / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    readme = (quick_suite / "README.md").read_text()
    assert all(f"]({name})" in readme for name in figures)
    assert "wall time" in readme and "cores" in readme and "--quick" in readme
    assert not [n for n in names if n.startswith(".")]  # no temporary file left
    assert "Paired comparisons" in readme and "table1_default_test_paired.csv" in readme


def test_quick_suite_paired_comparisons(quick_suite):
    paired = pd.read_csv(quick_suite / "table1_default_test_paired.csv")
    assert list(paired["model"])[:4] == ["CA-TD3", "CA-DDPG", "CA-TD3", "CA-DDPG"]
    assert list(paired["reference"])[:4] == ["IDM (SUMO)", "IDM (SUMO)", "TD3", "DDPG"]
    t1 = pd.read_csv(quick_suite / "table1_default_test.csv").set_index("model")
    for _, row in paired.iterrows():
        for m in ("jerk_mps3", "speed_mps", "dampening_ratio"):
            expected = t1.loc[row["model"], m] - t1.loc[row["reference"], m]
            assert abs(row[f"d_{m}"] - expected) < 1e-5, (row["model"], m)
            assert row[f"d_{m}_lo"] <= row[f"d_{m}"] + 1e-9 <= row[f"d_{m}_hi"] + 2e-9
            assert 0 <= row[f"{m}_seeds_better"] <= row["seeds"]


def test_quick_suite_compares_models_across_seeds(quick_suite):
    paired = pd.read_csv(quick_suite / "table1_default_test_paired.csv")
    seeds = pd.read_csv(quick_suite / "table1_default_test_seeds.csv")
    row = paired[(paired["model"] == "CA-TD3") & (paired["reference"] == "TD3")].iloc[0]
    assert row["seeds"] == 2 and row["reference_seeds"] == 2
    ca_seed, td3_seed = (int(torch.load(POLICIES / f"{s}.pt", weights_only=True)["metadata"]
                             ["seed"]) for s in ("ca_td3_10", "td3_1"))
    assert row["matched_seeds"] == len({1, ca_seed} & {1, td3_seed})  # seeds trained alike
    for m in ("jerk_mps3", "dampening_ratio", "speed_mps"):
        ca = seeds.loc[seeds["model"] == "CA-TD3", m].to_numpy()
        td3 = seeds.loc[seeds["model"] == "TD3", m].to_numpy()
        assert abs(row[f"seed_d_{m}"] - (ca.mean() - td3.mean())) < 1e-4  # CSV rounding
        assert np.isfinite(row[f"seed_t_{m}"]) and 0 < row[f"seed_p_{m}"] <= 1
        assert 0 <= row[f"{m}_matched_better"] <= row["matched_seeds"]
    ca_ddpg = paired[(paired["model"] == "CA-DDPG") & (paired["reference"] == "DDPG")].iloc[0]
    assert np.isnan(ca_ddpg["seed_t_dampening_ratio"])  # one seed each: no comparison
    readme = (quick_suite / "README.md").read_text()
    assert "Across seeds" in readme and "| CA-TD3 | TD3 | 2 vs 2 |" in readme


def test_quick_suite_csv_rows_columns_and_intervals(quick_suite):
    for stem, (n_rows, lengths) in TABLES.items():
        table = pd.read_csv(quick_suite / f"{stem}.csv")
        assert list(table.columns) == CSV_COLUMNS
        assert len(table) == n_rows, stem
        assert set(table["followers"]) == lengths
        for m in METRIC_KEYS:
            lo, mean, hi = table[f"{m}_lo"], table[m], table[f"{m}_hi"]
            ok = lo.notna()
            assert (lo[ok] <= mean[ok] + 1e-9).all() and (mean[ok] <= hi[ok] + 1e-9).all(), m
        if stem == "table3_stop_and_go":  # one event: no interval
            assert table["headway_s_lo"].isna().all()
        else:
            assert table["headway_s_lo"].notna().all() and (table["events"] == 2).all()
    t1 = pd.read_csv(quick_suite / "table1_default_test.csv")
    assert list(t1["model"]) == ["human (recorded)", "IDM (SUMO)", "Krauss (SUMO)",
                                 *CLASSICAL.values(), "MADDPG", "DDPG", "CA-DDPG", "TD3",
                                 "CA-TD3", "CA-TD3 on ploeg-tuned:h=0.8"]
    assert {"CACC (SUMO)", "Ploeg h=1 s", "Ploeg h=0.6 s"} <= set(CLASSICAL.values())
    assert (t1[t1["model"].str.startswith(("Ploeg", "CACC"))]["collisions"] == 0).all()
    t2 = pd.read_csv(quick_suite / "table2_generalization.csv")
    maddpg = t2[t2["model"] == "MADDPG"]
    assert sorted(zip(maddpg["policy"], maddpg["followers"])) == [("maddpg_10", 10),
                                                                  ("maddpg_20", 20)]


def test_quick_suite_spread_across_seeds(quick_suite):
    t1 = pd.read_csv(quick_suite / "table1_default_test.csv").set_index("policy")
    assert t1.loc["td3_1", "seeds"] == 2 and t1.loc["ca_ddpg_10", "seeds"] == 1
    assert np.isfinite(t1.loc["td3_1", "jerk_mps3_seed_std"])
    assert np.isnan(t1.loc["ca_ddpg_10", "jerk_mps3_seed_std"])
    per_event = pd.read_csv(quick_suite / "per_event.csv")
    td3 = per_event[(per_event["model"] == "td3_1") & (per_event["event_set"] == "default_test")
                    & (per_event["followers"] == 10)]
    shipped = int(torch.load(POLICIES / "td3_1.pt", weights_only=True)["metadata"]["seed"])
    by_seed = td3.groupby("seed")["jerk_mps3"].mean()
    assert sorted(by_seed.index) == sorted({shipped, 1}) and by_seed[shipped] != by_seed[1]
    all_seeds = pd.read_csv(quick_suite / "table1_default_test_seeds.csv")
    assert set(all_seeds["model"]) == {"TD3", "CA-TD3"}  # only models with several seeds
    seeds = all_seeds[all_seeds["model"] == "TD3"].reset_index(drop=True)
    assert list(seeds["policy"]) == ["td3_1", "td3_1_seed1"]
    assert list(seeds["seed"]) == [shipped, 1] and list(seeds["shipped"]) == [True, False]
    for _, row in seeds.iterrows():  # each seed's aggregate, recomputable from per_event.csv
        agg = aggregate(td3[td3["seed"] == row["seed"]].to_dict("records"))
        assert all(abs(agg[m] - row[m]) < 1e-4 for m in ("jerk_mps3", "speed_mps",
                                                          "dampening_ratio", "headway_s"))
    assert abs(seeds.loc[0, "jerk_mps3"] - t1.loc["td3_1", "jerk_mps3"]) < 1e-9
    md = (quick_suite / "table1_default_test.md").read_text()
    assert "Spread across seeds" in md and "n=2" in md and "n=1" in md
    t2 = pd.read_csv(quick_suite / "table2_generalization.csv")
    td3_t2 = t2[t2["policy"] == "td3_1"].set_index("followers")["seeds"]
    assert td3_t2[10] == 2 and td3_t2[20] == 1  # Table 2 runs the seed files at 10 only
    longer = per_event[(per_event["model"] == "td3_1") & (per_event["followers"] == 20)]
    assert set(longer["seed"]) == {shipped}


def test_bootstrap_matches_a_direct_resampling_of_aggregate():
    rng = np.random.default_rng(3)
    events = []
    for i in range(15):
        n = int(rng.integers(50, 400))
        events.append({"event_id": f"e{i}", "headway_s": rng.uniform(1, 3),
                       "jerk_mps3": rng.uniform(0.1, 1), "speed_mps": rng.uniform(5, 15),
                       "ttc_lt_4s_count": int(rng.integers(0, 20)), "ttc_lt_1_5s_count": 0,
                       "dampening_ratio": rng.uniform(0.5, 1.5),
                       "worst_successive_ratio": rng.uniform(0.8, 1.5), "collisions": 0,
                       "n_headway": n, "n_jerk": n - 2, "n_speed": n})
    ci = bootstrap_ci(events, n_boot=4000, seed=1)
    direct = []
    for _ in range(4000):
        direct.append(aggregate([events[j] for j in rng.integers(0, len(events), len(events))]))
    point = aggregate(events)
    for key in METRIC_KEYS:
        values = np.array([d[key] for d in direct], float)
        lo, hi = np.percentile(values, [2.5, 97.5])
        spread = max(hi - lo, 1e-9)
        assert abs(ci[key][0] - lo) <= 0.1 * spread + 1e-9, key
        assert abs(ci[key][1] - hi) <= 0.1 * spread + 1e-9, key
        assert ci[key][0] <= point[key] <= ci[key][1], key


def test_bootstrap_hand_made_cases():
    base = {"ttc_lt_4s_count": 2, "ttc_lt_1_5s_count": 0, "dampening_ratio": 0.5,
            "worst_successive_ratio": 1.0, "collisions": 0, "jerk_mps3": 0.2, "speed_mps": 10.0}
    # pooled mean: values 1 and 3 with 1 and 3 samples -> every resample lies in [1, 3]; the
    # point estimate is (1·1 + 3·3)/4 = 2.5
    events = [{**base, "event_id": "a", "headway_s": 1.0, "n_headway": 1, "n_jerk": 1,
               "n_speed": 1},
              {**base, "event_id": "b", "headway_s": 3.0, "n_headway": 3, "n_jerk": 1,
               "n_speed": 1}]
    ci = bootstrap_ci(events, n_boot=500)
    assert aggregate(events)["headway_s"] == 2.5
    assert ci["headway_s"] == (1.0, 3.0)  # both all-a and all-b resamples occur (p = 1/4 each)
    assert ci["ttc_lt_4s_count"] == (4.0, 4.0) and ci["dampening_ratio"] == (0.5, 0.5)
    one = bootstrap_ci(events[:1])
    assert all(np.isnan(lo) and np.isnan(hi) for lo, hi in one.values())


def test_paired_difference_cancels_what_the_events_share():
    rng = np.random.default_rng(5)
    base = {"ttc_lt_4s_count": 0, "ttc_lt_1_5s_count": 0, "worst_successive_ratio": 1.0,
            "collisions": 0, "headway_s": 1.8, "n_headway": 100, "n_jerk": 98, "n_speed": 100}
    # events differ a lot (speed 5-15 m/s), the model is 0.1 m/s faster on every one of them
    ref = [{**base, "event_id": f"e{i}", "speed_mps": s, "jerk_mps3": 0.2,
            "dampening_ratio": 0.7} for i, s in enumerate(rng.uniform(5, 15, 40))]
    model = [{**e, "speed_mps": e["speed_mps"] + 0.1 + rng.normal(0, 0.01)}
             for e in reversed(ref)]  # another order: paired by event id
    diff = paired_difference(model, ref, n_boot=1000)
    d, lo, hi = diff["speed_mps"]
    assert abs(d - 0.1) < 0.01 and 0.09 < lo < d < hi < 0.11
    own_lo, own_hi = bootstrap_ci(model, n_boot=1000)["speed_mps"]
    assert own_hi - own_lo > 50 * (hi - lo)  # unpaired intervals would hide the difference
    assert diff["jerk_mps3"] == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="same events"):
        paired_difference(model[1:], ref)


def test_figure_event_is_the_largest_leader_speed_range():
    calm = braking_event(n=400, event_id="calm", v0=6.0)
    wild = braking_event(n=400, event_id="wild", v0=14.0)
    short = braking_event(n=200, event_id="short", v0=20.0)  # 19.9 s: too short
    assert figure_event([calm, wild, short]) == "wild"
    assert figure_event([short]) == "short"


def test_seed_files_run_with_seeds_or_all_seeds_only(tmp_path):
    from carl_sumo.experiments.suite import controllers_run, plan_suite

    shutil.copytree(POLICIES, tmp_path / "p", ignore=shutil.ignore_patterns("*.ckpt", "logs"))
    for mode in ("shipped", "seeds", "all"):
        suite = plan_suite(quick=True, policies=tmp_path / "p", net=NET,
                           seeds=mode == "seeds", all_seeds=mode == "all")
        for key in ("ca_td3_10", "maddpg_10"):
            model = suite.models[key]
            assert len(model.files) > 1
            runs = {(spec.key, n): len(controllers_run(spec, model, n))
                    for spec in suite.tables for n in spec.followers if model.runs_on(n)}
            every = len(model.files) if mode == "all" else 1
            compared = key == "ca_td3_10" and mode == "seeds"  # Table 1 compares it across seeds
            assert runs[("table1_default_test", 10)] == runs[("table2_generalization", 10)] == (
                len(model.files) if compared else every)
            assert runs[("table3_stop_and_go", 10)] == runs[("cross_site_default_train", 10)] == every
            if key == "ca_td3_10":
                assert runs[("table2_generalization", 20)] == every
    with pytest.raises(InputError, match="exclude each other"):
        plan_suite(quick=True, policies=tmp_path / "p", net=NET, seeds=True, all_seeds=True)


def test_seed_files_are_found_and_duplicates_left_out(tmp_path):
    seeds = tmp_path / "seeds"
    seeds.mkdir()
    extra_seed(POLICIES / "ca_td3_10.pt", tmp_path / "ca_td3_10.pt", 7)  # shipped: seed 7
    extra_seed(POLICIES / "ca_td3_10.pt", seeds / "ca_td3_10_seed2.pt", 2)
    extra_seed(POLICIES / "ca_td3_10.pt", seeds / "ca_td3_10_seed0.pt", 0)
    shutil.copy(tmp_path / "ca_td3_10.pt", seeds / "ca_td3_10_seed7.pt")  # the shipped run again
    shutil.copy(tmp_path / "ca_td3_10.pt", seeds / "ca_td3_10_seed3.pt")  # seed 7 again
    shutil.copy(POLICIES / "ca_td3_10.pt", seeds / "ca_td3_10_seedx.pt")  # not a seed name
    extra_seed(POLICIES / "ca_td3_10.pt", tmp_path / "ca_td3_10_seed5.pt", 5)  # not in seeds/
    model = discover_model("ca_td3_10", tmp_path)
    assert model.seeds == (7, 0, 2) and model.name == "CA-TD3" and model.trained_on == 10
    assert [Path(f).name for f in model.files] == ["ca_td3_10.pt", "ca_td3_10_seed0.pt",
                                                   "ca_td3_10_seed2.pt"]
    maddpg = tmp_path / "m"
    maddpg.mkdir()
    shutil.copy(POLICIES / "maddpg_20.pt", maddpg / "maddpg_20.pt")
    model = discover_model("maddpg_20", maddpg)
    assert model.fixed_length == 20 and model.runs_on(20) and not model.runs_on(10)


def test_evaluate_bad_input_is_one_line_exit_2(capsys, tmp_path, monkeypatch):
    cases = [
        (["evaluate", "--quick", "--data", tmp_path / "none.csv"], "does not exist"),
        (["evaluate", "--suite", "tables", "--quick"], "invalid choice"),
        (["evaluate", "--quick", "--policies", tmp_path / "nowhere"], "policy directory"),
        (["evaluate", "--quick", "--policies", tmp_path], "does not exist"),
        (["evaluate", "--quick", "--events", "0"], "at least 1"),
        (["evaluate", "--quick", "--workers", "0"], "at least 1"),
        (["evaluate", "--quick", "--comm-loss", "2"], "--comm-loss is a probability"),
        (["evaluate", "--suite", "robustness", "--quick", "--comm-loss", "0.3"],
         "its own grid of impairments"),
        (["evaluate", "--quick", "--tables", "table9"], "choose one or more of table1"),
        (["evaluate", "--quick", "--tables", ","], "choose one or more of table1"),
        (["evaluate", "--quick", "--tables", "string_stability"], "--suite real only"),
        (["evaluate", "--suite", "robustness", "--quick", "--tables", "table1"],
         "--suite paper or real"),
    ]
    for argv, message in cases:
        code, out, err = run(capsys, *argv, "--out", tmp_path / "out")
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, (argv, err)
    monkeypatch.chdir(tmp_path)  # no ../shared/data/ngsim here
    code, _, err = run(capsys, "evaluate", "--out", tmp_path / "out", "--net", NET)
    assert code == 2 and "pass --data" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_replay_gui_without_display_is_one_line_exit_2(capsys, tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    fcd = tmp_path / "out.xml"
    code, _, err = run(capsys, "replay", "--controller", POLICIES / "ca_td3_10.pt", "--event",
                       "stop_and_go", "--data", "stop-and-go", "--fcd", fcd, "--net", NET, "--gui")
    assert code == 2 and "display" in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("stem,vehicles", [("ca_td3_10", 10), ("td3_1", 3), ("maddpg_10", 10)])
def test_replay_works_for_policy_files(capsys, tmp_path, stem, vehicles):
    fcd = tmp_path / "out.xml"
    code, out, err = run(capsys, "replay", "--controller", POLICIES / f"{stem}.pt", "--event",
                         "stop_and_go", "--data", "stop-and-go", "--vehicles", vehicles,
                         "--fcd", fcd, "--net", NET)
    assert code == 0, err
    steps = ET.parse(fcd).getroot().findall("timestep")
    assert len(steps) > 1000
    ids = {v.get("id") for v in steps[-1].findall("vehicle")}
    assert ids == {"leader", *(f"f{i}" for i in range(vehicles))}
    assert "collisions=0" in out


def test_replay_maddpg_other_length_is_refused_before_running(capsys, tmp_path):
    code, _, err = run(capsys, "replay", "--controller", POLICIES / "maddpg_10.pt", "--event",
                       "stop_and_go", "--data", "stop-and-go", "--vehicles", "5",
                       "--fcd", tmp_path / "out.xml", "--net", NET)
    assert code == 2 and "trained for 10 vehicles" in err
    assert list(tmp_path.iterdir()) == []


def test_quick_suite_through_ray_writes_the_same_tables(quick_suite, tmp_path):
    """``--ray local``: the suite's tasks as Ray tasks give every table and per-event row of the
    local pool's run (the fixture's), byte for byte."""
    pytest.importorskip("ray")
    policies = quick_suite.parent / "policies"
    out = tmp_path / "ray"
    assert main(["evaluate", "--suite", "paper", "--quick", "--seeds", "--out", str(out),
                 "--policies", str(policies), "--net", str(NET), "--workers", "2",
                 "--ray", "local"]) == 0
    compared = sorted(p.name for p in quick_suite.glob("*.csv") if p.name != "timing.csv")
    assert "per_event.csv" in compared and "table1_default_test.csv" in compared
    for name in compared:
        assert (out / name).read_bytes() == (quick_suite / name).read_bytes(), name
    assert {p.name for p in out.iterdir()} == {p.name for p in quick_suite.iterdir()}


def test_an_impaired_suite_impairs_the_carl_sumo_controllers_only():
    from dataclasses import replace

    from carl_sumo.control.channel import Impairments
    from carl_sumo.experiments.evaluate import plan_tasks, run_task
    from carl_sumo.experiments.suite import plan_suite
    from carl_sumo.experiments.suite_report import _impairments

    lossy = Impairments(loss=1.0)
    suite = replace(plan_suite(quick=True, events=1, net=NET), impairments=lossy)
    tasks = plan_tasks(suite, str(NET))
    native = {t["controller"] for t in tasks if t["impairments"] is None}
    impaired = {t["controller"] for t in tasks if t["impairments"] == lossy}
    assert {"idm", "krauss", "sumo-cacc", "human"} <= native
    assert any(c.startswith("ploeg") for c in impaired) and any(c.endswith(".pt") for c in impaired)
    assert native.isdisjoint(impaired)
    assert native | impaired == {t["controller"] for t in tasks}
    ploeg = next(t for t in tasks if t["controller"] == "ploeg:h=0.8")
    lost, clean = run_task(ploeg), run_task({**ploeg, "impairments": None})
    assert lost["per_event"][0]["jerk_mps3"] != clean["per_event"][0]["jerk_mps3"]
    assert "loss 1" in _impairments(lossy)


def test_a_warmed_suite_runs_every_table_warmed_and_says_so():
    from carl_sumo.experiments.suite import plan_suite

    cold = plan_suite(quick=True, events=1, net=NET)
    warm = plan_suite(quick=True, events=1, net=NET, warmup_s=5.0)
    assert warm.warmup_s == 5.0 and cold.warmup_s == 0.0
    for key, events in warm.events.items():
        assert [e.scored_from for e in events] == [50] * len(events)
        assert [e.n_samples for e in events] == [e.n_samples + 50 for e in cold.events[key]]
    assert warm.figure_events == cold.figure_events  # chosen on the recorded part


def test_tables_runs_only_the_chosen_tables_and_their_figures(capsys, tmp_path):
    """``--tables table3``: the stop-and-go table, its figures and the README, nothing else (no
    string-stability table in the real suite unless named)."""
    from carl_sumo.experiments.suite import plan_suite

    suite = plan_suite("real", quick=True, events=1, net=NET, plant="real",
                       only=("table1", "cross_site"))
    assert [t.key for t in suite.tables] == ["table1_default_test", "cross_site_default_train"]
    assert not suite.string_stability
    assert plan_suite("real", quick=True, events=1, net=NET, plant="real",
                      only=("table3", "string_stability")).string_stability
    out = tmp_path / "out"
    code, stdout, err = run(capsys, "evaluate", "--suite", "real", "--quick", "--tables", "table3",
                            "--out", out, "--net", NET, "--workers", "2")
    assert code == 0, err
    files = sorted(p.name for p in out.iterdir())
    assert [f for f in files if f.startswith(("table", "cross", "string"))] == [
        "table3_stop_and_go.csv", "table3_stop_and_go.md"]
    assert {"fig_timeseries_stop_and_go.png", "fig_accel_norm_profile.png"} <= set(files)
    assert not any(f.startswith(("fig_ecdf", "fig_frontier")) for f in files)
    rows = pd.read_csv(out / "table3_stop_and_go.csv")
    assert {"mpf-tuned:h=0.6", "mpc-tuned:h=0.6", "ca_td3_real_10"} <= set(rows["policy"])
    readme = (out / "README.md").read_text()
    assert "### Table 3" in readme and "### Table 1" not in readme
