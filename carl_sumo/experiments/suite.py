"""The paper's experiment suite: its tables, their models and events (what ``carl-sumo evaluate``
runs), and the data types of its results.

:func:`plan_suite` resolves a suite before anything runs (InputError on anything missing or wrong):
the event sets of the tables, the models of their rows (built-in controllers, the classical CACCs,
the shipped policy files and their seed files) and the event drawn in the time figures.
:class:`Suite` and :class:`JobResult` are what the runner (:mod:`carl_sumo.experiments.evaluate`), the
statistics (:mod:`carl_sumo.experiments.suite_stats`), the writing (:mod:`carl_sumo.experiments.suite_report`) and the
figures (:mod:`carl_sumo.experiments.figures`) share; this module imports none of them.

Tables (``--quick``: the shipped default leader set, 2 events per table, 10 and 20 followers in
Table 2, a one-cycle stop-and-go leader, and the default set's train split standing in for US-101):

1. NGSIM test split, 10 followers: human, IDM, Krauss, the classical CACCs (SUMO's CACC, the
   textbook Ploeg curve over :data:`TEXTBOOK_GAPS` and the tuned Ploeg frontier of
   ``policies/ploeg_tuned.json``), MADDPG, DDPG, CA-DDPG, TD3, CA-TD3;
2. generalization: every model on 10, 20 and 50 followers (MADDPG on its own length only);
3. the stop-and-go leader, 10 followers;
4. cross-site: the US-101 sample (no model was trained on it), 10 followers.

By default only the shipped policy files run. ``seeds`` (``--seeds``) adds the seed files of
CA-TD3, CA-DDPG, TD3 and DDPG (:data:`SEED_MODELS`) in Table 1 and in Table 2 at 10 followers;
``all_seeds`` (``--all-seeds``) runs every model's seed files in every row.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from carl_sumo.control.channel import Impairments
from carl_sumo.control.classical import is_classical_name
from carl_sumo.data import load_events
from carl_sumo.data.events import Event
from carl_sumo.data.synthetic import stop_and_go_event
from carl_sumo.errors import InputError
from carl_sumo.control.ploeg_names import PRESETS, parse_ploeg
from carl_sumo.resources import DEFAULT_NET, PRODUCT, policies_dir
from carl_sumo.sim.sumo import check_fits, lane_route


DEFAULT_NGSIM = Path("../shared/data/ngsim/ngsim_cf_events.csv.gz")
"""The NGSIM event table, relative to the directory carl-sumo runs in (the repository root)."""

SUITES = ("paper", "real")
"""``paper``: the paper's protocol (ideal plant, recorded start); ``real``: the same tables on the
real plant (a fleet with lag and dead time, V2V delay) from a settled start, with the radar-only
ACC and the gains tuned for that plant, and a string-stability table."""

ACC_GAPS = (2.0, 2.5, 3.0, 3.5)
"""Time gaps h (s) of the textbook ACC curve (kp = 0.2, kd = 0.7) in the real suite."""

TABLES = ("table1", "table2", "table3", "cross_site", "string_stability")
"""The parts of a suite ``evaluate --tables`` can choose: Table 1 (the test split), Table 2 (other
platoon lengths), Table 3 (stop-and-go), the cross-site table and, in the real suite, the
string-stability table."""

REAL_WARMUP_S = 60.0
"""The settled start of the real suite (s): every event first runs this long, unscored."""

SAMPLE_KEYS = ("headway_s", "speed_mps", "jerk_mps3")
"""Metrics whose every sample a figure job keeps (:attr:`JobResult.samples`, the ECDFs)."""


@dataclass(frozen=True)
class Model:
    """A row of the tables: a built-in controller or a policy stem with its seed files."""

    key: str                      # "idm", "human", or a policy stem such as "ca_td3_10"
    name: str                     # "IDM (SUMO)", "CA-TD3", ...
    files: tuple[str, ...] = ()   # policy files, the shipped file first
    seeds: tuple[int, ...] = ()   # their training seeds
    trained_on: int | None = None  # platoon length it was trained on
    fixed_length: int | None = None  # MADDPG: the only length it runs

    @property
    def controllers(self) -> tuple[str, ...]:
        """Controller names of its runs: the policy files, or the built-in name."""
        return self.files or (self.key,)

    def runs_on(self, n: int) -> bool:
        return self.fixed_length is None or self.fixed_length == n


BUILTIN_MODELS = {"human": "human (recorded)", "idm": "IDM (SUMO)", "krauss": "Krauss (SUMO)",
                  "sumo-cacc": "CACC (SUMO)", "idm-external": "IDM (carl-sumo, on the plant)"}
TEXTBOOK_GAPS = (0.6, 0.8, 1.0, 1.2, 1.5)
"""Time gaps h (s) of the textbook Ploeg curve (kp = 0.2, kd = 0.7) in every table."""


def is_classical(key: str) -> bool:
    """Whether a model key is a built-in (not learned) controller."""
    return key in BUILTIN_MODELS or is_classical_name(key)


ALGO_NAMES = {"ca-td3": "CA-TD3", "ca-ddpg": "CA-DDPG", "td3": "TD3", "ddpg": "DDPG",
              "maddpg": "MADDPG"}


@dataclass(frozen=True)
class EventSet:
    """Where a table's leaders come from."""

    key: str          # "ngsim_test" (data_tag + split), "stop_and_go", ...
    data: str         # an event table, "default" or "stop-and-go"
    split: str
    limit: int | None = None
    note: str = ""


@dataclass(frozen=True)
class TableSpec:
    key: str                       # file stem
    title: str
    events: EventSet
    followers: tuple[int, ...]
    models: tuple[str, ...]        # model keys, in row order
    figures: bool = False          # collect samples and trajectories for the figures
    seed_lengths: tuple[int, ...] | None = None  # lengths whose rows run the seed files too
    # (None: every length; the others run the shipped file only)
    seed_models: tuple[str, ...] | None = None  # models whose seed files run (None: every model)
    paired: tuple[tuple[str, str], ...] = ()  # (model, reference) pairs compared event by event


@dataclass
class Suite:
    """A planned suite: tables, models, the events of each event set, the figure events."""

    tables: list[TableSpec]
    models: dict[str, Model]
    events: dict[str, list[Event]]
    figure_events: dict[str, str]  # event-set key -> the event drawn in the time figures
    data: str
    quick: bool
    impairments: Impairments | None = None  # V2V and sensors of the carl-sumo controllers
    warmup_s: float = 0.0  # seconds every event runs before it is scored (Event.with_warmup)
    name: str = "paper"    # which suite (SUITES)
    string_stability: bool = True  # the real suite's string-stability table (TABLES)


@dataclass
class JobResult:
    """What one (event set, controller, platoon length) job produced, merged over its chunks."""

    per_event: list[dict] = field(default_factory=list)
    norms: list[np.ndarray] = field(default_factory=list)       # acceleration_norms per event
    samples: dict[str, list[np.ndarray]] = field(default_factory=dict)
    series: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    seconds: float = 0.0        # wall time its chunks took in the workers (s)
    cpu_seconds: float = 0.0    # CPU time of those chunks (s)


PRODUCT_STEM = Path(PRODUCT).stem
"""The real-plant product's row in the real suite (``policies/ca_td3_real_10.pt``)."""
PRODUCT_MPF = f"mpf-tuned:h={parse_ploeg(PRESETS['product-base']).time_gap_s:g}"
"""The multi-predecessor CACC tuned on the product's base, at the product's gap: the classical
law the product is paired with in the real suite."""
PRODUCT_MPC = PRODUCT_MPF.replace("mpf-", "mpc-", 1)
"""The distributed MPC tuned for the fleet at the product's gap (``mpc-tuned:h=0.6``): the other
classical reference the product is judged against (docs/baselines.md)."""
PAIRED_COMPARISONS = (("ca_td3_10", "idm"), ("ca_ddpg_10", "idm"), ("ca_td3_10", "td3_1"),
                      ("ca_ddpg_10", "ddpg_1"), ("td3_1", "idm"), ("ddpg_1", "idm"),
                      ("maddpg_10", "idm"), ("ca_td3_10", "ploeg:h=1.5"),
                      ("ca_ddpg_10", "ploeg:h=1.5"), ("ca_td3_ploeg_10", "ploeg-tuned:h=0.8"),
                      (PRODUCT_STEM, PRODUCT_MPF))
"""Table 1's paired comparisons: the quality bar's (CA models against IDM and against their
plain variants), the other learned models against IDM, the CA models against the textbook
Ploeg CACC at h = 1.5 s, which follows at the same mean headway (1.75 s), the product
configuration (CA-TD3 on the tuned Ploeg CACC) against its base alone, and in the real suite the
real-plant product against the multi-predecessor law tuned on its base (``mpf-tuned``)."""
SEED_MODELS = tuple(dict.fromkeys(key for pair in PAIRED_COMPARISONS
                                  if not is_classical(pair[1]) or pair[0] == "ca_td3_ploeg_10"
                                  for key in pair if not is_classical(key)))
"""Models whose seed files ``--seeds`` runs: the policy pairs of :data:`PAIRED_COMPARISONS`,
which Table 1 compares across seeds (each CA model with its plain variant), and the product
configuration (its seed mean against the tuned frontier). ``--all-seeds`` runs every model's
seed files in every row."""


# ------------------------------------------------------------------------------------ planning
def classical_models(tuned_file: Path | None = None, plant: str = "ideal") -> dict[str, str]:
    """Key (controller name) -> row name of the classical controllers: SUMO's CACC, the textbook
    Ploeg curve and the tuned Ploeg frontier (every h with safe tuned gains); on a real plant
    also the textbook ACC curve, the ACC and CACC gains tuned for that plant, and the
    multi-predecessor law and the MPC tuned for it (each when tuned)."""
    from carl_sumo.control.cacc import TUNED_FILE, read_tuned

    models = {"sumo-cacc": BUILTIN_MODELS["sumo-cacc"]}
    models.update({f"ploeg:h={h:g}": f"Ploeg h={h:g} s" for h in TEXTBOOK_GAPS})
    if plant == "ideal":
        entries = read_tuned(tuned_file or TUNED_FILE)
        models.update({f"ploeg-tuned:h={h}": f"Ploeg tuned h={h} s"
                       for h, e in sorted(entries.items(), key=lambda kv: float(kv[0]))
                       if e.get("kp") is not None})
        return models
    models.update({f"acc:h={h:g}": f"ACC h={h:g} s" for h in ACC_GAPS})
    for law, label in (("ploeg", "Ploeg"), ("acc", "ACC")):
        entries = read_tuned(None, law, plant)
        models.update({f"{law}-tuned:h={h}": f"{label} tuned h={h} s"
                       for h, e in sorted(entries.items(), key=lambda kv: float(kv[0]))
                       if e.get("kp") is not None})
    models[PRESETS["product-base"]] = PRODUCT_BASE_LABEL
    entries = read_tuned(None, "mpf", plant)
    models.update({f"mpf-tuned:h={h}": f"multi-predecessor CACC tuned h={h} s, r = "
                                       f"{e['r']} (the product's base)"
                   for h, e in sorted(entries.items(), key=lambda kv: float(kv[0]))
                   if e.get("name")})
    entries = read_tuned(None, "mpc", plant)
    models.update({f"mpc-tuned:h={h}": f"distributed MPC tuned h={h} s (ACC gap {e['ha']:g} s)"
                   for h, e in sorted(entries.items(), key=lambda kv: float(kv[0]))
                   if e.get("name")})
    return models


PRODUCT_BASE_LABEL = "Ploeg tuned h=0.6 s, trucks 0.8 s, its layers (the product's base)"
"""The row of ``product-base`` (:data:`carl_sumo.control.ploeg_names.PRESETS`) in the real
suite, beside the multi-predecessor law tuned on it (``mpf-tuned``) and the product."""


def default_data(quick: bool) -> str:
    """``--data`` when not given: the NGSIM table if it is where it belongs; ``default`` (quick)."""
    if quick:
        return "default"
    if DEFAULT_NGSIM.is_file():
        return str(DEFAULT_NGSIM)
    raise InputError(f"the NGSIM event table is not at {DEFAULT_NGSIM} (relative to {Path.cwd()});"
                     " pass --data PATH of ngsim_cf_events.csv.gz, or run --quick")


def policy_dir(path: Path | None) -> Path:
    """The directory of the shipped policies: ``path``, ``./policies`` or the repository's."""
    if path is not None:
        if not Path(path).is_dir():
            raise InputError(f"policy directory {path} does not exist; give --policies DIR with "
                             "the shipped policy files (ca_td3_10.pt, ...)")
        return Path(path)
    return Path("policies") if Path("policies").is_dir() else policies_dir()


SEEDS_DIR = "seeds"
"""Sub-directory of the policy directory with every training run: ``<stem>_seed<K>.pt``."""


def discover_model(stem: str, directory: Path) -> Model:
    """A policy model: ``<stem>.pt`` (the shipped run) and every ``seeds/<stem>_seed<K>.pt``.

    Files whose training seed repeats one already found are left out (the same run twice: the
    shipped file is one of the seed files). A policy on a classical base is named with it
    (``CA-TD3 on ploeg-tuned:h=1``).
    """
    from carl_sumo.learn.policy import read_policy_payload

    shipped = directory / f"{stem}.pt"
    if not shipped.is_file():
        raise InputError(f"policy {shipped} does not exist; the paper suite needs the shipped "
                         "policies (restore them from git, or pass --policies DIR)")
    pattern = re.compile(rf"{re.escape(stem)}_seed(\d+)\.pt")
    extra = sorted((p for p in (directory / SEEDS_DIR).glob(f"{stem}_seed*.pt")
                    if pattern.fullmatch(p.name)),
                   key=lambda p: int(pattern.fullmatch(p.name).group(1)))
    files, seeds = [], []
    algo, trained, fixed, base = "", None, None, "idm"
    for path in [shipped, *extra]:
        payload = read_policy_payload(path)  # the metadata only: no network is built here
        cfg, meta = payload["agent_config"], payload.get("metadata") or {}
        seed = meta.get("seed")
        if seed is None:
            seed = int(pattern.fullmatch(path.name).group(1)) if path != shipped else 0
        seed = int(seed)
        if seed in seeds:
            continue
        if not algo:
            algo = str(cfg["algo"])
            n_cfg = int(cfg.get("n_vehicles", 1))
            trained = int(meta.get("trained_vehicles", n_cfg))
            fixed = n_cfg if algo == "maddpg" else None
            base = str(cfg.get("base", "idm"))
        elif cfg["algo"] != algo:
            raise InputError(f"policy {path} is {cfg['algo']}, but {shipped} is {algo}; a "
                             "seed file must be the same algorithm as its shipped policy")
        files.append(str(path))
        seeds.append(seed)
    name = ALGO_NAMES.get(algo, algo) + ("" if base == "idm" else f" on {base}")
    return Model(stem, name, tuple(files), tuple(seeds), trained, fixed)


def data_tag(data: str) -> str:
    """The name of the leader data in the suite's file names: ``ngsim`` for an NGSIM event table
    (``ngsim*``), ``default`` for the shipped default set, else the file's name (letters, digits
    and ``_``), so that an output never claims data it did not run on."""
    if str(data) == "default":
        return "default"
    name = Path(data).name
    if name.startswith("ngsim"):
        return "ngsim"
    return re.sub(r"\W+", "_", name.split(".")[0]).strip("_").lower() or "data"


def data_titles(data: str, limit: int | None, quick: bool) -> tuple[str, str]:
    """What the tables ran on, for their titles: (the test split, the cross-site events), e.g.
    "NGSIM test split" or "test split of the shipped default set, first 2 events (--quick)"."""
    some = (f", first {limit} events" if limit else "") + (" (--quick)" if quick else "")
    if data == "default":
        return (f"test split of the shipped default set (not NGSIM){some}",
                f"train split of the shipped default set standing in (it has no US-101 "
                f"events){some}")
    if Path(data).name.startswith("ngsim"):
        return f"NGSIM test split{some}", f"US-101 (no model was trained on it){some}"
    return (f"test split of {Path(data).name}{some}",
            f"US-101 split of {Path(data).name} (no model was trained on it){some}")


def _events(es: EventSet, quick: bool, warmup_s: float = 0.0) -> list[Event]:
    if es.data == "stop-and-go":
        events = [stop_and_go_event(cycles=1, cruise_s=5.0) if quick else stop_and_go_event()]
    else:
        events = load_events(es.data, es.split, limit=es.limit)
    return [e.with_warmup(warmup_s) for e in events]


def figure_event(events: Sequence[Event]) -> str:
    """The event drawn in the time figures: the largest leader speed range among events of at
    least 30 s (among all events if none is that long)."""
    long = [e for e in events if e.duration_s - e.scored_from * e.dt >= 30.0] or list(events)
    return max(long, key=lambda e: float(np.ptp(e.leader_speed_mps))).event_id


def check_tables(only: tuple[str, ...] | None, suite: str) -> None:
    """InputError (one line) for ``--tables`` names that are not parts of ``suite``
    (:data:`TABLES`; None: every part)."""
    if only is None:
        return
    if not only or any(t not in TABLES for t in only):
        raise InputError(f"--tables {','.join(only)!r}: choose one or more of "
                         f"{', '.join(TABLES)}, separated by commas")
    if suite != "real" and set(only) == {"string_stability"}:
        raise InputError("--tables string_stability is a table of --suite real only")


def plan_suite(suite: str = "paper", data: str | None = None, quick: bool = False,
               events: int | None = None, policies: Path | None = None,
               net: str | Path = DEFAULT_NET, all_seeds: bool = False,
               seeds: bool = False, warmup_s: float = 0.0, plant: str = "ideal",
               extra: tuple[str, ...] = (), only: tuple[str, ...] | None = None) -> Suite:
    """Resolve data, events, policies and tables; InputError on anything missing or wrong.

    ``seeds``: the seed files of :data:`SEED_MODELS` run in Table 1 and in Table 2 at 10 followers
    (those are Table 1's runs), not in Table 3 or the cross-site table; ``all_seeds`` runs every model's
    seed files in every row (slower); with neither, no seed file runs (the shipped policies
    alone). ``warmup_s``: every event runs that long first, unscored (``Event.with_warmup``).
    ``plant``: the plant key of the real suite's tuned gains (:attr:`Impairments.plant_key`).
    ``extra``: controllers of the user's own (``module:attribute``), a row in every table.
    ``only``: the parts of :data:`TABLES` to run (None: all of them)."""
    check_tables(only, suite)
    if all_seeds and seeds:
        raise InputError("--all-seeds and --seeds exclude each other; give one")
    if suite not in SUITES:
        raise InputError(f"unknown suite {suite!r}; choose one of {', '.join(SUITES)}")
    if events is not None and events < 1:
        raise InputError(f"--events must be at least 1, got {events}")
    data = str(data) if data is not None else default_data(quick)
    limit = events if events is not None else (2 if quick else None)
    directory = policy_dir(policies)

    tag = data_tag(data)
    test = EventSet(f"{tag}_test", data, "test", limit)
    if data == "default":
        cross = EventSet("cross_site", data, "train", limit,
                         note="the shipped default set has no US-101 events; its train split "
                              "stands in for the cross-site table")
    else:
        cross = EventSet("cross_site", data, "us101", limit)
    sg = EventSet("stop_and_go", "stop-and-go", "test", None,
                  note="one synthetic leader: 25 m/s, " + ("one braking (--quick)" if quick else
                                                           "three brakings") + " at -5 m/s² to 1 m/s")
    classical = classical_models(plant=plant if suite == "real" else "ideal")
    if suite == "real":  # with the product beside its base and the laws on it
        classical = {"idm-external": BUILTIN_MODELS["idm-external"], **classical}
        extra = (PRODUCT_STEM, *extra)
    table1_models = ("human", "idm", "krauss", *classical, "maddpg_10", "ddpg_1", "ca_ddpg_10",
                     "td3_1", "ca_td3_10", "ca_td3_ploeg_10", *extra)
    seed_models = None if all_seeds else SEED_MODELS if seeds else ()
    table2_models = ("idm", "krauss", *classical, "maddpg_10", "maddpg_20", "ddpg_1", "td3_1",
                     "ca_ddpg_10", "ca_td3_10", "ca_ddpg_20", "ca_td3_20", "ca_td3_ploeg_10",
                     *extra)
    on_test, on_cross = data_titles(data, limit, quick)
    tables = [
        TableSpec(f"table1_{tag}_test", f"Table 1: {on_test}, 10 followers", test, (10,),
                  table1_models, figures=True,
                  paired=tuple(p for p in PAIRED_COMPARISONS if set(p) <= set(table1_models)),
                  seed_models=seed_models),
        TableSpec("table2_generalization", "Table 2: generalization to other platoon lengths, "
                  + on_test,
                  test, (10, 20) if quick else (10, 20, 50), table2_models,
                  seed_lengths=None if all_seeds else (10,), seed_models=seed_models),
        TableSpec("table3_stop_and_go", "Table 3: stop-and-go leader"
                  + (" (one braking, --quick)" if quick else "") + ", 10 followers", sg, (10,),
                  table1_models[1:], figures=True, seed_lengths=None if all_seeds else ()),
        TableSpec("cross_site_default_train" if data == "default" else "cross_site_us101",
                  f"Cross-site: {on_cross}, 10 followers", cross, (10,),
                  table1_models,
                  seed_lengths=None if all_seeds else ()),
    ]
    if only is not None:
        tables = [spec for spec in tables if spec.key.startswith(only)]
    models = _models(tables, classical, directory)
    event_sets = {spec.events.key: spec.events for spec in tables}
    loaded = {key: _events(es, quick, warmup_s) for key, es in event_sets.items()}
    if "cross_site" in loaded and not loaded["cross_site"]:
        raise InputError(f"{data} has no {cross.split} events for the cross-site table")
    route = lane_route(net)
    for spec in tables:  # a network too short fails here, before any worker starts
        for e in loaded[spec.events.key]:
            check_fits(route, e, max(spec.followers))
    figures = {spec.events.key: figure_event(loaded[spec.events.key]) for spec in tables
               if spec.figures}
    return Suite(tables, models, loaded, figures, data, quick, warmup_s=warmup_s, name=suite,
                 string_stability=only is None or "string_stability" in only)


def external_label(name: str) -> str:
    """The row name of a controller from outside carl-sumo: ``ATTR (FILE or MODULE)``."""
    target, _, attr = name.rpartition(":")
    return f"{attr} ({Path(target).name if target.endswith('.py') else target})"


def _models(tables: list[TableSpec], classical: dict[str, str], directory: Path
            ) -> dict[str, Model]:
    """The Model of every row key of the tables: built-in, classical, a controller of the user's
    own (module:attribute, file.py:attribute) or a policy stem with its seed files."""
    from carl_sumo.control.external import is_external_name

    models: dict[str, Model] = {}
    for spec in tables:
        for key in spec.models:
            if key in models:
                continue
            if is_classical(key):
                models[key] = Model(key, {**BUILTIN_MODELS, **classical}[key])
            elif is_external_name(key):
                models[key] = Model(key, external_label(key))
            else:
                models[key] = discover_model(key, directory)
    return models


def table_cells(spec: TableSpec, suite: Suite):
    """(model key, model, platoon length, followers simulated, controllers run) of every row of
    a table: the lengths a model can run (the recorded human follower is always one vehicle),
    with the seed files where ``spec.seed_lengths`` allows."""
    for key in spec.models:
        model = suite.models[key]
        for n in spec.followers:
            if model.runs_on(n):
                yield key, model, n, 1 if key == "human" else n, controllers_run(spec, model, n)


def controllers_run(spec: TableSpec, model: Model, n: int) -> tuple[str, ...]:
    """A model's controllers in a table at length n: all its seed files where
    ``spec.seed_lengths`` allows, the shipped one elsewhere."""
    spread = (spec.seed_lengths is None or n in spec.seed_lengths) and (
        spec.seed_models is None or model.key in spec.seed_models)
    return model.controllers if spread else model.controllers[:1]
