"""Helpers shared by the ``carl-sumo`` command modules: common options and value checks."""

from __future__ import annotations

import argparse
from pathlib import Path
import math
import sys
from contextlib import contextmanager
from typing import Iterator

from carl_sumo.errors import InputError


class Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (InputError: exit status 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise InputError(f"{message} (see `{self.prog} --help`)")

    def _get_value(self, action: argparse.Action, arg_string: str):  # type: ignore[override]
        """An empty path (``--out ""``) is refused: it would mean the current folder."""
        if (action.type in (Path, net_option) or action.dest in PATH_DESTS) \
                and isinstance(arg_string, str) and not arg_string.strip():
            name = "/".join(action.option_strings) or action.dest
            raise InputError(f"{name} is an empty path; give the path of a file or folder (an "
                             "empty path never means the current folder)")
        return super()._get_value(action, arg_string)


PATH_DESTS = frozenset({"data", "init", "resume", "out", "json", "fcd", "plot", "policies",
                        "results", "spec", "checkpoint", "policy", "files", "h_min_table"})
"""Options whose value is a path even where argparse keeps it as a string."""


def net_option(text: str) -> str:
    """``--net``: the path as given, or, when no such file exists, the shipped network of that
    file name (``--net i80.net.xml`` from any folder, as ``--data default`` finds its leaders)."""
    from carl_sumo.resources import NETWORKS, shipped

    return shipped(text, NETWORKS)


def controller_option(text: str) -> str:
    """``--controller``: each comma-separated name with a preset law (``cacc-real``,
    :data:`carl_sumo.control.ploeg_names.PRESETS`) or policy (``product``) or a shipped policy's
    file name resolved (:func:`carl_sumo.resources.controller_name`)."""
    from carl_sumo.control.ploeg_names import expand_preset
    from carl_sumo.resources import controller_name

    return ",".join(controller_name(expand_preset(c.strip())) if c.strip() else c
                    for c in text.split(","))


NET_HELP = "SUMO network (.net.xml; a shipped network's file name works from any folder)"


def add_common(p: argparse.ArgumentParser, split_default: str = "test") -> None:
    p.add_argument("--net", type=net_option, default="i80.net.xml", help=NET_HELP)
    p.add_argument("--data", default="default",
                   help="default | stop-and-go | PATH of an event table or a raw NGSIM CSV")
    p.add_argument("--split", default=split_default, help="test | train | us101 | all")
    p.add_argument("--vehicles", type=int, default=10, help="number of CACC followers")


def add_impairments(p: argparse.ArgumentParser) -> None:
    """The V2V channel and sensor options (:mod:`carl_sumo.control.channel`); defaults: perfect."""
    p.add_argument("--comm-delay", type=float, default=None, metavar="S",
                   help="every V2V message arrives S seconds late (a multiple of 0.1 s; default "
                        "0, or 0.1 with --plant real)")
    p.add_argument("--comm-loss", type=float, default=0.0, metavar="P",
                   help="every V2V message is lost with probability P")
    p.add_argument("--comm-burst", type=float, default=1.0, metavar="L",
                   help="losses come in bursts of mean length L steps (Gilbert-Elliott; 1: "
                        "independent)")
    p.add_argument("--comm-timeout", type=float, default=1.0, metavar="S",
                   help="a receiver falls back (CA: the boundary message; Ploeg: ACC) when its "
                        "last message is older than S seconds (default 1)")
    p.add_argument("--comm-fade", type=float, default=1.0, metavar="S",
                   help="past the timeout the held message fades linearly into the fallback "
                        "over S seconds (default 1; 0: a hard switch)")
    p.add_argument("--sensor-noise", action="store_true",
                   help="Gaussian noise on the measured gap (0.1 m) and relative speed (0.1 m/s)")
    p.add_argument("--sensor-filter", action="store_true",
                   help="with --sensor-noise: every follower filters its measured gap and "
                        "relative speed with a Kalman tracker (docs/robustness.md)")
    p.add_argument("--impairment-seed", type=int, default=0,
                   help="seed of the losses, the noise and the fleet's draws (default 0)")
    add_plant(p)


def add_plant(p: argparse.ArgumentParser) -> None:
    """The vehicle dynamics of the followers (:mod:`carl_sumo.sim.vehicle`); default: ideal."""
    p.add_argument("--plant", choices=("ideal", "real"), default="ideal",
                   help="ideal: every follower applies its command at once (the paper's "
                        "protocol, default); real: the default fleet (80 %% cars, 20 %% trucks, "
                        "lag and dead time drawn per class) and a 0.1 s V2V delay; the options "
                        "below replace its parts")
    p.add_argument("--fleet", default=None, metavar="SPEC",
                   help="vehicle classes with fractions, e.g. car:0.7,truck:0.3 (each "
                        "follower's class drawn per event; docs/vehicles.md)")
    p.add_argument("--vehicle-lag", type=float, default=None, metavar="S",
                   help="powertrain lag tau of every follower (s; first order)")
    p.add_argument("--actuation-delay", type=float, default=None, metavar="S",
                   help="actuation dead time of every follower (s; a multiple of 0.1 s)")


def add_event_choice(p: argparse.ArgumentParser) -> None:
    """train's options that choose its validation events and weight its training events."""
    p.add_argument("--eval-events", type=int, default=None,
                   help="held-out training events used for validation (default 8)")
    p.add_argument("--val-seed", type=int, default=None,
                   help="seed choosing the held-out events (default: --seed); give runs of "
                        "several seeds one --val-seed to compare them on the same events")
    p.add_argument("--val-source", default=None,
                   help="hold the validation events out of this event source only (the data "
                        "file's `source` column), e.g. the one most like the test set")
    p.add_argument("--val-events", default=None, metavar="FILE",
                   help="a file of training event IDs (one per line) held out and validated "
                        "on too, e.g. the hardest (benchmarks/hard_events.py)")
    p.add_argument("--exclude-events", default=None, metavar="FILE",
                   help="a file of training event IDs (one per line) left out of training and "
                        "validation, e.g. recordings that start in a collision")
    p.add_argument("--oversample", default=None, metavar="FILE",
                   help="a file of training event IDs (one per line) drawn --oversample-times "
                        "as often as the others in training, e.g. the hardest ones that "
                        "validation does not hold out (benchmarks/hard_events.py)")
    p.add_argument("--oversample-times", type=int, default=None, metavar="K",
                   help="how many times as often the --oversample events are drawn (default 4)")


def add_warmup(p: argparse.ArgumentParser) -> None:
    """``--warmup S``: a settling run before every event (:meth:`Event.with_warmup`)."""
    p.add_argument("--warmup", type=float, default=0.0, metavar="S",
                   help="run every event S seconds (a multiple of 0.1) longer at its start, the "
                        "leader holding its initial speed, so the platoon settles at its own "
                        "spacing before the recorded leader starts; metrics score the recorded "
                        "part only (default 0: the platoon starts at the recorded gap)")


def warmup_from(args: argparse.Namespace) -> float:
    """The checked ``--warmup`` (s); InputError for a negative value or one that is not a whole
    number of 0.1 s steps."""
    from carl_sumo.config import DT_S

    from carl_sumo.data.events import check_warmup

    s = check_warmup(args.warmup)
    if abs(s / DT_S - round(s / DT_S)) > 1e-6:
        raise InputError(f"--warmup {s} is not a multiple of the {DT_S} s step; give e.g. "
                         f"{round(s / DT_S) * DT_S:g}")
    return float(s)


def impairments_from(args: argparse.Namespace):
    """The :class:`carl_sumo.control.channel.Impairments` of parsed options (InputError if invalid), or
    None when everything is perfect."""
    from carl_sumo.control.channel import Impairments

    if args.sensor_filter and not args.sensor_noise and not getattr(args, "comm_randomize", None):
        raise InputError("--sensor-filter filters noisy measurements: give it with --sensor-noise"
                         + (" or --comm-randomize" if hasattr(args, "comm_randomize") else ""))
    return Impairments.from_options(args)


def positive(value: int, name: str) -> int:
    if value < 1:
        raise InputError(f"{name} must be at least 1, got {value}")
    return value


def fmt(value: float) -> str:
    if isinstance(value, int):
        return str(value)
    return "nan" if math.isnan(value) else f"{value:.3f}"


def add_ray(p: argparse.ArgumentParser, what: str = "the SUMO tasks") -> None:
    """``--ray ADDRESS``: run ``what`` as Ray tasks (:mod:`carl_sumo.scale.cluster`)."""
    p.add_argument("--ray", default=None, metavar="ADDRESS",
                   help=f"run {what} on Ray: local (a Ray runtime in this process with --workers "
                        "CPUs), auto (the cluster started here with `ray start --head`) or "
                        "HOST:PORT of a cluster's head; needs pip install -e '.[ray]'")


def check_ray(args: argparse.Namespace) -> None:
    """InputError now (before any long work) for a malformed ``--ray`` or a missing extra."""
    if getattr(args, "ray", None) is not None:
        from carl_sumo.scale.cluster import check_address, import_ray

        check_address(args.ray)
        import_ray()


@contextmanager
def ray_session(args: argparse.Namespace, num_cpus: int | None = None) -> Iterator[None]:
    """Connected to ``--ray`` (when given) for the block, ``num_cpus`` CPUs for ``local``;
    afterwards one line on stderr says how many tasks ran on which nodes."""
    if getattr(args, "ray", None) is None:
        yield
        return
    from carl_sumo.scale import cluster

    cluster.connect(args.ray, num_cpus)
    try:
        yield
    finally:
        if cluster.last_nodes:
            print(f"ray: {cluster.describe_nodes()}", file=sys.stderr)
        cluster.disconnect()


def workers_for(args: argparse.Namespace, default: int) -> int:
    """``--workers`` if given (at least 1), else: with ``--ray`` the CPUs of the Ray runtime
    (call inside :func:`ray_session`), without it ``default``."""
    if args.workers is not None:
        return positive(args.workers, "--workers")
    if getattr(args, "ray", None) is not None:
        from carl_sumo.scale.cluster import cluster_cpus

        return cluster_cpus()
    return default
