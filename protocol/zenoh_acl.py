"""Who may do what on the bench's Zenoh router: the one definition of its access control.

Every session of a secure bench is a client of one router that authenticates it by user name
and password (Zenoh's ``usrpwd``: a challenge-response, the password never crosses the link)
and then applies the rules below, default deny. A login is a role, and for the roles that act
for one robot, the role and the robot (``controller.robot1``: :func:`login`):

- ``controller.<robot>`` publishes ``hil/<robot>/cmd/torque``, ``hil/<robot>/telemetry``,
  ``hil/<robot>/status``, its tap ``hil/<robot>/tap/controller`` (:mod:`protocol.tap`) and
  its clock pings (``hilclock/<robot>/ping``), and reads only ``hil/<robot>/**`` and the pongs
  of its robot's plant;
- ``emulator.<robot>`` publishes ``hil/<robot>/state``, ``hil/<robot>/status``, its tap
  ``hil/<robot>/tap/plant`` and the clock pongs, and reads only its robot's keys;
- ``recorder`` (``hil run``'s recorder) and ``monitor`` (an operator's tool) publish nothing
  and read ``hil/**``, every robot;
- ``run`` (``hil run``'s start announcement) publishes ``hil/*/status`` only and reads nothing.

So one robot's controller can neither command another robot nor read its state.
``hil run --secure`` builds its router from :func:`router_inserts` for the run's robots, and
``deploy/zenoh-router-acl.json5`` is :func:`deploy_json5` written out for ``robot1``
(``python -m protocol.zenoh_acl > deploy/zenoh-router-acl.json5``); a test checks that the
file is exactly that text, so the deployed router and the tested one cannot drift apart.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

from protocol import keys
from protocol.zenoh_config import ZenohSettings, config_dict

ALL = keys.ALL_ROBOTS  # hil/**
DEPLOY_DICTIONARY = "/etc/hil/zenoh-users.txt"
DEPLOY_LISTEN = ("tcp/127.0.0.1:7447",)
DEPLOY_ROBOTS = ("robot1",)
CLOCK_PREFIX = "hilclock"  # runtime.clocksync's exchanges (it cannot be imported here)


def stream_key(suffix: str) -> str:
    """``hil/*/<suffix>``: one stream of every robot (``*`` is exactly one key chunk)."""
    return f"{keys.PREFIX}/*/{suffix}"


@dataclass(frozen=True)
class Role:
    name: str
    publishes: tuple[str, ...]  # stream suffixes of protocol.keys
    reads: bool  # may subscribe and be delivered (its robot's keys, or hil/** for all robots)
    what: str
    per_robot: bool = False  # one login per robot, its rights on that robot's keys only
    clock: str = ""  # the clock exchange it publishes (runtime.clocksync): ping or pong

    @property
    def put_keys(self) -> list[str]:
        return [stream_key(s) for s in self.publishes]

    def robot_put_keys(self, robot: str) -> list[str]:
        own = [f"{keys.PREFIX}/{keys.validate_robot_id(robot)}/{s}" for s in self.publishes]
        return own + ([f"{CLOCK_PREFIX}/{robot}/{self.clock}"] if self.clock else [])


ROLES: tuple[Role, ...] = (
    Role(
        "controller",
        (keys.TORQUE, keys.TELEMETRY, keys.STATUS, f"{keys.TAP}/controller"),
        True,
        "one robot's controller service",
        per_robot=True,
        clock="ping",
    ),
    Role(
        "emulator",
        (keys.STATE, keys.STATUS, f"{keys.TAP}/plant"),
        True,
        "one robot's plant",
        True,
        "pong",
    ),
    Role("recorder", (), True, "hil run's recorder"),
    Role("monitor", (), True, "an operator's read-only tool"),
    Role("run", (keys.STATUS,), False, "hil run's start message"),
)
ROLE_NAMES = tuple(r.name for r in ROLES)


def role(name: str) -> Role:
    for r in ROLES:
        if r.name == name:
            return r
    raise KeyError(f"no role {name!r} (roles: {', '.join(ROLE_NAMES)})")


def login(role_name: str, robot: str) -> str:
    """The user name of ``role_name`` for ``robot``: ``controller.robot1`` for a role that
    acts for one robot, the role's name for the others."""
    return (
        f"{role_name}.{keys.validate_robot_id(robot)}" if role(role_name).per_robot else role_name
    )


def logins(robots: Sequence[str]) -> dict[str, tuple[str, str | None]]:
    """Every user name of a router for ``robots`` -> (its role, its robot or None)."""
    out: dict[str, tuple[str, str | None]] = {}
    for r in ROLES:
        if r.per_robot:
            out.update({login(r.name, b): (r.name, b) for b in robots})
        else:
            out[r.name] = (r.name, None)
    return out


def _grants(rid: str, put_keys: list[str]) -> list[dict[str, Any]]:
    """What it may publish (ingress at the router), and the subscriptions on those keys it is
    told about (egress), so its own session does not filter its puts away."""
    return [
        {
            "id": f"{rid}-put",
            "messages": ["put"],
            "flows": ["ingress"],
            "permission": "allow",
            "key_exprs": put_keys,
        },
        {
            "id": f"{rid}-sees-subscribers",
            "messages": ["declare_subscriber"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": put_keys,
        },
    ]


def _reads(rid: str, key_exprs: list[str]) -> list[dict[str, Any]]:
    """Subscribe to ``key_exprs`` and be delivered what is published there."""
    return [
        {
            "id": f"{rid}-subscribe",
            "messages": ["declare_subscriber"],
            "flows": ["ingress", "egress"],
            "permission": "allow",
            "key_exprs": key_exprs,
        },
        {
            "id": f"{rid}-deliver",
            "messages": ["put"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": key_exprs,
        },
    ]


def _subject(user: str, rules: list[dict[str, Any]], out: dict[str, list[dict[str, Any]]]) -> None:
    out["rules"] += rules
    out["subjects"].append({"id": user, "usernames": [user]})
    out["policies"].append({"rules": [r["id"] for r in rules], "subjects": [user]})


def access_control(robots: Sequence[str] = DEPLOY_ROBOTS) -> dict[str, Any]:
    """The router's ``access_control`` block (Zenoh 1.x ACL: rules, subjects, policies) for
    ``robots``: a subject per login, each with exactly its own rights."""
    acl: dict[str, list[dict[str, Any]]] = {"rules": [], "subjects": [], "policies": []}
    for r in ROLES:
        if not r.per_robot:
            rules = _grants(r.name, r.put_keys) if r.publishes else []
            rules += _reads(r.name, [ALL]) if r.reads else []
            if rules:
                _subject(r.name, rules, acl)
            continue
        for robot in robots:
            user = login(r.name, robot)
            own = [keys.robot_prefix(robot), f"{CLOCK_PREFIX}/{robot}/**"]
            _subject(user, _grants(user, r.robot_put_keys(robot)) + _reads(user, own), acl)
    return {"enabled": True, "default_permission": "deny", **acl}


def router_inserts(
    listen: Sequence[str],
    dictionary_file: str,
    *,
    allow_non_loopback: bool = False,
    robots: Sequence[str] = DEPLOY_ROBOTS,
) -> dict[str, Any]:
    """The router's configuration as ``key path -> value`` (what ``insert_json5`` takes): the
    bench's router settings (:mod:`protocol.zenoh_config`: multicast scouting off), usrpwd
    authentication against ``dictionary_file`` (``user:password`` lines) and the ACL for
    ``robots``."""
    settings = ZenohSettings(
        mode="router", listen=tuple(listen), allow_non_loopback=allow_non_loopback
    )
    out = config_dict(settings)
    out["transport/auth/usrpwd/dictionary_file"] = dictionary_file
    out["access_control"] = access_control(robots)
    return out


def router_config(
    listen: Sequence[str],
    dictionary_file: str,
    *,
    allow_non_loopback: bool = False,
    robots: Sequence[str] = DEPLOY_ROBOTS,
) -> zenoh.Config:
    conf = zenoh.Config()
    inserts = router_inserts(
        listen, dictionary_file, allow_non_loopback=allow_non_loopback, robots=robots
    )
    for key, value in inserts.items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def _nest(inserts: dict[str, Any]) -> dict[str, Any]:
    root: dict[str, Any] = {}
    for path, value in inserts.items():
        node = root
        *parents, leaf = path.split("/")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return root


_HEADER = """\
// Zenoh router with user/password authentication and access control (eclipse-zenoh 1.x).
// GENERATED from protocol/zenoh_acl.py: do not edit; regenerate with
//   python -m protocol.zenoh_acl > deploy/zenoh-router-acl.json5
// (tests/test_zenoh_secure.py checks this file is exactly that output.)
// Default deny. Logins (user names) for the robots {robots}:
{roles}
// dictionary_file: one "user:password" line per user, mode 0600, readable by the router only.
// Clients set transport/auth/usrpwd/{{user,password}}; the bench's services take them from
// HIL_ZENOH_CREDENTIALS (a 0600 file) or HIL_ZENOH_USER/HIL_ZENOH_PASSWORD (deploy/README.md).
// Listening on loopback; for several hosts change listen/endpoints (and see deploy/README.md).
"""


def deploy_json5(
    listen: Sequence[str] = DEPLOY_LISTEN, dictionary_file: str = DEPLOY_DICTIONARY
) -> str:
    """The text of ``deploy/zenoh-router-acl.json5``."""
    lines = []
    for user, (name, robot) in logins(DEPLOY_ROBOTS).items():
        r = role(name)
        put = r.robot_put_keys(robot) if robot else r.put_keys
        pub = ", ".join(put) or "nothing"
        scope = f"hil/{robot}/**" if robot else ALL
        reads = f"reads {scope}" if r.reads else "reads nothing"
        reads += f" and {CLOCK_PREFIX}/{robot}/**" if robot else ""
        lines.append(f"//   {user} ({r.what}): publishes {pub}; {reads}")
    body = _dump(_nest(router_inserts(listen, dictionary_file)), "")
    robots = ", ".join(DEPLOY_ROBOTS)
    return _HEADER.format(roles="\n".join(lines), robots=robots) + body + "\n"


def _dump(value: Any, indent: str) -> str:
    """JSON (valid JSON5) with objects one key per line and lists of scalars on one line."""
    if isinstance(value, dict):
        inner = indent + "  "
        items = [f"{inner}{json.dumps(k)}: {_dump(v, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}" if items else "{}"
    if isinstance(value, list) and any(isinstance(v, dict | list) for v in value):
        inner = indent + "  "
        return "[\n" + ",\n".join(inner + _dump(v, inner) for v in value) + "\n" + indent + "]"
    return json.dumps(value)


def main() -> int:
    sys.stdout.write(deploy_json5())
    return 0


if __name__ == "__main__":
    sys.exit(main())
