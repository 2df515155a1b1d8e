"""The ``net`` and ``data`` commands: build the network, list and make leader data."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from carl_sumo.cli.common import (NET_HELP, net_option, Parser)
from carl_sumo.files import check_output_file

if TYPE_CHECKING:
    pass


def _net_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("net", help="network tools")
    net_sub = p.add_subparsers(dest="net_command", required=True, parser_class=Parser)
    b = net_sub.add_parser("build", help="regenerate the shipped i80.net.xml with netconvert")
    b.add_argument("--config", type=Path, default=None, help="netconvert .netccfg")
    b.add_argument("--out", type=Path, default=None)


def cmd_net(args: argparse.Namespace) -> None:
    from carl_sumo.sim.network import NET_FILE, NET_SOURCES, build_network

    out = check_output_file(args.out or NET_FILE, "--out")
    out = build_network(args.config or NET_SOURCES, out)
    print(f"wrote {out}")


def _data_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("data", help="leader data tools")
    data_sub = p.add_subparsers(dest="data_command", required=True, parser_class=Parser)
    d = data_sub.add_parser("list", help="list the events of a split")
    d.add_argument("--data", default="default")
    d.add_argument("--split", default="all")
    d = data_sub.add_parser("make-default", help="regenerate the shipped default leader set")
    d.add_argument("--net", type=net_option, default="i80.net.xml", help=NET_HELP)
    d.add_argument("--out", type=Path, default=None)
    d.add_argument("--seed", type=int, default=42)


def cmd_data(args: argparse.Namespace) -> None:
    if args.data_command == "list":
        from carl_sumo.data import load_events

        for e in load_events(args.data, args.split):
            print(f"{e.event_id}\t{e.source}\t{e.duration_s:.1f} s\t"
                  f"mean leader speed {e.leader_speed_mps.mean():.2f} m/s")
    else:
        from carl_sumo.data import DEFAULT_EVENTS
        from carl_sumo.data.default_set import make_default_set

        out = check_output_file(args.out or DEFAULT_EVENTS, "--out")
        table = make_default_set(Path(args.net), Path(out), seed=args.seed)
        print(f"wrote {out}: {table['event_id'].nunique()} events")


