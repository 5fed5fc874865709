"""The bring-up's command line (``scripts/swarm_up.py``, ``apf-swarm up``)."""

from __future__ import annotations

import argparse
import faulthandler
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from apf_swarm_core.config_files import resolve
from apf_swarm_core.errors import ApfSwarmError

from ..argtypes import (
    add_config_args,
    add_view_args,
    domain_id,
    node_param,
    nonneg_int,
    positive_float,
    positive_int,
)
from ..capacity import probe
from ..capacity.probe import PROCESSES_PER_CORE
from .commands import Plan
from .isolation import check_capacity
from .processes import EXIT_BAD_INPUT, EXIT_INTERRUPTED
from .session import Bringup

__all__ = ['add_arguments', 'main', 'plan', 'run']


def _netns_rule(text: str) -> str:
    pattern, sep, ns = text.partition('=')
    if not sep or not pattern or not ns:
        raise argparse.ArgumentTypeError(f'{text!r}: expected PATTERN=NETNS, e.g. tracker_*=h2')
    return text


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``swarm_up.py`` / ``apf-swarm up``."""
    add_config_args(p)
    p.add_argument('--n-trackers', type=int, metavar='N', help='number of tracker processes')
    p.add_argument(
        '--mode',
        choices=('lockstep', 'realtime'),
        default='lockstep',
        help='lockstep: simulated time, reproduces the simulator (default); '
        'realtime: wall-clock timers',
    )
    p.add_argument(
        '--duration',
        type=positive_float,
        metavar='S',
        help='simulated (lockstep) or wall (realtime) seconds',
    )
    p.add_argument('--seed', type=int, metavar='N')
    p.add_argument(
        '--domain-id',
        type=domain_id,
        metavar='N',
        help='ROS_DOMAIN_ID of the run (default: a random unused-looking one, 1..101); a '
        'domain that already carries a swarm (a publisher of its topics) is refused',
    )
    p.add_argument(
        '--discovery-range',
        choices=('LOCALHOST', 'SUBNET', 'SYSTEM_DEFAULT', 'OFF'),
        default='LOCALHOST',
        help='LOCALHOST (default): every socket bound to 127.0.0.1 (DIR/dds/; '
        'docs/RELIABILITY.md, "Isolation"); SUBNET or SYSTEM_DEFAULT: open to the network, '
        'for nodes on several hosts (scripts/multihost.py); OFF: no discovery',
    )
    p.add_argument(
        '--secure',
        action='store_true',
        help='with --discovery-range SUBNET: admit only the hosts of this run (this one, each '
        '--node-netns namespace, each --secure-host): a per-run authority, TLS both ways, '
        'files in DIR/dds/, keys removed at the end (docs/RELIABILITY.md, "Multi-host runs: '
        'threat model")',
    )
    p.add_argument(
        '--secure-host',
        action='append',
        default=[],
        metavar='NAME',
        help='--secure: also issue files for host NAME (DIR/dds/NAME/), for nodes started '
        'there by hand; repeatable',
    )
    p.add_argument(
        '--secure-address',
        metavar='ADDR',
        help="--secure: this host's address the others reach its discovery server at "
        '(default: its first non-loopback IPv4 address)',
    )
    p.add_argument(
        '--keep-keys',
        action='store_true',
        help="--secure: keep the hosts' private keys after the run (default: removed)",
    )
    p.add_argument(
        '--secure-pki',
        type=Path,
        metavar='DIR',
        help='--secure: reuse the DIR/dds/ files of an earlier run kept with --keep-keys, '
        'each checked (a missing, expired, mismatched or exposed file stops the bring-up)',
    )
    p.add_argument(
        '--record', action='store_true', help='also record a rosbag2 (MCAP) with the recorder node'
    )
    p.add_argument(
        '--trackers-per-process',
        type=_per_process,
        default=0,
        metavar='K',
        help='host the trackers K to a process (executable trackers; each still '
        'its own node with its own namespace and parameters); default auto: about '
        f'{PROCESSES_PER_CORE} tracker processes per core, one tracker each for small swarms '
        '(`apf-swarm probe` prints the choice)',
    )
    p.add_argument(
        '--spawn',
        choices=('fork', 'exec'),
        default='fork',
        help='how node processes start: fork (default) from a zygote that imported rclpy, '
        'numpy and the nodes once, the same main() and command line as the executable; '
        'exec: each runs its executable, as ros2 run does (slower start)',
    )
    p.add_argument(
        '--node-netns',
        type=_netns_rule,
        action='append',
        default=[],
        metavar='PATTERN=NETNS',
        help='run the node processes whose name matches PATTERN in that network '
        'namespace (root; forked into it, or under `ip netns exec` with --spawn exec): '
        'simulated hosts, see scripts/multihost.py; repeatable, first match wins',
    )
    p.add_argument(
        '--allow-overload',
        action='store_true',
        help="start more tracker processes than this machine's limit, which "
        'its probe derives (`apf-swarm probe`)',
    )
    p.add_argument(
        '--on-recorder-death',
        choices=('stop', 'continue'),
        default='stop',
        help='with --record: what a dying recorder does to the run (default stop; '
        'continue: fly on unrecorded, reindex the bag afterwards)',
    )
    p.add_argument(
        '--respawn',
        action='store_true',
        help='restart a node process that dies (counted in summary.json)',
    )
    p.add_argument(
        '--max-respawns',
        type=nonneg_int,
        default=3,
        metavar='K',
        help='with --respawn: give up (exit 3) after K restarts of one node (default 3)',
    )
    p.add_argument(
        '--ready-timeout',
        type=positive_float,
        default=30.0,
        metavar='S',
        help='how long to wait for every node and topic (default 30)',
    )
    p.add_argument(
        '--stall-timeout',
        type=positive_float,
        default=20.0,
        metavar='S',
        help='stop when no /swarm/state arrives for this long (default 20)',
    )
    p.add_argument(
        '--gains',
        choices=('auto', 'config'),
        default='auto',
        help='realtime: auto (default) replaces the gains by designed ones (`apf-swarm design`) '
        "when the configuration's are predicted to lose the formation; config flies them",
    )
    p.add_argument('--no-plots', action='store_true', help='skip the PNG figures')
    add_view_args(p)
    p.add_argument(
        '--node-param',
        action='append',
        default=[],
        metavar='NAME:=VALUE',
        type=node_param,
        dest='node_params',
        help='a node parameter for every node (repeatable), e.g. executor:=events, inputs:=odom',
    )
    p.add_argument('--out', type=Path, required=True, metavar='DIR')


def _per_process(text: str) -> int:
    """``--trackers-per-process``: a positive count, or ``auto`` (0)."""
    return 0 if text == 'auto' else int(positive_int(text))


def plan(args: argparse.Namespace, prog: str) -> Plan:
    """The run the command line asks for, checked against this machine's capacity."""

    def say(text: str) -> None:
        print(f'{prog}: {text}', file=sys.stderr, flush=True)

    cfg = resolve(
        args.config,
        args.preset,
        args.sets,
        n_trackers=args.n_trackers,
        seed=args.seed,
        duration=args.duration,
    )
    per_process = args.trackers_per_process or probe.trackers_per_process(
        probe.load(), cfg.n_trackers, cfg.control_rate or None
    )  # auto: from the cached probe if there is one
    check_capacity(
        cfg.n_trackers, allow_overload=args.allow_overload, per_process=per_process, say=say
    )
    if per_process > 1 and not args.trackers_per_process:  # said once it is not refused
        say(
            f'hosting the trackers {per_process} to a process (--trackers-per-process K to choose)'
        )
    return Plan.from_args(args, cfg=cfg, trackers_per_process=per_process)


def run(args: argparse.Namespace, prog: str = 'swarm_up') -> int:
    """Run a bring-up from parsed arguments (:func:`add_arguments`); returns the exit code,
    or raises :class:`~apf_swarm_core.errors.ApfSwarmError` for bad input (before any start)."""
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # a hung run says where
    return Bringup(plan(args, prog), prog=prog).execute()


def main(argv: Sequence[str] | None = None, prog: str = 'swarm_up.py') -> int:
    """Entry point of ``scripts/swarm_up.py``."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description='Bring up the ROS 2 swarm (target, plant, one tracker process '
        'per UAV), run it, and write trajectory.npz, summary.json, logs and figures.',
    )
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run(args, prog=prog)
    except ApfSwarmError as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        print(f'{prog}: error: {exc.strerror or exc}: {exc.filename or ""}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f'{prog}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    sys.exit(main())
