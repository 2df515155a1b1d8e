"""Helpers shared by the ``carl-sumo`` command modules: common options and value checks."""

from __future__ import annotations

import argparse
import math

from carl_sumo.errors import InputError


def add_common(p: argparse.ArgumentParser, split_default: str = "test") -> None:
    p.add_argument("--net", default="networks/i80.net.xml", help="SUMO network (.net.xml)")
    p.add_argument("--data", default="default",
                   help="default | stop-and-go | PATH of an event table or a raw NGSIM CSV")
    p.add_argument("--split", default=split_default, help="test | train | us101 | all")
    p.add_argument("--vehicles", type=int, default=10, help="number of CACC followers")


def positive(value: int, name: str) -> int:
    if value < 1:
        raise InputError(f"{name} must be at least 1, got {value}")
    return value


def fmt(value: float) -> str:
    if isinstance(value, int):
        return str(value)
    return "nan" if math.isnan(value) else f"{value:.3f}"
