"""Shipped files found by name from any folder, presets, progress lines and the Gymnasium
registration on ``import carl_sumo``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from carl_sumo.cli import main
from carl_sumo.progress import Tracker, track
from carl_sumo.resources import (DEFAULT_NET, NETWORKS, PRODUCT, VTYPES_FILE, controller_name,
                                 policies_dir, shipped)

REPO = Path(__file__).resolve().parents[1]


def test_shipped_files_are_package_data_of_carl_sumo():
    import carl_sumo

    package = Path(carl_sumo.__file__).parent
    assert DEFAULT_NET.is_file() and DEFAULT_NET.parent == package / "networks"
    assert VTYPES_FILE.is_file() and VTYPES_FILE.parent == package / "routes"
    assert (policies_dir() / PRODUCT).is_file()


def test_a_shipped_file_is_found_by_its_name_and_a_real_path_wins(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert shipped("networks/i80.net.xml", NETWORKS) == str(DEFAULT_NET)
    assert shipped("nowhere.net.xml", NETWORKS) == "nowhere.net.xml"
    own = tmp_path / "i80.net.xml"
    own.write_text("<net/>")
    assert shipped("i80.net.xml", NETWORKS) == "i80.net.xml"
    assert controller_name("product") == str(policies_dir() / PRODUCT)
    assert controller_name("policies/ca_td3_10.pt") == str(policies_dir() / "ca_td3_10.pt")
    assert controller_name("ploeg:h=0.8") == "ploeg:h=0.8"


def test_the_event_lists_are_package_data_that_recipes_name_from_any_folder(tmp_path,
                                                                            monkeypatch):
    """The event lists the recipes name live in the data layer and are found by file name from
    any folder; a recipe printed back names them (and the network) by file name too."""
    from carl_sumo.cli.config_options import config_from_args
    from carl_sumo.cli.policies import train_parser
    from carl_sumo.data.events import read_event_ids
    from carl_sumo.learn.recipe import recipe_toml
    from carl_sumo.resources import EVENT_LISTS, shipped_name

    lists = sorted(p.name for p in EVENT_LISTS.glob("*.txt"))
    assert lists == ["exclude_start_overlap.txt", "train_hard_real.txt", "val_hard4_real.txt",
                     "val_hard_real.txt"]
    assert not list((REPO / "policies").glob("*.txt"))
    monkeypatch.chdir(tmp_path)
    recipe = REPO / "recipes" / "ca_td3_real_10.toml"
    args = train_parser().parse_args(["train", "--config", str(recipe), "--data", "default"])
    cfg = config_from_args(args, check=False)
    assert cfg.val_events == str(EVENT_LISTS / "val_hard4_real.txt")
    assert len(read_event_ids(cfg.val_events)) == 4
    text = recipe_toml(cfg)
    assert 'val_events = "val_hard4_real.txt"' in text and 'net = "i80.net.xml"' in text
    assert shipped_name("policies/val_hard_real.txt", EVENT_LISTS) == "val_hard_real.txt"
    own = tmp_path / "val_hard_real.txt"
    own.write_text("x\n")
    assert shipped_name("val_hard_real.txt", EVENT_LISTS) == "val_hard_real.txt"  # its own
    assert shipped_name(str(own), EVENT_LISTS) == str(own)


def test_the_product_runs_by_name_from_another_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "--controller", "product", "--plant", "real", "--events", "1",
                 "--vehicles", "4", "--workers", "1"]) == 0  # its start hears 3 vehicles ahead
    out = capsys.readouterr().out
    assert PRODUCT in out and "nan" not in out.split(PRODUCT)[1].splitlines()[0]


def test_progress_lines_without_a_terminal(capsys):
    assert list(track(range(3), 3, "study", "run", progress=1e-9)) == [0, 1, 2]
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith("study: 3/3 runs (100 %)") and len(lines) == 3
    quiet = Tracker(2, "x", progress=False)
    quiet.update(2)
    assert capsys.readouterr().err == ""


def test_import_carl_sumo_registers_the_environment():
    code = ("import gymnasium, carl_sumo; assert carl_sumo.ENV_ID in gymnasium.registry; "
            "import sys; assert 'carl_sumo.learn.gym_env' not in sys.modules; "
            "assert 'torch' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=REPO)


def test_no_source_checkout_path_outside_resources():
    """The package finds its files through carl_sumo.resources only (a wheel has no repo)."""
    offenders = [str(p.relative_to(REPO)) for p in (REPO / "carl_sumo").rglob("*.py")
                 if "parents[2]" in p.read_text() or "REPO_ROOT" in p.read_text()]
    assert offenders == []


def test_the_policies_readme_is_the_generated_index(monkeypatch, capsys):
    monkeypatch.chdir(REPO)
    assert main(["policy-info", "--index", "policies"]) == 0
    assert capsys.readouterr().out == (REPO / "policies" / "README.md").read_text(), \
        "regenerate it: carl-sumo policy-info --index policies > policies/README.md"


def test_law_presets_expand_in_every_command(capsys):
    from carl_sumo.cli.common import controller_option
    from carl_sumo.control.ploeg_names import PRESETS

    assert controller_option("cacc-real,idm") == PRESETS["cacc-real"] + ",idm"
    assert main(["train", "--base", "product-base", "--print-config", "--steps", "2000"]) == 0
    assert f'base = "{PRESETS["product-base"]}"' in capsys.readouterr().out


def test_the_wheel_lists_every_subpackage():
    import tomllib

    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
                 ["packages"])
    on_disk = {"carl_sumo"} | {f"carl_sumo.{p.name}" for p in (REPO / "carl_sumo").iterdir()
                               if (p / "__init__.py").is_file()}
    assert on_disk | {"carl_sumo.shipped"} == listed
