"""Authenticated, authorized transport: credentials from a private file or the environment, the
one ACL definition (protocol.zenoh_acl) against the deploy file, and a real router enforcing it.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import subprocess
import time
from pathlib import Path

import pytest
import zenoh

from hil.errors import BadInputError
from protocol import keys, zenoh_acl
from runtime import credentials as cr
from runtime.credentials import Credentials, CredentialsError
from runtime.zsession import open_session, session_config
from tests.procs import Lines, free_tcp_port, wait_until

ROOT = Path(__file__).resolve().parents[1]
DEPLOY_ACL = ROOT / "deploy" / "zenoh-router-acl.json5"
# The loop's streams and both services' taps (protocol.tap): each role may put exactly its own.
STREAMS = (keys.STATE, keys.TORQUE, keys.TELEMETRY, keys.STATUS, f"{keys.TAP}/controller",
           f"{keys.TAP}/plant")  # fmt: skip
NO_ENV = dict.fromkeys(cr.ENV_VARS, "")


# --- credentials ------------------------------------------------------------------------------
def _private(path: Path, text: str, mode: int = 0o600) -> Path:
    path.write_text(text)
    path.chmod(mode)
    return path


def test_credentials_file_and_environment(tmp_path, monkeypatch) -> None:
    monkeypatch.delenv(cr.SYSTEMD_CREDENTIALS_DIR, raising=False)
    f = _private(
        tmp_path / "c", "# bench\nHIL_ZENOH_USER=controller\nHIL_ZENOH_PASSWORD='s3cret-pw'\n"
    )
    got = cr.from_environment({cr.ENV_FILE: str(f)})
    assert (got.user, got.password) == ("controller", "s3cret-pw")
    assert "s3cret" not in repr(got)
    env = {cr.ENV_USER: "monitor", cr.ENV_PASSWORD: "pw2"}
    assert cr.from_environment(env).user == "monitor"
    assert cr.from_environment({}) is None
    assert cr.from_environment(NO_ENV) is None  # empty = unset (hil run clears them)
    with pytest.raises(CredentialsError, match="not both"):
        cr.from_environment({cr.ENV_FILE: str(f), cr.ENV_USER: "x"})
    with pytest.raises(CredentialsError, match="together"):
        cr.from_environment({cr.ENV_USER: "x"})
    for bad in (
        "HIL_ZENOH_USER=a\n",
        "user=a\npassword=b\n",
        "HIL_ZENOH_USER=a:b\nHIL_ZENOH_PASSWORD=c\n",
    ):
        p = _private(tmp_path / "bad", bad)
        with pytest.raises(CredentialsError):
            cr.read_credentials_file(p)
        p.unlink()


@pytest.mark.parametrize("mode", [0o644, 0o604, 0o640, 0o620, 0o666])
def test_a_readable_credentials_file_is_refused(tmp_path, monkeypatch, mode) -> None:
    monkeypatch.delenv(cr.SYSTEMD_CREDENTIALS_DIR, raising=False)
    f = _private(tmp_path / "c", "HIL_ZENOH_USER=a\nHIL_ZENOH_PASSWORD=b\n", mode)
    with pytest.raises(CredentialsError, match=f"mode {mode:04o}.*chmod 600"):
        cr.from_environment({cr.ENV_FILE: str(f)})
    f.chmod(0o400)
    assert cr.from_environment({cr.ENV_FILE: str(f)}).user == "a"
    # systemd's LoadCredential= grants the service's user read access by an ACL (a group bit).
    f.chmod(0o440)
    monkeypatch.setenv(cr.SYSTEMD_CREDENTIALS_DIR, str(tmp_path))
    assert cr.from_environment({cr.ENV_FILE: str(f)}).user == "a"


def test_write_private_makes_0600_and_never_overwrites(tmp_path) -> None:
    p = cr.write_private(tmp_path / "x", "secret")
    assert (p.stat().st_mode & 0o777) == 0o600
    with pytest.raises(FileExistsError):
        cr.write_private(p, "other")


def test_session_config_applies_credentials_to_clients_only(monkeypatch) -> None:
    for var in cr.ENV_VARS:
        monkeypatch.delenv(var, raising=False)
    ep = "tcp/127.0.0.1:7447"
    conf = session_config(ep, listen_endpoint=False, mode="router")
    assert json.loads(zenoh.Config.get_json(conf, "transport/auth/usrpwd"))["user"] is None
    monkeypatch.setenv(cr.ENV_USER, "controller")
    monkeypatch.setenv(cr.ENV_PASSWORD, "pw")
    conf = session_config(ep, listen_endpoint=False, mode="router")
    auth = json.loads(zenoh.Config.get_json(conf, "transport/auth/usrpwd"))
    assert (auth["user"], auth["password"]) == ("controller", "pw")
    explicit = Credentials("monitor", "pw2")
    conf = session_config(ep, listen_endpoint=False, mode="client", credentials=explicit)
    assert json.loads(zenoh.Config.get_json(conf, "transport/auth/usrpwd"))["user"] == "monitor"
    conf = session_config(ep, listen_endpoint=False, mode="client", credentials=None)
    assert json.loads(zenoh.Config.get_json(conf, "transport/auth/usrpwd"))["user"] is None
    # A peer has no router to present them to: an error, not a silent drop.
    with pytest.raises(CredentialsError, match='mode = "router"'):
        session_config(ep, listen_endpoint=False, mode="peer")


# --- the ACL: one definition, the deploy file, a real router ------------------------------------
def test_deploy_acl_file_is_the_generated_one() -> None:
    assert DEPLOY_ACL.read_text() == zenoh_acl.deploy_json5(), (
        "deploy/zenoh-router-acl.json5 drifted: python -m protocol.zenoh_acl > "
        "deploy/zenoh-router-acl.json5"
    )
    conf = zenoh.Config.from_json5(DEPLOY_ACL.read_text())
    code = zenoh_acl.router_config(zenoh_acl.DEPLOY_LISTEN, zenoh_acl.DEPLOY_DICTIONARY)
    for key in ("access_control", "transport/auth/usrpwd", "mode", "listen/endpoints"):
        assert zenoh.Config.get_json(conf, key) == zenoh.Config.get_json(code, key), key
    assert json.loads(zenoh.Config.get_json(conf, "scouting/multicast/enabled")) is False


def _allowed(role: str, stream: str) -> bool:
    return stream in zenoh_acl.role(role).publishes


ACL_ROBOT = zenoh_acl.DEPLOY_ROBOTS[0]  # the deploy file's robot; hil.bench.router's default


def _users(tmp_path: Path) -> dict[str, Credentials]:
    """A password for every login of the router (keyed by role: one robot)."""
    creds = {
        role: Credentials(user, f"pw-{user}-{os.urandom(6).hex()}")
        for user, (role, _) in zenoh_acl.logins([ACL_ROBOT]).items()
    }
    cr.write_private(tmp_path / "users", cr.dictionary_text(creds.values()))
    return creds


def _start_router(spawn, tmp_path: Path, ep: str) -> None:
    env = {**os.environ, **NO_ENV, cr.ENV_DICTIONARY: str(tmp_path / "users")}
    proc = spawn.python(
        ["-m", "hil.bench.router", ep, "--secure"], env=env, stderr=subprocess.STDOUT, text=True
    )
    out = Lines(proc.stdout)
    assert wait_until(lambda: out.seen("router up") or proc.poll() is not None, 60), out.text()
    assert proc.poll() is None and out.seen("access control"), out.text()


def _deploy_router(tmp_path: Path, ep: str):
    conf = zenoh.Config.from_json5(DEPLOY_ACL.read_text())
    conf.insert_json5("listen/endpoints", json.dumps([ep]))
    conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(tmp_path / "users")))
    return zenoh.open(conf)


@pytest.mark.parametrize("router", ["hil.bench.router", "deploy file"])
def test_router_grants_each_role_exactly_its_rights(spawn, tmp_path, router) -> None:
    creds = _users(tmp_path)
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    sessions = []
    try:
        if router == "hil.bench.router":
            _start_router(spawn, tmp_path, ep)
        else:
            sessions.append(_deploy_router(tmp_path, ep))
        # No credentials, a wrong password, an unknown user: no session at all.
        wrong = Credentials(creds["controller"].user, "wrong")
        for bad in (None, wrong, Credentials("eve", "guess"), Credentials("controller", "x")):
            with pytest.raises(zenoh.ZError):
                sessions.append(open_session(ep, mode="client", credentials=bad))
        witness_q: queue.Queue[tuple[str, bytes]] = queue.Queue()
        witness = open_session(ep, mode="client", credentials=creds["recorder"])
        sessions.append(witness)
        witness.declare_subscriber(
            keys.ALL_ROBOTS, lambda s: witness_q.put((str(s.key_expr), s.payload.to_bytes()))
        )
        # "run" may publish its start message but may not read anything.
        run_q: queue.Queue[bytes] = queue.Queue()
        runner = open_session(ep, mode="client", credentials=creds["run"])
        sessions.append(runner)
        runner.declare_subscriber(keys.ALL_ROBOTS, lambda s: run_q.put(s.payload.to_bytes()))
        pubs = {r: open_session(ep, mode="client", credentials=creds[r]) for r in creds}
        sessions += pubs.values()
        expected = {
            (r, st) for r in zenoh_acl.ROLE_NAMES for st in STREAMS if _allowed(r, st)
        }  # fmt: skip
        seen: set[tuple[str, str]] = set()
        deadline = time.monotonic() + 30
        while not expected <= seen and time.monotonic() < deadline:
            for r, s in pubs.items():
                for st in STREAMS:
                    s.put(f"hil/{ACL_ROBOT}/{st}", f"{r}|{st}".encode())
            with contextlib.suppress(queue.Empty):
                while True:
                    key, payload = witness_q.get(timeout=0.1)
                    r, st = payload.decode().split("|")
                    assert key == f"hil/{ACL_ROBOT}/{st}"
                    seen.add((r, st))
        assert seen == expected, f"granted {sorted(seen)}, defined {sorted(expected)}"
        # Everything allowed went through (several rounds), nothing else did; and the "run"
        # session, which may not read, was delivered nothing.
        assert not {r for r, _ in seen} & {"recorder", "monitor"}
        assert run_q.empty(), list(run_q.queue)
    finally:
        for s in reversed(sessions):
            with contextlib.suppress(Exception):
                s.close()


def test_router_refuses_a_readable_dictionary_and_a_missing_one(spawn, tmp_path) -> None:
    users = _private(tmp_path / "users", "controller:pw\n", 0o644)
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    for env, needle in (
        ({cr.ENV_DICTIONARY: str(users)}, "chmod 600"),
        ({}, "--secure needs HIL_ZENOH_DICTIONARY"),
    ):
        proc = spawn.python(
            ["-m", "hil.bench.router", ep, "--secure"],
            env={**os.environ, **NO_ENV, **env},
            text=True,
        )
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 2 and needle in err, err


@pytest.mark.parametrize("case", ["world-readable file", "peer with credentials"])
def test_a_service_with_bad_credentials_exits_2_before_writing_its_log(spawn, tmp_path, case):
    f = _private(tmp_path / "c", "HIL_ZENOH_USER=controller\nHIL_ZENOH_PASSWORD=Zq9-secr3t\n")
    if case == "world-readable file":
        f.chmod(0o644)
        needle = "chmod 600"
    else:
        needle = 'mode = "router"'  # the bundled scenario is peer-to-peer
    out = tmp_path / "svc"
    env = {**os.environ, **NO_ENV, cr.ENV_FILE: str(f)}
    env.pop(cr.SYSTEMD_CREDENTIALS_DIR, None)
    proc = spawn.python(
        ["-m", "hil", "controller", "paper_tracking", "--duration", "1", "--out", str(out)],
        env=env,
        text=True,
    )
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2 and needle in err, err[-2000:]
    assert "Zq9-secr3t" not in err
    assert not (out / "controller.hoplog").exists()


def test_init_writes_private_deployment_credentials(tmp_path, monkeypatch, capsys) -> None:
    from hil.bench.secure import main

    monkeypatch.delenv(cr.SYSTEMD_CREDENTIALS_DIR, raising=False)
    assert main(["init", str(tmp_path / "etc")]) == 0
    users = cr.dictionary_from_environment(
        {cr.ENV_DICTIONARY: str(tmp_path / "etc/zenoh-users.txt")}
    )
    lines = users.read_text().splitlines()
    assert [line.split(":")[0] for line in lines] == list(zenoh_acl.logins(["robot1"]))
    for user in zenoh_acl.logins(["robot1"]):
        c = cr.read_credentials_file(tmp_path / "etc" / "credentials" / f"{user}.env")
        assert f"{c.user}:{c.password}" in lines
    assert main(["init", str(tmp_path / "etc")]) == 2  # never overwrites
    assert "not overwritten" in capsys.readouterr().err


def test_a_scenario_cannot_carry_credentials() -> None:
    from hil.bench.defaults import PAPER_TRACKING_TOML
    from hil.scenario import loads_scenario

    for key in ("user", "password"):
        text = PAPER_TRACKING_TOML + f'\n[zenoh]\nmode = "router"\n{key} = "x"\n'
        with pytest.raises(BadInputError, match=key):
            loads_scenario(text, ROOT)


def test_deploy_units_take_credentials_from_systemd_never_inline() -> None:
    units = ROOT / "deploy" / "systemd"
    for name, var in (
        ("hil-controller.service", cr.ENV_FILE),
        ("hil-emulator.service", cr.ENV_FILE),
        ("hil-zenoh-router.service", cr.ENV_DICTIONARY),
    ):
        text = (units / name).read_text()
        lines = [line for line in text.splitlines() if not line.startswith("#")]
        assert any(line.startswith("LoadCredential=") for line in lines), name
        assert f"Environment={var}=%d/" in text, name
        assert not any(cr.ENV_PASSWORD in line or "password" in line.lower() for line in lines)
