"""The zygote (``--spawn fork``; docs/PERFORMANCE.md, "Fast start: the zygote"): one process
that imported rclpy, numpy, the nodes and every message type once, and forks each node
process of a run, respawns too, into the ``main()`` of its executable with its argv,
environment, cwd, log and ``ps`` line. It never initialises ROS. It forks twice so that the
node is re-parented to the bring-up (a child subreaper: :class:`ForkedProcess`); a batch runs
once its last node is forked.

Protocol: a JSON list of requests a line on stdin (``entry``, ``argv``, ``env``, ``cwd``,
``log``, ``netns``), the list of replies (``{"pid": N}`` or ``{"error": "..."}``) a line on
stdout; ``"bye"`` ends it. An input that ends without it (the bring-up died): the zygote
stops its nodes and removes their shared memory (:func:`orphaned_cleanup`).
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import psutil

if TYPE_CHECKING:
    from .processes import Child

__all__ = [
    'BYE',
    'DIST',
    'ForkedProcess',
    'Zygote',
    'become_subreaper',
    'close_helper',
    'main',
    'node_entry_points',
    'orphaned_cleanup',
]

#: the distribution whose console scripts are the node executables
DIST = 'apf-swarm-nodes'
#: console scripts that are not nodes (never preloaded or forked)
NOT_NODES = frozenset({'apf-swarm'})
#: prctl(2) options, and setns(2)'s type of a network namespace
PR_SET_CHILD_SUBREAPER, PR_SET_PDEATHSIG, CLONE_NEWNET = 36, 1, 0x40000000
#: the line that ends a helper's input when its bring-up closes it
BYE = 'bye'
#: seconds an orphaned zygote gives its nodes before it kills them, and waits before it
#: looks for stale shared memory a second time
ORPHAN_GRACE, ORPHAN_SECOND_LOOK = 5.0, 1.0
#: the node processes this zygote forked (the run's nodes and their respawns)
FORKED: list[psutil.Process] = []


def node_entry_points() -> dict[str, str]:
    """``{executable: 'module:function'}`` of the package's node console scripts."""
    from importlib.metadata import PackageNotFoundError, distribution

    try:
        eps = distribution(DIST).entry_points
    except PackageNotFoundError:
        return {}
    return {
        ep.name: ep.value
        for ep in eps
        if ep.group == 'console_scripts' and ep.name not in NOT_NODES
    }


def _prctl(option: int, value: int) -> bool:
    """Linux ``prctl(option, value)``; False where it fails."""
    try:
        return bool(ctypes.CDLL(None, use_errno=True).prctl(option, value, 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


def become_subreaper() -> bool:
    """Make this process the reaper of its orphaned descendants; False where impossible."""
    return _prctl(PR_SET_CHILD_SUBREAPER, 1)


# --- the bring-up's side ----------------------------------------------------------------------


def close_helper(proc: subprocess.Popen[bytes], goodbye: bytes) -> None:
    """End a helper (zygote, janitor) normally: ``goodbye`` and end of input on its stdin,
    then at most 5 s for it to exit before SIGKILL."""
    with contextlib.suppress(OSError, ValueError):
        if proc.stdin is not None:
            proc.stdin.write(goodbye + b'\n')
            proc.stdin.close()
    try:
        proc.wait(5.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()


class ForkedProcess:
    """A node process forked by the zygote and re-parented to this one: the part of
    :class:`subprocess.Popen` that :class:`~.processes.Child` uses."""

    def __init__(self, pid: int, args: Sequence[str]) -> None:
        self.pid = pid
        self.args = list(args)
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:
                # not (or no longer) our child: only a liveness check is left
                if not psutil.pid_exists(self.pid):
                    self.returncode = -signal.SIGKILL
                return self.returncode
            if pid == self.pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while (rc := self.poll()) is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
            time.sleep(0.01)
        return rc


class Zygote:
    """The bring-up's handle on a zygote process: :meth:`spawn_all` forks node processes,
    :meth:`close` ends the zygote (the nodes live on)."""

    def __init__(self) -> None:
        self.entries = node_entry_points()
        self.usable = bool(self.entries) and become_subreaper()
        self.proc: subprocess.Popen[bytes] | None = None
        self.error: str | None = None if self.usable else 'no child subreaper or no entry points'
        if not self.usable:
            return
        # its stderr is this process's: a zygote that fails says so where the bring-up talks
        self.proc = subprocess.Popen(
            [sys.executable, '-m', __name__],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            start_new_session=True,
            close_fds=True,
        )

    def spawn_all(self, children: Sequence[Child]) -> list[ForkedProcess | None]:
        """Fork the children's processes as one batch; None for each it cannot fork (not a
        node executable of the package, or the zygote is gone: the caller executes it)."""
        out: list[ForkedProcess | None] = [None] * len(children)
        entries = [self.entries.get(Path(c.argv[0]).name) if c.argv else None for c in children]
        batch = [i for i, entry in enumerate(entries) if entry]
        proc = self.proc
        if not batch or proc is None or proc.stdin is None or proc.stdout is None:
            return out
        requests = [
            {
                'entry': entries[i],
                'argv': list(c.argv),
                'env': dict(os.environ if c.env is None else c.env),
                'cwd': None if c.cwd is None else str(c.cwd),
                'log': str(c.log_path),
                'netns': c.netns,
            }
            for i, c in ((i, children[i]) for i in batch)
        ]
        try:
            proc.stdin.write(json.dumps(requests).encode() + b'\n')
            proc.stdin.flush()
            line = proc.stdout.readline()
        except OSError as exc:
            line = b''
            self.error = f'zygote pipe: {exc}'
        if not line:
            self.error = self.error or f'zygote ended ({proc.poll()})'
            self.close()
            return out
        for i, reply in zip(batch, json.loads(line), strict=True):
            if 'pid' in reply:
                out[i] = ForkedProcess(int(reply['pid']), children[i].argv)
            else:
                self.error = str(reply.get('error'))
        return out

    def close(self) -> None:
        """Goodbye: the zygote exits, its nodes live on."""
        proc, self.proc = self.proc, None
        if proc is not None:
            close_helper(proc, json.dumps(BYE).encode())


# --- the zygote's side ------------------------------------------------------------------------


def preload(entries: Mapping[str, str]) -> None:
    """Import every node module, load the type support of every message, service and action
    (until no new one appears), and fill the :mod:`inspect` and :mod:`linecache` caches
    rclpy's logger reads: what each node would otherwise do while it starts."""
    import inspect
    import linecache

    from rclpy.type_support import check_for_type_support

    for value in entries.values():
        importlib.import_module(value.partition(':')[0])
    from apf_swarm_core.kernels import warm

    warm()  # the control kernels' machine code, shared with every node process
    done: set[str] = set()
    while todo := [
        name
        for name, module in list(sys.modules.items())
        if module is not None
        and name not in done
        and name.rpartition('.')[2] in ('msg', 'srv', 'action')
    ]:
        for name in todo:
            done.add(name)
            for attr in list(vars(sys.modules[name]).values()):
                if isinstance(attr, type) and hasattr(attr, '__import_type_support__'):
                    with contextlib.suppress(Exception):
                        check_for_type_support(attr)
    frame = inspect.currentframe()
    if frame is not None:
        inspect.getframeinfo(frame)  # builds inspect's module cache
    for name, module in list(sys.modules.items()):
        file = getattr(module, '__file__', None)
        if name.startswith(('apf_swarm', 'rclpy')) and file and file.endswith('.py'):
            linecache.getlines(file)


def fork_node() -> int:
    """Like :func:`os.fork` (0 in the child, its pid here), through an intermediate process
    that exits: the node is not this process's child."""
    r, w = os.pipe()
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    first = os.fork()
    if first == 0:
        os.close(r)
        try:
            second = os.fork()
        except OSError:
            os._exit(1)
        if second == 0:
            os.close(w)
            return 0
        os.write(w, b'%d' % second)
        os._exit(0)
    os.close(w)
    with os.fdopen(r, 'rb') as f:
        data = f.read()
    os.waitpid(first, 0)
    if not data:
        raise OSError('the intermediate process could not fork')
    return int(data)


def enter_netns(name: str) -> None:
    """Move this single-threaded process into network namespace ``/run/netns/NAME``, or exit 2
    with the reason in its log."""
    try:
        fd = os.open(f'/run/netns/{name}', os.O_RDONLY | os.O_CLOEXEC)
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.setns(fd, CLONE_NEWNET) != 0:
                raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))
        finally:
            os.close(fd)
    except OSError as exc:
        print(
            f'error: cannot enter network namespace {name!r}: {exc}', file=sys.stderr, flush=True
        )
        os._exit(2)


def become_node(request: Mapping[str, Any]) -> None:
    """In the forked node process: what executing it would have given it (own session,
    default signals, its log as stdout and stderr, environment, cwd, argv, ``ps`` line)."""
    os.setsid()
    signal.signal(signal.SIGINT, signal.default_int_handler)  # the zygote ignores it
    # SIGINT (a clean DDS exit) when the bring-up dies, even by SIGKILL
    _prctl(PR_SET_PDEATHSIG, signal.SIGINT)
    if os.getppid() == 1:  # the bring-up died before that: no one would stop this node
        os._exit(0)
    for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGCHLD, signal.SIGUSR1):
        signal.signal(sig, signal.SIG_DFL)
    log = os.open(request['log'], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    null = os.open(os.devnull, os.O_RDONLY)
    for fd, target in ((null, 0), (log, 1), (log, 2)):
        os.dup2(fd, target)
    os.close(log)
    os.close(null)
    # unbuffered text streams, as PYTHONUNBUFFERED gives an executed node
    sys.stdin = open(0, closefd=False)  # noqa: SIM115 (the process's stdin, never closed)
    sys.stdout = open(1, 'w', buffering=1, closefd=False)  # noqa: SIM115
    sys.stderr = open(2, 'w', buffering=1, errors='backslashreplace', closefd=False)  # noqa: SIM115
    if request.get('netns'):  # a simulated host: its sockets, as `ip netns exec` gives them
        enter_netns(request['netns'])
    os.environ.clear()
    os.environ.update(request['env'])
    if request.get('cwd'):
        os.chdir(request['cwd'])
    sys.argv = list(request['argv'])
    import setproctitle

    setproctitle.setproctitle(' '.join([sys.executable, *sys.argv]))
    setproctitle.setthreadtitle(Path(sys.argv[0]).name)  # what top shows


def serve(requests: IO[bytes], replies: IO[bytes]) -> Mapping[str, Any] | None:
    """Answer batches of requests until the goodbye (exits) or the end of input (None); in a
    forked node process, return its request once its whole batch is forked."""
    for line in requests:
        try:
            batch = json.loads(line)
            bad = None if isinstance(batch, list) else 'expected a JSON list of requests'
        except ValueError as exc:
            batch, bad = [], f'ValueError: {exc}'
        if batch == BYE:  # the bring-up closes it: it stops its nodes itself
            sys.exit(0)
        results: list[dict[str, Any]] = [] if bad is None else [{'error': bad}]
        gate_r, gate_w = os.pipe()  # its end of file lets the batch run
        for request in batch if bad is None else []:
            try:
                pid = fork_node()
            except OSError as exc:
                results.append({'error': f'{type(exc).__name__}: {exc}'})
                continue
            if pid == 0:
                os.close(gate_w)
                os.read(gate_r, 1)
                os.close(gate_r)
                return dict(request)
            results.append({'pid': pid})
            with contextlib.suppress(psutil.Error):  # (its start time: no pid reused later)
                FORKED.append(psutil.Process(pid))
        os.close(gate_w)
        os.close(gate_r)
        replies.write(json.dumps(results).encode() + b'\n')
        replies.flush()
    return None


def _running(p: psutil.Process) -> bool:
    """Running and not a zombie (which holds no lock and no mapping)."""
    try:
        return bool(p.is_running() and p.status() != psutil.STATUS_ZOMBIE)
    except psutil.Error:
        return False


def _running_after(procs: Sequence[psutil.Process], seconds: float) -> list[psutil.Process]:
    """Those of ``procs`` still running once all have ended or ``seconds`` have passed."""
    deadline = time.monotonic() + seconds
    pending = [p for p in procs if _running(p)]
    while pending and time.monotonic() < deadline:
        time.sleep(0.05)
        pending = [p for p in pending if _running(p)]
    return pending


def orphaned_cleanup(nodes: Sequence[psutil.Process] | None = None) -> None:
    """The bring-up died and its nodes (default :data:`FORKED`) stop on their parent-death
    signal: give them :data:`ORPHAN_GRACE` s plus the bring-up's per-process stop time,
    SIGKILL the session of each one left, then remove the stale Fast DDS shared memory."""
    from ..dds import shm
    from ..lifetime import STOP_CPU_PER_PROCESS

    pending = _running_after(FORKED if nodes is None else nodes, 0.0)
    grace = ORPHAN_GRACE + STOP_CPU_PER_PROCESS * len(pending) / (os.cpu_count() or 1)
    for p in _running_after(pending, grace):
        with contextlib.suppress(OSError):
            os.killpg(p.pid, signal.SIGKILL)  # its own session: the node and its children
    _running_after(pending, 5.0)  # the kernel drops a killed node's locks at its exit
    with contextlib.suppress(OSError):
        shm.remove_stale()
        # a node started just before the bring-up died, and not told of, frees its own later
        time.sleep(ORPHAN_SECOND_LOOK)
        shm.remove_stale()


def main() -> None:
    """Preload, then serve the bring-up; in a forked node process, run the node's main()."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the bring-up's to handle
    requests, replies = sys.stdin.buffer, sys.stdout.buffer
    preload(node_entry_points())
    import gc

    import setproctitle

    # set up once, while the environment still lies behind argv (where it finds it)
    setproctitle.setproctitle(setproctitle.getproctitle())
    gc.collect()
    gc.freeze()  # the preloaded objects stay shared with every node process
    request = serve(requests, replies)
    if request is None:  # no goodbye: the bring-up died and could stop nothing
        orphaned_cleanup()
        return
    become_node(request)
    module, _, func = request['entry'].partition(':')
    sys.exit(getattr(importlib.import_module(module), func)())


if __name__ == '__main__':
    main()
