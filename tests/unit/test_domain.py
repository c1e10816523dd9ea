"""How a run picks its ROS domain (pf_slam_nodes.ros.domain; no ROS needed): a held domain and a
domain with a live DDS port are skipped, the lock lasts as long as its holders, an explicit
domain is taken as given and a bad one is refused by name, and an isolated run's discovery
settings hold inside the block only."""

from __future__ import annotations

import fcntl
import os
import socket
import subprocess
import sys

import pytest

from pf_slam_nodes.ros import domain

#: domains no test or run uses (outside the pool 1..100), so these tests disturb nobody
FREE = [201, 202, 203]


def _bind(port: int) -> socket.socket | None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("0.0.0.0", port))
    except OSError:
        s.close()
        return None
    return s


def test_ports_are_the_rtps_block_of_the_domain():
    assert domain.domain_ports(0)[0] == 7400 and domain.domain_ports(0)[-1] == 7649
    assert 7410 in domain.domain_ports(0) and 7410 + 250 in domain.domain_ports(1)
    assert domain.domain_ports(100)[-1] < 32768  # the pool stays below Linux's ephemeral ports


def test_a_held_domain_and_a_domain_in_use_are_skipped():
    a, b, c = FREE
    sock = _bind(domain.domain_ports(b)[10])  # as a participant's discovery port on b
    if sock is None:
        pytest.skip("the port is taken on this host")
    try:
        assert domain.domain_in_use(b) and not domain.domain_in_use(c)
        with domain.claim_domain([a]) as (held, _fd):
            assert held == a
            with domain.claim_domain(FREE) as (got, _fd2):
                assert got == c
            with pytest.raises(domain.DomainError, match=r"no free ROS domain in 201..202.*--domain N"):
                with domain.claim_domain([a, b]):
                    pass
    finally:
        sock.close()
    with domain.claim_domain([b]) as (got, _fd):  # free again once the socket is closed
        assert got == b


def test_the_lock_lasts_as_long_as_a_child_that_inherited_it():
    """A node process inherits the run's lock (pass_fds): the domain stays held until it is gone."""
    a = FREE[0]
    with domain.claim_domain([a]) as (_, fd):
        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"], pass_fds=(fd,))
    try:
        with pytest.raises(domain.DomainError):
            with domain.claim_domain([a]):
                pass
    finally:
        child.kill()
        child.wait()
    with domain.claim_domain([a]) as (got, _fd):
        assert got == a


def test_explicit_domains_and_bad_values(monkeypatch):
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert domain.explicit_domain() is None
    assert domain.explicit_domain(7) == (7, "--domain")
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert domain.explicit_domain() == (42, "ROS_DOMAIN_ID")
    assert domain.explicit_domain(3) == (3, "--domain")  # the flag wins
    monkeypatch.setenv("ROS_DOMAIN_ID", " ")
    assert domain.explicit_domain() is None  # set but empty: as unset (rcl reads it as 0)
    monkeypatch.setenv("ROS_DOMAIN_ID", "five")
    with pytest.raises(domain.DomainError, match=r"ROS_DOMAIN_ID='five' is not a number"):
        domain.explicit_domain()
    monkeypatch.delenv("ROS_DOMAIN_ID")
    with pytest.raises(domain.DomainError, match=r"--domain 233 is out of range: a ROS domain is 0..232"):
        domain.explicit_domain(233)


def test_isolated_settings_and_the_environment(monkeypatch):
    """The process environment is left alone (init_context applies the settings, tests/ros); the
    node processes of an isolated run get LOCALHOST and no link to other graphs."""
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    monkeypatch.setenv("ROS_STATIC_PEERS", "192.168.0.7")
    monkeypatch.setenv("ROS_DISCOVERY_SERVER", "10.0.0.1:11811")
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "SUBNET")
    with domain.run_domain(single_participant=True) as dom:
        assert dom.isolated and dom.id in domain.POOL and dom.discovery == "OFF" and dom.lock_fd is not None
        assert dom.environ_overrides() == {
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF",
            "ROS_STATIC_PEERS": None,
            "ROS_LOCALHOST_ONLY": None,
            "ROS_DISCOVERY_SERVER": None,
        }
        with pytest.raises(BlockingIOError):  # held
            fd = os.open(domain.lock_dir() / f"{dom.id}.lock", os.O_RDONLY)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            finally:
                os.close(fd)
        assert domain.holder(dom.id) == os.getpid()
        assert dom.summary() == {"id": dom.id, "isolated": True, "discovery": "OFF", "chosen_by": "pf-slam"}
        assert "isolated" in dom.describe() and "--domain N" in dom.describe()
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"
    assert os.environ["ROS_STATIC_PEERS"] == "192.168.0.7"
    with domain.run_domain(single_participant=False) as dom:
        env = dom.child_env()
        assert env["ROS_DOMAIN_ID"] == str(dom.id) and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
        assert "ROS_STATIC_PEERS" not in env


def test_an_explicit_domain_keeps_the_environment(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "17")
    monkeypatch.setenv("ROS_STATIC_PEERS", "192.168.0.7")
    monkeypatch.delenv("ROS_AUTOMATIC_DISCOVERY_RANGE", raising=False)
    with domain.run_domain() as dom:
        assert (dom.id, dom.isolated, dom.chosen_by, dom.lock_fd) == (17, False, "ROS_DOMAIN_ID", None)
        assert dom.discovery == "SUBNET (ROS default)" and "open" in dom.describe()
        assert dom.environ_overrides() == {}
        assert os.environ["ROS_STATIC_PEERS"] == "192.168.0.7"
        env = dom.child_env()
        assert env["ROS_STATIC_PEERS"] == "192.168.0.7" and env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


def test_an_explicit_domain_held_by_another_run_is_warned_about(monkeypatch):
    """--domain N on a domain an isolated run (here: another process) holds: the run says so and
    summary.json records it; the holder's own children (a test's runs) are not warned."""
    a = FREE[1]
    code = (
        "import sys, time; from pf_slam_nodes.ros import domain\n"
        f"with domain.claim_domain([{a}]) as (d, _):\n    print(d, flush=True); time.sleep(30)\n"
    )
    other = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout.readline().strip() == str(a)
        assert domain.holder(a) == other.pid
        monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
        with domain.run_domain(a) as dom:
            assert dom.warning and f"pid {other.pid}" in dom.warning and "choose another --domain" in dom.warning
            assert dom.summary()["warning"] == dom.warning and "warning:" in dom.describe()
    finally:
        other.kill()
        other.wait()
    assert domain.holder(a) is None
    with domain.claim_domain([a]):  # held by this process: runs it starts are not warned
        with domain.run_domain(a) as dom:
            assert dom.warning is None and "warning" not in dom.summary()
