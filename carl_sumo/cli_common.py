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


def add_impairments(p: argparse.ArgumentParser) -> None:
    """The V2V channel and sensor options (:mod:`carl_sumo.channel`); defaults: perfect."""
    p.add_argument("--comm-delay", type=float, default=0.0, metavar="S",
                   help="every V2V message arrives S seconds late (a multiple of 0.1 s)")
    p.add_argument("--comm-loss", type=float, default=0.0, metavar="P",
                   help="every V2V message is lost with probability P")
    p.add_argument("--comm-burst", type=float, default=1.0, metavar="L",
                   help="losses come in bursts of mean length L steps (Gilbert-Elliott; 1: "
                        "independent)")
    p.add_argument("--comm-timeout", type=float, default=1.0, metavar="S",
                   help="a receiver falls back (CA: the boundary message; Ploeg: ACC) when its "
                        "last message is older than S seconds (default 1)")
    p.add_argument("--sensor-noise", action="store_true",
                   help="Gaussian noise on the measured gap (0.1 m) and relative speed (0.1 m/s)")
    p.add_argument("--impairment-seed", type=int, default=0,
                   help="seed of the losses and the noise (default 0)")


def impairments_from(args: argparse.Namespace):
    """The :class:`carl_sumo.channel.Impairments` of parsed options (InputError if invalid), or
    None when everything is perfect."""
    from carl_sumo.channel import Impairments

    imp = Impairments(args.comm_delay, args.comm_loss, args.comm_burst, args.comm_timeout,
                      args.sensor_noise, args.impairment_seed)
    return imp if imp.active else None


def positive(value: int, name: str) -> int:
    if value < 1:
        raise InputError(f"{name} must be at least 1, got {value}")
    return value


def fmt(value: float) -> str:
    if isinstance(value, int):
        return str(value)
    return "nan" if math.isnan(value) else f"{value:.3f}"
