"""The live benchmarks' harness: the node in a process of its own, and an observer of its topics.

``bench live`` and ``bench soak`` measure the ``assessor`` node as a robot runs it: the node is
``python -m landing_zone.ros.node`` in its own process (its CPU time and memory read from
``/proc``), the clouds come from another process, and this process only watches: it subscribes
to ``/diagnostics`` and ``~/safety_grid`` on a private rclpy context and notes when each grid
arrived. Every run uses a DDS domain of its own (from the pid, 200..229: clear of the tests'
100..199 and 87) with discovery limited to this host.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

__all__ = ['bench_domain', 'dds_env', 'config_file', 'NodeProcess', 'Observer', 'load_line']


def bench_domain() -> int:
    """A DDS domain for this benchmark run: 200 + pid % 30."""
    return 200 + os.getpid() % 30


def config_file(name: str) -> Path:
    """A file of the package's ``config/`` (source tree, or ``share/landing_zone/config``)."""
    for directory in (Path(__file__).resolve().parents[3] / 'config',
                      Path(sys.prefix) / 'share' / 'landing_zone' / 'config'):
        if (directory / name).is_file():
            return directory / name
    raise FileNotFoundError(f'config/{name} is not installed')


def dds_env(domain: int, shm_profile: bool) -> dict[str, str]:
    """The environment of a benchmark process: its domain, localhost discovery and, with
    ``shm_profile``, the shipped Fast DDS profile (config/fastdds_shm.xml)."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    env.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
    env.pop('FASTDDS_DEFAULT_PROFILES_FILE', None)
    if shm_profile:
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(config_file('fastdds_shm.xml'))
    return env


def load_line() -> str:
    """The 1-minute load average against the cores: how busy the shared machine was."""
    try:
        with open('/proc/loadavg', encoding='utf-8') as f:
            return f'load average {f.read().split()[0]} on {os.cpu_count()} cores'
    except OSError:
        return 'load average unknown'


class NodeProcess:
    """``python -m landing_zone.ros.node`` with parameters, its log in a file.

    Args:
        params: ``name -> value`` node parameters.
        env: the process environment (:func:`dds_env`).
        log: where its output goes.
        remap: topic remappings ``from -> to``.
    """

    def __init__(self, params: dict[str, Any], env: dict[str, str], log: Path,
                 remap: dict[str, str] | None = None) -> None:
        args = [sys.executable, '-m', 'landing_zone.ros.node', '--ros-args']
        for name, value in params.items():
            args += ['-p', f'{name}:={value}']
        for src, dst in (remap or {}).items():
            args += ['-r', f'{src}:={dst}']
        self.log = log
        self._out = open(log, 'w', encoding='utf-8')
        self.proc = subprocess.Popen(args, env=env, stdout=self._out, stderr=subprocess.STDOUT)
        self._tick = os.sysconf('SC_CLK_TCK')

    def text(self) -> str:
        return self.log.read_text(encoding='utf-8', errors='replace')

    def wait_ready(self, timeout: float = 120.0) -> float:
        """Wait for the node's "ready in X s" line; return X.

        Raises:
            RuntimeError: the node exited or did not get ready in time (with its log).
        """
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            text = self.text()
            if 'ready in ' in text:
                return float(text.split('ready in ', 1)[1].split()[0])
            if self.proc.poll() is not None:
                raise RuntimeError(f'the node exited with {self.proc.returncode}:\n{text}')
            time.sleep(0.1)
        raise RuntimeError(f'the node was not ready after {timeout:.0f} s:\n{self.text()}')

    def cpu_seconds(self) -> float:
        """User + system CPU time of the node so far [s] (all its threads)."""
        with open(f'/proc/{self.proc.pid}/stat', encoding='utf-8') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / self._tick

    def memory_mb(self) -> tuple[float, float]:
        """(resident now, resident peak) [MB]."""
        now = peak = 0.0
        with open(f'/proc/{self.proc.pid}/status', encoding='utf-8') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    now = int(line.split()[1]) / 1024
                elif line.startswith('VmHWM:'):
                    peak = int(line.split()[1]) / 1024
        return now, peak

    def stop(self, timeout: float = 30.0) -> int:
        """SIGINT (the node's orderly shutdown), then wait; kill if it hangs."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._out.close()
        return int(self.proc.returncode)


class Observer:
    """Watches the node's ``/diagnostics`` and ``~/safety_grid`` on a private rclpy context.

    Attributes:
        grids: ``(stamp_ns, time.monotonic() on arrival)`` of every grid, in arrival order.
        diagnostics: ``(time.monotonic(), level, values)`` of every diagnostics message.
    """

    def __init__(self, domain: int, node_name: str = 'assessor') -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import OccupancyGrid
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        from msg_adapters import stamp_to_ns

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('landing_zone_bench_observer', context=self.context)
        self.grids: list[tuple[int, float]] = []
        self.diagnostics: list[tuple[float, int, dict[str, str]]] = []
        self._lock = threading.Lock()
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)

        def on_grid(msg: Any) -> None:
            with self._lock:
                self.grids.append((stamp_to_ns(msg.header.stamp), time.monotonic()))

        def on_diag(msg: Any) -> None:
            for status in msg.status:
                if status.name.startswith(node_name):
                    values = {kv.key: kv.value for kv in status.values}
                    with self._lock:
                        self.diagnostics.append((time.monotonic(), status.level[0]
                                                 if isinstance(status.level, bytes)
                                                 else int(status.level), values))

        self.node.create_subscription(OccupancyGrid, f'/{node_name}/safety_grid', on_grid,
                                      latched)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 50)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def last(self) -> dict[str, str]:
        """The newest diagnostics values ({} before the first)."""
        with self._lock:
            return dict(self.diagnostics[-1][2]) if self.diagnostics else {}

    def counts(self) -> dict[str, int]:
        """``clouds integrated`` and every ``dropped clouds: REASON`` of the newest message."""
        d = self.last()
        out = {'integrated': int(d.get('clouds integrated', 0))}
        for key, value in d.items():
            if key.startswith('dropped clouds: '):
                out[key[len('dropped clouds: '):]] = int(value)
        return out

    def wait_for(self, predicate: Any, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.05)
        return False

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(5.0)
