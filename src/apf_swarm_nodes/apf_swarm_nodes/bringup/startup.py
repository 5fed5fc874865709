"""Before the run: the checks that need no process (executables, recorder, output directory,
configuration), the run's isolation (domain id, discovery range, log directory) and the
node processes started, the recorder first."""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.config_files import to_ros_params

from ..topics import RECORDER_NODE
from .commands import executable_path, hosted_nodes, node_commands, node_netns, package_prefix
from .errors import BringupError
from .isolation import env_domain, pick_domain_id
from .processes import Child

if TYPE_CHECKING:
    from ..dds.secure import Pki
    from .flight_check import FlightCheck
    from .janitor import Janitor
    from .supervision import Supervisor
    from .zygote import Zygote

__all__ = ['Startup']


class Startup:
    """What a run does before it starts (the bring-up holds one): the checks that need no
    process (:meth:`prepare`), the isolation (:meth:`isolate`: :attr:`domain_id`, a secure
    run's :attr:`pki`), the zygote or janitor (:meth:`start_zygote`), the launch of the node
    processes into ``sup``'s groups (:meth:`launch`), and what it started, stopped
    (:meth:`close`)."""

    def __init__(
        self,
        args: argparse.Namespace,
        cfg: SwarmConfig,
        run_id: int,
        node_params: list[str],
        node_values: dict[str, str],
        sup: Supervisor,
        flight: FlightCheck,
        say: Callable[[str], None],
    ) -> None:
        self.args, self.cfg, self.run_id, self.node_params = args, cfg, run_id, node_params
        #: the same, read once: name -> value
        self.node_values = node_values
        self.mode: str = args.mode
        self.n = cfg.n_trackers
        self.out: Path = args.out
        self.group, self.rec_group = sup.group, sup.rec_group
        self.flight, self.say = flight, say
        self.domain_id: int | None = None
        #: a secure run's files (--secure), else None
        self.pki: Pki | None = None
        self.zygote: Zygote | None = None
        self.janitor: Janitor | None = None
        #: the monotonic time of the launch [s]
        self.t_launch: float | None = None
        self.prefix = Path()
        self.config_file = Path()

    def prepare(self) -> SwarmConfig:
        """Checks that need no process: executables, recorder, output directory, config.
        Returns the configuration to fly (realtime: the flight check's)."""
        import yaml

        if self.mode == 'realtime':
            self.cfg = self.flight.check(self.cfg)
        elif self.cfg.control_rate > 0:
            raise BringupError(
                f'control_rate = {self.cfg.control_rate:g} Hz: lockstep commands '
                'every step of dt; use --mode realtime, or --set control_rate=0'
            )
        prefix = package_prefix()
        names = [
            'target',
            'plant',
            'tracker' if self.args.trackers_per_process == 1 else 'trackers',
        ]
        if self.args.record:
            names.append('recorder')
            if (self.out / 'bag').exists():
                raise BringupError(
                    f'--record: {self.out / "bag"} exists already; a bag is never '
                    'overwritten: choose a new --out directory'
                )
        for name in names:
            path = executable_path(prefix, name)
            if not (path.is_file() and os.access(path, os.X_OK)):
                raise BringupError(
                    f'node executable {path} not found; build the workspace with `make setup`'
                )
        self.prefix = prefix
        (self.out / 'logs').mkdir(parents=True, exist_ok=True)
        self.config_file = self.out / 'config.yaml'
        self.config_file.write_text(yaml.safe_dump(to_ros_params(self.cfg), sort_keys=False))
        return self.cfg

    def isolate(self) -> None:
        """Domain id and discovery range into os.environ (before rclpy.init; children inherit)."""
        if self.args.domain_id is not None:
            self.domain_id = self.args.domain_id
        else:
            own = env_domain()
            self.domain_id = pick_domain_id(exclude=[own] if own is not None else [])
        os.environ['ROS_DOMAIN_ID'] = str(self.domain_id)
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = self.args.discovery_range
        os.environ.pop('ROS_LOCALHOST_ONLY', None)  # deprecated; would fight the range
        # every ROS log file of the run (this node's and the children's) under DIR/logs/ros
        os.environ['ROS_LOG_DIR'] = str((self.out / 'logs' / 'ros').resolve())
        # DDS: in LOCALHOST nothing from outside this machine (a Fast DDS profile that binds
        # 127.0.0.1), the discovery timing, and no second swarm on the domain (DdsError)
        from ..dds.profiles import isolate_dds

        processes = 3 + -(-self.n // self.args.trackers_per_process) + int(self.args.record)
        if getattr(self.args, 'secure', False):
            # a multi-host run that admits only its hosts: TLS, a per-run authority
            from ..dds.secure import secure_dds

            self.pki = secure_dds(
                self.out / 'dds',
                self.domain_id,
                self.args.discovery_range,
                hosts=[*(r.partition('=')[2] for r in self.args.node_netns),
                       *getattr(self.args, 'secure_host', [])],
                address=getattr(self.args, 'secure_address', None),
                processes=processes,
                run=f'{self.run_id}',
                reuse=getattr(self.args, 'secure_pki', None),
                say=self.say,
            )  # fmt: skip
            if not getattr(self.args, 'keep_keys', False):
                # a killed bring-up cannot remove the keys; its janitor does
                if self.janitor is None:
                    from .janitor import Janitor

                    self.janitor = Janitor()
                self.janitor.keys(self.out / 'dds')
            return
        isolate_dds(
            self.out / 'dds',
            self.domain_id,
            self.args.discovery_range,
            processes=processes,
            say=self.say,
        )

    @property
    def batch_commands(self) -> bool:
        """Whether the trackers send a process's commands as one message: by default in a
        secure realtime run of several trackers to a process; else as the
        ``batch_commands`` node parameter says."""
        given = self.node_values.get('batch_commands')
        several = (
            self.mode == 'realtime'
            and self.args.trackers_per_process > 1
            and self.node_values.get('inputs', 'aggregate') == 'aggregate'
        )
        if given is not None:
            return several and given.strip().lower() == 'true'
        return several and self.pki is not None

    def check_secure(self) -> None:
        """A secure run, before any node starts: the bring-up's own port (its participant,
        the discovery server) refuses a TLS client without the run's certificate."""
        if self.pki is None:
            return
        from ..dds.secure import check_refuses, first_address, server_port

        assert self.domain_id is not None
        address = getattr(self.args, 'secure_address', None) or first_address()
        check_refuses(address, server_port(self.domain_id))

    def close(self) -> None:
        """The run's end: the zygote and the janitor told goodbye, then a secure run's
        private keys removed, unless kept (--keep-keys)."""
        if self.zygote is not None:
            self.zygote.close()
        if self.janitor is not None:
            self.janitor.close()
        if self.pki is None or getattr(self.args, 'keep_keys', False):
            return
        from ..dds.secure import remove_keys

        remove_keys(self.out / 'dds')

    def host_env(self, env: dict[str, str], netns: str | None, name: str) -> dict[str, str]:
        """The environment of node process ``name`` on the simulated host ``netns`` (None:
        this host): a secure run's nodes take their host's files, a process of trackers
        only the client profile (:data:`~..dds.secure.CLIENT_PROFILE_FILE`)."""
        if self.pki is None:
            return env
        from ..dds.secure import THIS_HOST, secure_environment

        host = self.pki.hosts.get(THIS_HOST if netns is None else netns)
        if host is None:
            return env
        nodes = hosted_nodes(name)
        trackers = bool(nodes) and all(n.endswith('/tracker') for n in nodes)
        profile = host.client_profile if trackers else host.profile
        return {**env, **secure_environment(profile, self.pki.openssl)}

    def start_zygote(self) -> None:
        """``--spawn fork``: start the zygote first, so that its imports overlap the
        preparation (the node processes are forked from it at the launch). Nodes executed
        instead: the janitor, which cleans up after them if this bring-up is killed."""
        if getattr(self.args, 'spawn', 'exec') == 'fork':
            from .zygote import Zygote

            self.zygote = Zygote()
            if self.zygote.usable:
                return
            self.say(f'--spawn fork unavailable ({self.zygote.error}); executing the nodes')
            self.zygote = None
        from .janitor import Janitor

        self.janitor = Janitor()

    def child_env(self) -> dict[str, str]:
        env = dict(os.environ)
        env.setdefault('PYTHONUNBUFFERED', '1')
        env.setdefault('RCUTILS_COLORIZED_OUTPUT', '0')
        return env

    def launch(self) -> None:
        self.check_secure()
        env = self.child_env()
        cmds = node_commands(
            self.prefix,
            self.config_file.resolve(),
            self.n,
            self.mode,
            # the run's identity: its nodes refuse the commands and states of another run
            # recorded: each writer waits for the recorder's reader before its first message
            [
                # over TLS a message costs more than its bytes: one command message per
                # process (docs/PERFORMANCE.md, "Secure multi-host runs"); a bag records
                # it as /swarm/force_cmds
                *(['batch_commands:=true'] if self.batch_commands else []),
                *self.node_params,
                f'run:={self.run_id}',
                *(['recorded:=true'] if self.args.record else []),
            ],
            per_process=self.args.trackers_per_process,
        )
        self.t_launch = time.monotonic()
        if self.args.record:
            # first, so that it subscribes to every topic as soon as its publisher appears
            rec = Child(
                'recorder',
                [
                    str(executable_path(self.prefix, 'recorder')),
                    '--ros-args',
                    '-r',
                    f'__node:={RECORDER_NODE}',
                    '-p',
                    f'mode:={self.mode}',
                    '-p',
                    f'output:={(self.out / "bag").resolve()}',
                    '-p',
                    f'config_file:={self.config_file.resolve()}',
                    *[a for p in self.node_params for a in ('-p', p)],
                ],
                self.out / 'logs' / 'recorder.log',
                env,
                zygote=self.zygote,
                janitor=self.janitor,
            )
            self.rec_group.add(rec)
            self.rec_group.start_all()
        for name, cmd in cmds:
            ns = node_netns(name, self.args.node_netns)  # a simulated host (multihost.py)
            self.group.add(
                Child(
                    name,
                    cmd,
                    self.out / 'logs' / f'{name}.log',
                    self.host_env(env, ns, name),
                    zygote=self.zygote,
                    netns=ns,
                    janitor=self.janitor,
                )
            )
        self.group.start_all()
        if self.zygote is not None and self.zygote.error:
            self.say(f'warning: the zygote failed ({self.zygote.error}); nodes executed instead')
        self.say(
            f'started {len(cmds) + len(self.rec_group.children)} processes '
            f'{"(forked) " if self.zygote is not None else ""}on ROS_DOMAIN_ID={self.domain_id} '
            f'({self.args.discovery_range}), {self.mode}, {self.n} trackers, '
            f'logs in {self.out / "logs"}'
        )
