"""Per-robot access control under --secure: each robot's controller login may publish only its
own robot's command keys and read only its own robot's state, on a real router, while the
robots' loops run at the same time."""

from __future__ import annotations

import contextlib
import os
import subprocess
import threading
from collections import Counter

from protocol import keys, zenoh_acl
from runtime import credentials as cr
from runtime.credentials import Credentials
from runtime.zsession import open_session
from tests.procs import Lines, free_tcp_port, wait_until

NO_ENV = dict.fromkeys(cr.ENV_VARS, "")
ROBOTS = ("robot1", "robot2")
N = 200


def test_each_robot_login_is_granted_its_own_robot_keys_only():
    acl = zenoh_acl.access_control(ROBOTS)
    rules = {r["id"]: r for r in acl["rules"]}
    for robot, other in (ROBOTS, ROBOTS[::-1]):
        for role in ("controller", "emulator"):
            user = zenoh_acl.login(role, robot)
            policy = next(p for p in acl["policies"] if p["subjects"] == [user])
            granted = [k for rid in policy["rules"] for k in rules[rid]["key_exprs"]]
            assert granted and all(f"/{robot}/" in k for k in granted), (user, granted)
            assert not any(f"/{other}/" in k or "/*/" in k for k in granted), (user, granted)
    # The fleet's observers still read every robot.
    assert {"recorder", "monitor"} <= set(zenoh_acl.logins(ROBOTS))


def _router(spawn, tmp_path, ep: str) -> dict[str, Credentials]:
    creds = {u: Credentials(u, os.urandom(9).hex()) for u in zenoh_acl.logins(ROBOTS)}
    cr.write_private(tmp_path / "users", cr.dictionary_text(creds.values()))
    env = {**os.environ, **NO_ENV, cr.ENV_DICTIONARY: str(tmp_path / "users")}
    argv = ["-m", "hil.bench.router", ep, "--secure", f"--robots={','.join(ROBOTS)}"]
    proc = spawn.python(argv, env=env, stderr=subprocess.STDOUT, text=True)
    out = Lines(proc.stdout)
    assert wait_until(lambda: out.seen("router up") or proc.poll() is not None, 60), out.text()
    assert proc.poll() is None, out.text()
    return creds


def test_robot2s_controller_is_refused_on_robot1s_keys_while_both_run(spawn, tmp_path):
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    creds = _router(spawn, tmp_path, ep)
    got: Counter[tuple[str, str]] = Counter()  # (who received, whose payload)
    lock = threading.Lock()

    def counter(who: str):
        def on_sample(sample) -> None:
            with lock:
                got[(who, bytes(sample.payload.to_bytes()).decode().split("|")[0])] += 1

        return on_sample

    sessions = {}
    try:
        for user in ("controller.robot1", "controller.robot2", "emulator.robot1"):
            sessions[user] = open_session(ep, mode="client", credentials=creds[user])
        sessions["emulator.robot2"] = open_session(
            ep, mode="client", credentials=creds["emulator.robot2"]
        )
        s = sessions
        s["emulator.robot1"].declare_subscriber(keys.torque_key("robot1"), counter("plant1"))
        s["emulator.robot2"].declare_subscriber(keys.torque_key("robot2"), counter("plant2"))
        s["controller.robot1"].declare_subscriber(keys.state_key("robot1"), counter("ctrl1"))
        # robot 2's controller asks for robot 1's state: it must be delivered none of it.
        with contextlib.suppress(Exception):  # a refused declaration may also raise
            s["controller.robot2"].declare_subscriber(keys.state_key("robot1"), counter("ctrl2"))
        # A subscription reaches the router asynchronously: put on each allowed route until one
        # sample arrives, so that what follows counts the rules, not the start-up.
        for who, sess, key in (
            ("plant1", "controller.robot1", keys.torque_key("robot1")),
            ("plant2", "controller.robot2", keys.torque_key("robot2")),
            ("ctrl1", "emulator.robot1", keys.state_key("robot1")),
        ):
            up = lambda who=who, sess=sess, key=key: (  # noqa: E731
                s[sess].put(key, "route-up|0") or got[(who, "route-up")] > 0
            )
            assert wait_until(up, 20), (who, dict(got))
        # Both robots' loops at once; robot 2's controller also puts on robot 1's command key.
        for i in range(N):
            s["controller.robot2"].put(keys.torque_key("robot1"), f"ctrl2-forged|{i}")
            s["controller.robot2"].put(keys.torque_key("robot2"), f"ctrl2|{i}")
            s["emulator.robot1"].put(keys.state_key("robot1"), f"plant1|{i}")
            s["emulator.robot2"].put(keys.state_key("robot2"), f"plant2|{i}")
            s["controller.robot1"].put(keys.torque_key("robot1"), f"ctrl1|{i}")
        # The allowed traffic, sent after each forged put, all arrives...
        assert wait_until(
            lambda: (
                got[("plant1", "ctrl1")] == N
                and got[("plant2", "ctrl2")] == N
                and got[("ctrl1", "plant1")] == N
            ),
            30,
        ), dict(got)
        # ...and none of the forbidden did: 0 of N puts reached robot 1's plant.
        assert got[("plant1", "ctrl2-forged")] == 0, dict(got)
        assert got[("ctrl2", "plant1")] == 0, dict(got)
    finally:
        for sess in sessions.values():
            with contextlib.suppress(Exception):
                sess.close()
