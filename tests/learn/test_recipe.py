"""The training configuration's single definition: the generated options, recipe files and the
configuration stored in policy files."""

from __future__ import annotations

import shlex
from dataclasses import asdict, fields
from pathlib import Path

import pytest

from carl_sumo.cli import main
from carl_sumo.errors import InputError
from carl_sumo.learn.recipe import option_fields, read_recipe, recipe_toml
from carl_sumo.learn.train_config import SECTIONS, TrainConfig

REPO = Path(__file__).resolve().parents[2]


def _train_actions():
    from carl_sumo.cli.policies import train_parser

    parser = train_parser()
    (sub,) = [a for a in parser._actions if hasattr(a, "choices") and a.choices]
    return {a.dest: a for a in sub.choices["train"]._actions}


def test_every_training_option_is_one_field_with_doc_section_and_a_generated_flag():
    actions = _train_actions()
    for f in fields(TrainConfig):
        meta = f.metadata
        assert meta["doc"] and meta["section"] in SECTIONS, f.name
    for key, f in option_fields().items():
        action = actions[key]
        assert action.default is None  # not given: the recipe's or the field's default
        assert f.metadata["doc"].replace("%", "%%")[:30] in action.help, key
    extra = set(actions) - set(option_fields())
    assert extra == {"help", "config", "print_config", "resume", "ray", "tensorboard",
                     "progress_every"}


def test_reward_agent_and_channel_options_are_defined_once_where_they_are_used():
    """A reward, agent or channel option of TrainConfig is RewardConfig's, AgentConfig's or
    Impairments' field (one default, doc, unit and range), of the same type, and comes back as
    that field's value."""
    from typing import get_type_hints

    from carl_sumo.config import REWARD, RewardConfig
    from carl_sumo.learn.agents import AgentConfig

    hints = get_type_hints(TrainConfig)
    taken = {}
    for f in fields(TrainConfig):
        if "source" in f.metadata:
            source, name = f.metadata["source"]
            (src,) = [g for g in fields(source) if g.name == name]
            assert f.default == src.default and hints[f.name] == get_type_hints(source)[name]
            assert {k: v for k, v in f.metadata.items() if k != "source"} == dict(src.metadata)
            taken.setdefault(source, set()).add(name)
    from carl_sumo.control.channel import Impairments

    for source in (RewardConfig, AgentConfig, Impairments):  # every option they have a user sets
        assert taken[source] == {g.name for g in fields(source) if g.metadata.get("cli")}
    cfg = TrainConfig(spacing_gap=1.1, noise=0.3, shield_ttc=2.0, update_every=2, scale_rates=True)
    assert cfg.reward.spacing_gap_s == 1.1 and cfg.reward.w_gap == REWARD.w_gap
    agent = cfg.agent_config()
    assert (agent.exploration_noise, agent.shield_ttc_s, agent.actor_lr) == (0.3, 2.0, 2 * 3e-4)


def test_train_help_shows_each_default_and_unit(capsys):
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "vector steps (each steps every environment once) (in [1, 100000000]; default 20000)" \
        in text
    assert "policy file (none: policies/ALGO.pt)" in text
    assert "bound of the learned adjustment |a_adj| (m/s²;" in text


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_recipe_extends_another_and_the_command_line_overrides_it(tmp_path, capsys):
    _write(tmp_path / "base.toml", '[agent]\nalgo = "td3"\nvehicles = 3\n[training]\nsteps = 500\nlearning_starts = 100\n'
           'scale_rates = true\nupdate_every = 3\n')
    child = _write(tmp_path / "child.toml", 'extends = "base.toml"\n[training]\nsteps = 700\n')
    assert read_recipe(child) == {"algo": "td3", "n_vehicles": 3, "steps": 700, "learning_starts": 100,
                                  "scale_rates": True, "update_every": 3}
    assert main(["train", "--config", str(child), "--vehicles", "4", "--no-scale-rates",
                 "--print-config"]) == 0
    printed = capsys.readouterr().out
    again = _write(tmp_path / "again.toml", printed)
    cfg = TrainConfig(**read_recipe(again))
    assert (cfg.algo, cfg.n_vehicles, cfg.steps, cfg.scale_rates) == ("td3", 4, 700, False)
    assert recipe_toml(cfg) == printed


def test_none_on_the_command_line_leaves_a_recipes_option_out(tmp_path, capsys):
    recipe = _write(tmp_path / "r.toml", '[base]\nbase = "product-base"\n[training]\n'
                    'imitate = "two-ahead:c=0.3"\n')
    assert main(["train", "--config", str(recipe), "--print-config"]) == 0
    assert 'imitate = "two-ahead:c=0.3"' in capsys.readouterr().out
    assert main(["train", "--config", str(recipe), "--imitate", "none", "--print-config"]) == 0
    assert "# imitate = (none)" in capsys.readouterr().out


@pytest.mark.parametrize("text, needle", [
    ("[agent]\nsteps = 5\n", "steps belongs in [training], not [agent]"),
    ("[agent]\nnot_an_option = 1\n", "not_an_option is not a training option"),
    ("[training]\nsteps = 5.5\n", "steps = 5.5 is not int"),
    ("[stuff]\nx = 1\n", "unknown entry 'stuff'"),
    ('extends = "r.toml"\n', "extends itself"),
    ("[training\n", "not readable TOML"),
    ("[agent]\nadj_max = -1\n", "--adj-max must be a finite number in (0, 100]"),
])
def test_a_bad_recipe_is_one_line_and_exit_2(tmp_path, capsys, text, needle):
    recipe = _write(tmp_path / "r.toml", text)
    out = tmp_path / "p.pt"
    assert main(["train", "--config", str(recipe), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err
    assert not out.exists()


def test_a_missing_recipe_is_one_line(capsys):
    assert main(["train", "--config", "nowhere/r.toml"]) == 2
    assert "recipe nowhere/r.toml does not exist" in capsys.readouterr().err


def _recorded(meta: dict) -> TrainConfig:
    from carl_sumo.cli.policies import check_train_args
    from carl_sumo.cli.policies import train_parser

    return check_train_args(train_parser().parse_args(shlex.split(meta["command"])[1:]))[0]


@pytest.mark.parametrize("recipe", sorted((REPO / "recipes").glob("*.toml")), ids=lambda p: p.stem)
def test_each_shipped_recipe_is_the_configuration_of_its_seed_files(recipe, monkeypatch):
    """recipes/<stem>.toml resolves to the configuration recorded in its seed 0 file (the seed
    and the output aside)."""
    from carl_sumo.learn.policy import read_policy_payload

    monkeypatch.chdir(REPO)
    seed_file = REPO / "policies" / "seeds" / f"{recipe.stem}_seed0.pt"
    assert seed_file.exists(), f"no seed file for {recipe.name}"
    recorded = _recorded(read_policy_payload(seed_file)["metadata"])
    from carl_sumo.cli.config_options import config_from_args
    from carl_sumo.cli.policies import train_parser

    args = train_parser().parse_args(["train", "--config", str(recipe.relative_to(REPO)),
                                      "--seed", "0"])
    resolved = config_from_args(args, converters={})
    drop = ("out", "command", "net", "init")
    assert {k: v for k, v in asdict(resolved).items() if k not in drop} == \
        {k: v for k, v in asdict(recorded).items() if k not in drop}
    assert read_recipe(recipe) is not None
    text = recipe.read_text()
    assert "description" in text


def test_policy_info_prints_a_recipe_that_retrains_the_shipped_product(tmp_path, capsys,
                                                                       monkeypatch):
    monkeypatch.chdir(REPO)
    assert main(["policy-info", "--recipe", "policies/ca_td3_real_10.pt"]) == 0
    printed = _write(tmp_path / "product.toml", capsys.readouterr().out)
    assert main(["train", "--config", str(printed), "--print-config"]) == 0
    again = capsys.readouterr().out
    def body(text: str) -> str:
        return text[text.index("[data]"):]

    assert body(again) == body(printed.read_text())
    with pytest.raises(InputError):
        from carl_sumo.learn.recipe import config_from_stored

        config_from_stored({"no_such_option": 1})


def test_a_trained_policy_stores_its_configuration_and_says_how_it_compares_with_its_base(
        tmp_path, capsys):
    recipe = _write(tmp_path / "tiny.toml", '[data]\nnet = "i80.net.xml"\n[agent]\nalgo = "td3"\n'
                    'vehicles = 2\n[training]\nsteps = 60\nlearning_starts = 20\nenvs = 1\n'
                    'checkpoint_every = 60\n[validation]\neval_every = 60\neval_events = 1\n')
    out = tmp_path / "tiny.pt"
    assert main(["train", "--config", str(recipe), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "kept policy vs its base (idm) on the validation events: headway_s" in printed
    from carl_sumo.learn.policy import read_policy_payload

    stored = read_policy_payload(out)["metadata"]["config"]
    assert stored["steps"] == 60 and stored["algo"] == "td3" and stored["vehicles"] == 2
    assert main(["policy-info", "--recipe", str(out)]) == 0
    again = _write(tmp_path / "again.toml", capsys.readouterr().out)
    retrained = asdict(TrainConfig(**read_recipe(again)))
    wanted = asdict(TrainConfig(**read_recipe(recipe), out=str(out)))
    assert Path(retrained.pop("net")).name == wanted.pop("net")
    assert retrained == wanted


def test_the_commands_sharing_train_options_take_them_from_its_fields(capsys):
    """simulate, evaluate, study ... have train's channel, sensor, plant, data and warm-up
    options from the same fields: one help text, default, allowed values and range."""
    from carl_sumo.cli import build_parser
    from carl_sumo.cli.common import IMPAIRMENT_OPTIONS, PLANT_OPTIONS
    from carl_sumo.cli.config_options import help_of

    parser = build_parser()
    (sub,) = [a for a in parser._actions if hasattr(a, "choices") and a.choices]
    by_name = {f.name: f for f in fields(TrainConfig)}
    for command in ("simulate", "replay", "evaluate", "tune", "study", "string-stability"):
        actions = {a.dest: a for a in sub.choices[command]._actions}
        for name in (*IMPAIRMENT_OPTIONS, *PLANT_OPTIONS):
            f, action = by_name[name], actions[name]
            assert action.help == help_of(f) and action.default == f.default, (command, name)
    assert main(["simulate", "--comm-delay", "6", "--events", "1"]) == 2
    assert "--comm-delay must be a finite number in [0, 5]" in capsys.readouterr().err
