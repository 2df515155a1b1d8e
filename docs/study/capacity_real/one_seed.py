"""``python one_seed.py S STUDY-ARGS...``: ``carl-sumo study STUDY-ARGS`` for the one seed S.

Each run of the study is seeded by its (p, seed) alone (routes, SUMO, the plant's draws by vehicle
ID, the sensors by run name), so seed S here is the run that ``--seeds N`` (N > S) makes; this
adds a seed to a study already run without running seed 0 again. Used for seed 1 of the capacity
study (run.sh)."""

import sys

import carl_sumo.study.run as study_run
from carl_sumo.cli import main

SEED = int(sys.argv[1])
_Config = study_run.StudyConfig


def _one_seed(**kwargs):
    return _Config(**{**kwargs, "seeds": (SEED,)})


study_run.StudyConfig = _one_seed  # cmd_study imports it when it runs
sys.exit(main(["study", *sys.argv[2:]]))
