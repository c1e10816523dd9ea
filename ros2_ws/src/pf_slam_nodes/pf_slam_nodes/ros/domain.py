"""The ROS domain a run is on, and how it is kept to itself (no rclpy import at module level).

By default (no ``--domain``, ROS_DOMAIN_ID unset) a run is *isolated*: it takes a domain in
1..100 that no other pf-slam run or test holds (an exclusive lock on
``$TMPDIR/pf_slam_domains/<id>.lock`` for as long as the run and its node processes live) and
on which no DDS participant of this host has a port open (the RTPS port block of the domain in
/proc/net/udp), and limits discovery: ``OFF`` for the single-process graph (one Context = one
DDS participant; Fast DDS then admits no other participant at all), ``LOCALHOST`` for one
process per node (they must discover each other; nothing else is on the domain). Static peers,
ROS_LOCALHOST_ONLY and ROS_DISCOVERY_SERVER are dropped for such a run: they would join it to
another graph. The run thus neither publishes into nor listens to an unrelated ROS graph, and
two runs at once cannot meet.

An explicit domain (``--domain N`` or a set ROS_DOMAIN_ID) keeps the open behaviour: that domain
with the discovery the environment asks for, so rviz2 or Foxglove can watch the run live.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

#: domains a run or a test may take for itself: their RTPS ports (7400 + 250 d ...) stay below
#: Linux's ephemeral range (32768..), as the ROS docs advise (0..101)
POOL = range(1, 101)
MAX_DOMAIN = 232  # Fast DDS: the highest domain whose ports fit in 16 bits
#: the environment that would connect an isolated run to other graphs
FOREIGN_LINKS = ("ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY", "ROS_DISCOVERY_SERVER")
_PORT_BASE, _DOMAIN_GAIN = 7400, 250  # RTPS spec 9.6.1.1 (Fast DDS and Cyclone defaults)


class DomainError(ValueError):
    """No usable domain: a bad --domain / ROS_DOMAIN_ID, or none free in the pool."""


def lock_dir() -> Path:
    """Where runs and tests hold their domains (one lock file per domain)."""
    return Path(os.environ.get("TMPDIR") or "/tmp") / "pf_slam_domains"


def domain_ports(domain: int) -> range:
    """The UDP ports RTPS uses on `domain` (discovery and user traffic of every participant)."""
    start = _PORT_BASE + _DOMAIN_GAIN * domain
    return range(start, start + _DOMAIN_GAIN)


def bound_udp_ports() -> set[int]:
    """Local UDP ports open on this host (network namespace), IPv4 and IPv6."""
    ports: set[int] = set()
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            m = re.match(r"\s*\d+:\s+[0-9A-Fa-f]+:([0-9A-Fa-f]{4})\s", line)
            if m:
                ports.add(int(m.group(1), 16))
    return ports


def domain_in_use(domain: int, ports: set[int] | None = None) -> bool:
    """A DDS participant on this host has a port of `domain` open (ROS 2 nodes are up on it)."""
    used = bound_udp_ports() if ports is None else ports
    block = domain_ports(domain)
    return any(p in block for p in used)


def _open_lock(domain: int) -> int:
    d = lock_dir()
    if not d.is_dir():
        d.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(OSError):
            d.chmod(0o1777)  # other users' runs lock here too
    path = d / f"{domain}.lock"
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except PermissionError:
        fd = os.open(path, os.O_RDONLY)  # another user's file: flock works on it all the same
    with contextlib.suppress(OSError):
        os.fchmod(fd, 0o666)
    return fd


@contextlib.contextmanager
def claim_domain(pool: range | list[int] = POOL, probe: bool = True) -> Iterator[tuple[int, int]]:
    """A domain of `pool` no other run or test holds and (`probe`) no participant of this host
    uses; held (exclusive flock) until the block exits. Yields (domain, the lock's fd: pass it
    to child processes, pass_fds, to hold the domain as long as they live). The search starts at
    an offset from the pid, so parallel claims rarely contend."""
    pool = list(pool)
    if not pool:
        raise DomainError("no domain ids to choose from")
    start = os.getpid() % len(pool)
    ports = bound_udp_ports() if probe else set()
    for k in range(len(pool)):
        domain = pool[(start + k) % len(pool)]
        if probe and domain_in_use(domain, ports):
            continue
        fd = _open_lock(domain)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        if probe and domain_in_use(domain):  # came up between the first look and the lock
            os.close(fd)
            continue
        with contextlib.suppress(OSError):  # who holds it, for an explicit run that lands on it
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        try:
            yield domain, fd
        finally:
            os.close(fd)  # no LOCK_UN: a child holding a copy of fd keeps the domain until it exits
        return
    raise DomainError(
        f"no free ROS domain in {pool[0]}..{pool[-1]} (all held by other pf-slam runs or "
        f"used by ROS 2 nodes on this host); choose one with --domain N"
    )


def holder(domain: int) -> int | None:
    """The pid of the run or test holding `domain` (-1: held, pid unknown), or None when free."""
    path = lock_dir() / f"{domain}.lock"
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        text = os.pread(fd, 32, 0).decode(errors="replace").strip()
        return int(text) if text.isdigit() else -1
    finally:
        os.close(fd)  # releases the shared lock, if it was taken
    return None


def _ancestors() -> set[int]:
    """This process and its parents (a test holding a domain starts the runs on it)."""
    pids, pid = set(), os.getpid()
    while pid > 1 and pid not in pids:
        pids.add(pid)
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            pid = int(stat.rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            break
    return pids


@dataclass(frozen=True)
class RosDomain:
    """The domain of a run: its id, whether it is isolated, the discovery range, and who chose it
    ('pf-slam' (free, held by the run), '--domain' or 'ROS_DOMAIN_ID')."""

    id: int
    isolated: bool
    discovery: str
    chosen_by: str
    lock_fd: int | None = None
    #: an explicit domain that an isolated pf-slam run or a test holds: the two will mix
    warning: str | None = None

    def summary(self) -> dict:
        """summary.json "ros_domain"."""
        out = {"id": self.id, "isolated": self.isolated, "discovery": self.discovery, "chosen_by": self.chosen_by}
        return out if self.warning is None else dict(out, warning=self.warning)

    def describe(self) -> str:
        if self.isolated:
            return (
                f"[pf-slam] ROS domain {self.id} (isolated: free, held by this run; discovery "
                f"{self.discovery}; to watch the run live in rviz2 or Foxglove, give --domain N or set ROS_DOMAIN_ID)"
            )
        line = (
            f"[pf-slam] ROS domain {self.id} (open, from {self.chosen_by}; discovery {self.discovery}: "
            f"viewers can watch, and any other ROS 2 node on this domain reaches the run)"
        )
        return line if self.warning is None else f"{line}\n[pf-slam] warning: {self.warning}"

    def environ_overrides(self) -> dict[str, str | None]:
        """What this process's environment must say while the run's Context is created (None:
        unset); nothing for an explicit domain (the user's settings apply)."""
        if not self.isolated:
            return {}
        return {"ROS_AUTOMATIC_DISCOVERY_RANGE": self.discovery, **{k: None for k in FOREIGN_LINKS}}

    def child_env(self, base: dict[str, str] | None = None) -> dict[str, str]:
        """The environment of a node process of this run."""
        env = dict(os.environ if base is None else base, ROS_DOMAIN_ID=str(self.id))
        if self.isolated:
            for k in FOREIGN_LINKS:
                env.pop(k, None)
            env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        else:
            env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        return env


def explicit_domain(domain_id: int | None = None) -> tuple[int, str] | None:
    """(domain, who chose it) when `domain_id` or ROS_DOMAIN_ID names one; None when neither."""
    if domain_id is not None:
        value, who = domain_id, "--domain"
    else:
        raw = os.environ.get("ROS_DOMAIN_ID", "").strip()
        if not raw:
            return None
        who = "ROS_DOMAIN_ID"
        try:
            value = int(raw)
        except ValueError:
            raise DomainError(
                f"ROS_DOMAIN_ID={raw!r} is not a number (0..{MAX_DOMAIN}); unset it for an isolated run"
            ) from None
    if not 0 <= int(value) <= MAX_DOMAIN:
        raise DomainError(
            f"{who} {value} is out of range: a ROS domain is 0..{MAX_DOMAIN} (0..101 on Linux "
            "keeps clear of the ephemeral ports)"
        )
    return int(value), who


@contextlib.contextmanager
def run_domain(domain_id: int | None = None, single_participant: bool = True) -> Iterator[RosDomain]:
    """The domain for a run (see the module doc), held until the block exits. `single_participant`:
    every node of the run is in this process's one Context (discovery OFF); else node processes
    must discover each other (LOCALHOST). Create the run's Context with init_context()."""
    chosen = explicit_domain(domain_id)
    if chosen is not None:
        disc = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") or "SUBNET (ROS default)"
        pid = holder(chosen[0])
        warning = None
        if pid is not None and pid not in _ancestors():
            warning = (
                f"ROS domain {chosen[0]} is held by another pf-slam run or test "
                f"({'pid ' + str(pid) if pid > 0 else 'pid unknown'}): both will receive each "
                "other's topics; choose another --domain"
            )
        yield RosDomain(chosen[0], False, disc, chosen[1], warning=warning)
        return
    discovery = "OFF" if single_participant else "LOCALHOST"
    with claim_domain() as (domain, fd):
        yield RosDomain(domain, True, discovery, "pf-slam", fd)


#: one Context at a time has the environment set for it (rcl reads the discovery settings from
#: the environment at init, Fast DDS ROS_DISCOVERY_SERVER when the participant is created)
_ENV_LOCK = threading.Lock()


def init_context(dom: RosDomain, first_node: str):
    """A new rclpy Context on `dom` and its first node (which creates the DDS participant). An
    isolated domain's discovery settings are in os.environ only while the two are made, under a
    lock, then restored: other code and concurrent runs in this process keep their environment.
    Returns (context, node)."""
    import rclpy

    ctx = rclpy.Context()
    with _ENV_LOCK, _environ(**dom.environ_overrides()):
        rclpy.init(context=ctx, domain_id=dom.id)
        try:
            node = rclpy.create_node(first_node, context=ctx)
        except BaseException:
            rclpy.shutdown(context=ctx)
            raise
    return ctx, node


@contextlib.contextmanager
def _environ(**values: str | None) -> Iterator[None]:
    """Set (None: unset) environment variables for the block."""
    old = {k: os.environ.get(k) for k in values}
    try:
        _set_environ(values)
        yield
    finally:
        _set_environ(old)


def _set_environ(values: dict[str, str | None]) -> None:
    for k, v in values.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


@contextlib.contextmanager
def ros_context(domain_id: int | None = None, name: str = "pf_slam_tool"):
    """An rclpy Context for a tool whose nodes all live in this process (parameter reference,
    benchmarks): on run_domain(domain_id) — isolated unless a domain is given. A node `name`
    lives as long as the block, so the participant made with the isolated settings does too.
    Yields (context, RosDomain); shut down afterwards."""
    import rclpy

    with run_domain(domain_id, single_participant=True) as dom:
        ctx, keeper = init_context(dom, name)
        try:
            yield ctx, dom
        finally:
            keeper.destroy_node()
            if ctx.ok():
                rclpy.shutdown(context=ctx)
