"""Helpers shared by the ``carl-sumo`` command modules: common options and value checks."""

from __future__ import annotations

import argparse
from pathlib import Path
import math
import sys
from contextlib import contextmanager
from typing import Iterator

from carl_sumo.cli.config_options import add_shared_options, check_shared_options, help_of
from carl_sumo.learn.train_config import TrainConfig
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


PATH_DESTS = frozenset({"data", "net", "exclude_events", "oversample", "val_events", "init",
                        "resume", "out", "json", "fcd", "plot", "policies", "results", "spec",
                        "checkpoint", "policy", "files", "h_min_table"})
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


NET_HELP = help_of(TrainConfig.__dataclass_fields__["net"])
"""``--net``'s help: ``train``'s (its default shown: the shipped network)."""


def add_common(p: argparse.ArgumentParser, split_default: str = "test") -> None:
    p.add_argument("--net", type=net_option, default="i80.net.xml", help=NET_HELP)
    add_shared_options(p, ("data",))
    p.add_argument("--split", default=split_default, help="test | train | us101 | all")
    p.add_argument("--vehicles", type=int, default=10, help="number of CACC followers")


IMPAIRMENT_OPTIONS = ("comm_delay", "comm_loss", "comm_burst", "comm_timeout", "comm_fade",
                      "sensor_noise", "sensor_filter", "impairment_seed")
"""The V2V channel and sensor options (:mod:`carl_sumo.control.channel`): ``train``'s fields."""

PLANT_OPTIONS = ("plant", "fleet", "vehicle_lag", "actuation_delay")
"""The followers' vehicle dynamics options (:mod:`carl_sumo.sim.vehicle`): ``train``'s fields."""


def add_impairments(p: argparse.ArgumentParser) -> None:
    """The V2V channel, sensor and plant options, as ``train`` has them; defaults: perfect."""
    add_shared_options(p, IMPAIRMENT_OPTIONS)
    add_plant(p)


def add_plant(p: argparse.ArgumentParser) -> None:
    """The vehicle dynamics of the followers, as ``train`` has them; default: ideal."""
    add_shared_options(p, PLANT_OPTIONS)


def add_warmup(p: argparse.ArgumentParser) -> None:
    """``--warmup S``: a settling run before every event (:meth:`Event.with_warmup`)."""
    add_shared_options(p, ("warmup",))


def warmup_from(args: argparse.Namespace) -> float:
    """The checked ``--warmup`` (s); InputError for a negative value or one that is not a whole
    number of 0.1 s steps."""
    from carl_sumo.data.events import check_warmup, check_whole_steps

    return float(check_whole_steps(check_warmup(args.warmup)))


def impairments_from(args: argparse.Namespace):
    """The :class:`carl_sumo.control.channel.Impairments` of parsed options (InputError if invalid), or
    None when everything is perfect."""
    from carl_sumo.control.channel import Impairments

    if args.sensor_filter and not args.sensor_noise and not getattr(args, "comm_randomize", None):
        raise InputError("--sensor-filter filters noisy measurements: give it with --sensor-noise"
                         + (" or --comm-randomize" if hasattr(args, "comm_randomize") else ""))
    impairments = Impairments.from_options(args)
    check_shared_options(args, IMPAIRMENT_OPTIONS + PLANT_OPTIONS)  # train's bounds, as --help says
    return impairments


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
