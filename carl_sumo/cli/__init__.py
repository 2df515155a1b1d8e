"""The ``carl-sumo`` command line.

Bad input (missing or malformed files, unknown options, events, controllers, a network too short)
ends with one line ``carl-sumo: error: ...`` on stderr and exit status 2; nothing is half-written.
Ctrl-C, SIGTERM and SIGHUP stop a command with exit status 128 + the signal's number, its worker
processes and any sumo-gui with it, and leave no output or temporary file.
"""

from __future__ import annotations

import argparse
import os
import sys

from carl_sumo.cli.common import Parser
from carl_sumo.cli.data import _data_parser, _net_parser, cmd_data, cmd_net
from carl_sumo.cli.policies import (_export_parser, _policy_info_parser, _rank_parser,
                                    _train_parser, _tune_parser, cmd_export, cmd_policy_info,
                                    cmd_rank, cmd_train, cmd_tune)
from carl_sumo.cli.run import (_bench_parser, _evaluate_parser, _replay_parser, _simulate_parser,
                               cmd_bench, cmd_evaluate, cmd_replay, cmd_simulate, format_table)
from carl_sumo.cli.stability import _string_stability_parser, cmd_string_stability
from carl_sumo.cli.study import _study_parser, cmd_study
from carl_sumo.cli.sweep import _sweep_parser, cmd_sweep
from carl_sumo import COMMAND_MARK
from carl_sumo.errors import InputError
from carl_sumo.interrupts import exit_status, ignore_stop_signals, stop_on_signals, stopped
from carl_sumo.scale.workers import WorkerError, stop_children

__all__ = ["COMMANDS", "build_parser", "format_table", "main"]

EXIT_BAD_INPUT = 2


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``carl-sumo``: each subcommand's options are defined beside the command
    (``_<command>_parser`` above ``cmd_<command>``, in the module of its command group)."""
    parser = Parser(prog="carl-sumo", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    for add in (_simulate_parser, _replay_parser, _evaluate_parser, _train_parser, _sweep_parser,
                _tune_parser, _export_parser, _policy_info_parser, _rank_parser, _bench_parser,
                _study_parser, _string_stability_parser, _net_parser, _data_parser):
        add(sub)
    return parser


COMMANDS = {"simulate": cmd_simulate, "evaluate": cmd_evaluate, "train": cmd_train,
            "policy-info": cmd_policy_info, "export": cmd_export, "tune": cmd_tune,
            "sweep": cmd_sweep,
            "replay": cmd_replay,
            "bench": cmd_bench, "rank": cmd_rank, "net": cmd_net, "study": cmd_study,
            "data": cmd_data, "string-stability": cmd_string_stability}


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status: 0 done, 2 bad input or an output that cannot be
    written, 1 a worker died for good, 128 + n stopped by signal n (SIGINT, SIGTERM, SIGHUP)."""
    restore_signals = stop_on_signals()
    marked = os.environ.get(COMMAND_MARK)
    os.environ[COMMAND_MARK] = "1"  # its workers leave Ctrl-C to it from their first import
    try:
        return _run(argv)
    finally:
        if marked is None:
            os.environ.pop(COMMAND_MARK, None)
        if argv is None and stopped():  # the process exits with 128 + n: a second signal on
            ignore_stop_signals()       # the way out must not kill it by the signal
        else:
            restore_signals()


def _run(argv: list[str] | None) -> int:
    try:
        args = build_parser().parse_args(argv)
        COMMANDS[args.command](args)
    except InputError as exc:
        print(f"carl-sumo: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except WorkerError as exc:  # a worker process died twice on the same task
        print(f"carl-sumo: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: every `finally` has run
        stop_children()
        print("carl-sumo: interrupted", file=sys.stderr)
        return exit_status(exc)
    except BrokenPipeError:  # the reader went away (`carl-sumo rank ... | head`): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return 0

