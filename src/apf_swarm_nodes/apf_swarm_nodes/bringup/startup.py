"""Before the run: the checks that need no process, the run's isolation (domain id,
discovery range, DDS profiles, log directory) and the launch of its processes."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from apf_swarm_core.config import SwarmConfig
from apf_swarm_core.config_files import to_ros_params

from ..dds.domains import env_domain, pick_domain_id
from .commands import (
    Plan,
    executable_path,
    hosted_nodes,
    node_commands,
    node_netns,
    package_prefix,
    recorder_command,
)
from .errors import BringupError
from .processes import Child

if TYPE_CHECKING:
    from ..dds.secure import Pki
    from .flight_check import FlightCheck
    from .janitor import Janitor
    from .supervision import Supervisor
    from .zygote import Zygote

__all__ = ['Startup']


class Startup:
    """What a run does before it starts: :meth:`prepare`, :meth:`isolate`,
    :meth:`start_zygote`, :meth:`launch` (into ``sup``'s groups), and :meth:`close` at its
    end."""

    def __init__(
        self,
        plan: Plan,
        run_id: int,
        sup: Supervisor,
        flight: FlightCheck,
        say: Callable[[str], None],
    ) -> None:
        self.plan, self.run_id, self.sup, self.flight, self.say = plan, run_id, sup, flight, say
        self.domain_id: int | None = None
        #: a secure run's files (--secure), else None
        self.pki: Pki | None = None
        self.zygote: Zygote | None = None
        self.janitor: Janitor | None = None
        #: the monotonic time of the launch [s]
        self.t_launch: float | None = None
        self.prefix = Path()
        self.config_file = plan.out / 'config.yaml'

    def prepare(self) -> SwarmConfig:
        """Check executables, bag and configuration, write DIR/config.yaml; returns the
        configuration to fly (realtime: the flight check's)."""
        import yaml

        plan, cfg = self.plan, self.plan.cfg
        if plan.mode == 'realtime':
            cfg = self.flight.check(cfg)
        elif cfg.control_rate > 0:
            raise BringupError(
                f'control_rate = {cfg.control_rate:g} Hz: lockstep commands '
                'every step of dt; use --mode realtime, or --set control_rate=0'
            )
        self.prefix = package_prefix()
        names = ['target', 'plant', 'tracker' if plan.trackers_per_process == 1 else 'trackers']
        if plan.record:
            names.append('recorder')
            if (plan.out / 'bag').exists():
                raise BringupError(
                    f'--record: {plan.out / "bag"} exists already; a bag is never '
                    'overwritten: choose a new --out directory'
                )
        for name in names:
            path = executable_path(self.prefix, name)
            if not (path.is_file() and os.access(path, os.X_OK)):
                raise BringupError(
                    f'node executable {path} not found; build the workspace with `make setup`'
                )
        (plan.out / 'logs').mkdir(parents=True, exist_ok=True)
        self.config_file.write_text(yaml.safe_dump(to_ros_params(cfg), sort_keys=False))
        return cfg

    def isolate(self) -> None:
        """Domain id and discovery range into os.environ (before rclpy.init; children inherit)."""
        plan = self.plan
        if plan.domain_id is not None:
            self.domain_id = plan.domain_id
        else:
            own = env_domain()
            self.domain_id = pick_domain_id(exclude=[own] if own is not None else [])
        os.environ['ROS_DOMAIN_ID'] = str(self.domain_id)
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = plan.discovery_range
        os.environ.pop('ROS_LOCALHOST_ONLY', None)  # deprecated; would fight the range
        os.environ['ROS_LOG_DIR'] = str((plan.out / 'logs' / 'ros').resolve())
        from ..dds.profiles import isolate_dds

        processes = 3 + -(-plan.n // plan.trackers_per_process) + int(plan.record)
        if not plan.secure:
            isolate_dds(
                plan.out / 'dds',
                self.domain_id,
                plan.discovery_range,
                processes=processes,
                say=self.say,
            )
            return
        # a multi-host run that admits only its hosts: TLS, a per-run authority
        from ..dds.secure import secure_dds

        self.pki = secure_dds(
            plan.out / 'dds',
            self.domain_id,
            plan.discovery_range,
            hosts=[*(r.partition('=')[2] for r in plan.node_netns), *plan.secure_host],
            address=plan.secure_address,
            processes=processes,
            run=f'{self.run_id}',
            reuse=plan.secure_pki,
            say=self.say,
        )
        if not plan.keep_keys:  # a killed bring-up cannot remove the keys; its janitor does
            if self.janitor is None:
                from .janitor import Janitor

                self.janitor = Janitor()
            self.janitor.keys(plan.out / 'dds')

    def close(self) -> None:
        """Goodbye to the zygote and the janitor; a secure run's keys removed (unless
        --keep-keys)."""
        if self.zygote is not None:
            self.zygote.close()
        if self.janitor is not None:
            self.janitor.close()
        if self.pki is None or self.plan.keep_keys:
            return
        from ..dds.secure import remove_keys

        remove_keys(self.plan.out / 'dds')

    def host_env(self, env: dict[str, str], netns: str | None, name: str) -> dict[str, str]:
        """The environment of node process ``name`` on host ``netns`` (None: this one): a
        secure run's take their host's files, a process of trackers its client profile."""
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
        """``--spawn fork``: the zygote, early (its imports overlap the preparation); else, or
        if it cannot, the janitor, which cleans up after executed nodes."""
        if self.plan.spawn == 'fork':
            from .zygote import Zygote

            self.zygote = Zygote()
            if self.zygote.usable:
                return
            self.say(f'--spawn fork unavailable ({self.zygote.error}); executing the nodes')
            self.zygote = None
        from .janitor import Janitor

        self.janitor = Janitor()

    def launch(self) -> None:
        """Start the recorder (first: it subscribes to each topic as its publisher appears),
        then the node processes, forked as one batch where the zygote can."""
        plan, logs = self.plan, self.plan.out / 'logs'
        if self.pki is not None:  # the bring-up's own port refuses a TLS client without a cert
            from ..dds.secure import check_refuses, first_address, server_port

            assert self.domain_id is not None
            check_refuses(plan.secure_address or first_address(), server_port(self.domain_id))
        env = {'PYTHONUNBUFFERED': '1', 'RCUTILS_COLORIZED_OUTPUT': '0', **os.environ}
        config_file = self.config_file.resolve()
        # batch_commands: docs/PERFORMANCE.md, "Secure multi-host runs"; run: the nodes refuse
        # another run's messages; recorded: each writer waits for the recorder's reader
        params = [
            *(['batch_commands:=true'] if plan.batch_commands else []),
            *plan.node_params,
            f'run:={self.run_id}',
            *(['recorded:=true'] if plan.record else []),
        ]
        cmds = node_commands(
            self.prefix, config_file, plan.n, plan.mode, params, plan.trackers_per_process
        )
        self.t_launch = time.monotonic()
        recorder = []
        if plan.record:
            bag = (plan.out / 'bag').resolve()
            argv = recorder_command(self.prefix, plan.mode, bag, config_file, plan.node_params)
            recorder = [('recorder', argv)]
        for group, commands in ((self.sup.rec_group, recorder), (self.sup.group, cmds)):
            for name, cmd in commands:
                rec = group is self.sup.rec_group
                ns = None if rec else node_netns(name, plan.node_netns)  # a simulated host
                group.add(
                    Child(
                        name,
                        cmd,
                        logs / f'{name}.log',
                        env if rec else self.host_env(env, ns, name),
                        zygote=self.zygote,
                        netns=ns,
                        janitor=self.janitor,
                    )
                )
            group.start_all()
        if self.zygote is not None and self.zygote.error:
            self.say(f'warning: the zygote failed ({self.zygote.error}); nodes executed instead')
        self.say(
            f'started {len(cmds) + len(self.sup.rec_group.children)} processes '
            f'{"(forked) " if self.zygote is not None else ""}on ROS_DOMAIN_ID={self.domain_id} '
            f'({plan.discovery_range}), {plan.mode}, {plan.n} trackers, logs in {logs}'
        )
