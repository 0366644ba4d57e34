"""Who may do what on the bench's Zenoh router: the one definition of its access control.

Every session of a secure bench is a client of one router that authenticates it by user name
and password (Zenoh's ``usrpwd``: a challenge-response, the password never crosses the link)
and then applies the rules below, default deny. A role is a user name:

- ``controller`` publishes ``hil/*/cmd/torque``, ``hil/*/telemetry``, ``hil/*/status``;
- ``emulator`` publishes ``hil/*/state``, ``hil/*/status``;
- ``recorder`` (``hil run``'s recorder) and ``monitor`` (an operator's tool) publish nothing;
- ``run`` (``hil run``'s start announcement) publishes ``hil/*/status`` only;
- every role but ``run`` may subscribe to ``hil/**`` and be delivered what is published there.

``hil run --secure`` builds its router from :func:`router_inserts`, and
``deploy/zenoh-router-acl.json5`` is :func:`deploy_json5` written out
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


def stream_key(suffix: str) -> str:
    """``hil/*/<suffix>``: one stream of every robot (``*`` is exactly one key chunk)."""
    return f"{keys.PREFIX}/*/{suffix}"


@dataclass(frozen=True)
class Role:
    name: str
    publishes: tuple[str, ...]  # stream suffixes of protocol.keys
    reads: bool  # may subscribe to hil/** and be delivered it
    what: str

    @property
    def put_keys(self) -> list[str]:
        return [stream_key(s) for s in self.publishes]


ROLES: tuple[Role, ...] = (
    Role("controller", (keys.TORQUE, keys.TELEMETRY, keys.STATUS), True, "the controller service"),
    Role("emulator", (keys.STATE, keys.STATUS), True, "the plant emulator"),
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


def access_control() -> dict[str, Any]:
    """The router's ``access_control`` block (Zenoh 1.x ACL: rules, subjects, policies)."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for r in ROLES:
        if not r.publishes:
            continue
        subjects.append({"id": r.name, "usernames": [r.name]})
        # What it may publish (ingress at the router), and the subscriptions on those keys it
        # is told about (egress), so its own session does not filter its puts away.
        rules.append(
            {
                "id": f"{r.name}-put",
                "messages": ["put"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": r.put_keys,
            }
        )
        rules.append(
            {
                "id": f"{r.name}-sees-subscribers",
                "messages": ["declare_subscriber"],
                "flows": ["egress"],
                "permission": "allow",
                "key_exprs": r.put_keys,
            }
        )
        rule_ids = [f"{r.name}-put", f"{r.name}-sees-subscribers"]
        policies.append({"rules": rule_ids, "subjects": [r.name]})
    readers = [r.name for r in ROLES if r.reads]
    subjects.append({"id": "readers", "usernames": readers})
    rules.append(
        {
            "id": "subscribe",
            "messages": ["declare_subscriber"],
            "flows": ["ingress", "egress"],
            "permission": "allow",
            "key_exprs": [ALL],
        }
    )
    rules.append(
        {
            "id": "deliver",
            "messages": ["put"],
            "flows": ["egress"],
            "permission": "allow",
            "key_exprs": [ALL],
        }
    )
    policies.append({"rules": ["subscribe", "deliver"], "subjects": ["readers"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def router_inserts(
    listen: Sequence[str], dictionary_file: str, *, allow_non_loopback: bool = False
) -> dict[str, Any]:
    """The router's configuration as ``key path -> value`` (what ``insert_json5`` takes): the
    bench's router settings (:mod:`protocol.zenoh_config`: multicast scouting off), usrpwd
    authentication against ``dictionary_file`` (``user:password`` lines) and the ACL."""
    settings = ZenohSettings(
        mode="router", listen=tuple(listen), allow_non_loopback=allow_non_loopback
    )
    out = config_dict(settings)
    out["transport/auth/usrpwd/dictionary_file"] = dictionary_file
    out["access_control"] = access_control()
    return out


def router_config(
    listen: Sequence[str], dictionary_file: str, *, allow_non_loopback: bool = False
) -> zenoh.Config:
    conf = zenoh.Config()
    inserts = router_inserts(listen, dictionary_file, allow_non_loopback=allow_non_loopback)
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
// Default deny. Roles (user names):
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
    for r in ROLES:
        pub = ", ".join(r.put_keys) or "nothing"
        reads = "reads hil/**" if r.reads else "reads nothing"
        lines.append(f"//   {r.name} ({r.what}): publishes {pub}; {reads}")
    body = _dump(_nest(router_inserts(listen, dictionary_file)), "")
    return _HEADER.format(roles="\n".join(lines)) + body + "\n"


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
