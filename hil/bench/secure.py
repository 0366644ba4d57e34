"""``hil run --secure``: the whole bench through an authenticating router with access control
(docs/realtime.md, "Secure mode").

Per run, :class:`RunIdentities` makes a fresh random password for each login of
:mod:`protocol.zenoh_acl` (``controller.robot1``, ...) in a private folder outside the run folder
(``tempfile.mkdtemp``, ``hil-secure-*``), deleted at the run's end (after a SIGKILL its passwords
die with the router, PR_SET_PDEATHSIG). A child's environment holds only the path of its own
file, so ``ps e`` and ``/proc/PID/environ`` show no password. Without ``--secure`` every
inherited ``HIL_ZENOH_*`` is cleared: Zenoh refuses a client that presents credentials to a
router that asks for none.

``python -m hil.bench.secure init DIR [ROBOT ...]`` writes the same files for a deployment
(deploy/README.md): ``DIR/zenoh-users.txt`` and ``DIR/credentials/<login>.env`` (robots:
``robot1`` unless named), all 0600.
"""

from __future__ import annotations

import contextlib
import secrets
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from protocol.zenoh_acl import DEPLOY_ROBOTS, login, logins
from runtime.credentials import (
    ENV_DICTIONARY,
    ENV_FILE,
    ENV_VARS,
    Credentials,
    credentials_text,
    dictionary_text,
    write_private,
)
from runtime.zsession import open_session

# hil run's children -> their role (user name) on the router.
CHILD_ROLES = {"controller": "controller", "plant": "emulator"}
PASSWORD_BYTES = 32
DICTIONARY_NAME = "router.users"


def credentials_file_name(role: str) -> str:
    return f"{role}.credentials"


def write_identities(
    source: str, robots: Sequence[str], credentials_dir: Path, dictionary: Path, suffix: str
) -> dict[str, Credentials]:
    """A fresh random password for every login of :mod:`protocol.zenoh_acl` for ``robots``:
    one private credentials file per login, then the router's private dictionary."""
    creds = {
        u: Credentials(u, secrets.token_urlsafe(PASSWORD_BYTES), source) for u in logins(robots)
    }
    for user, c in creds.items():
        write_private(credentials_dir / f"{user}{suffix}", credentials_text(c))
    write_private(dictionary, dictionary_text(creds.values()))
    return creds


class RunIdentities:
    """The run's credentials (``secure``) or the absence of any (see the module docstring)."""

    def __init__(self, secure: bool, robots: Sequence[str] = DEPLOY_ROBOTS) -> None:
        self.secure = bool(secure)
        self.robots = tuple(robots)
        self.folder: Path | None = None
        self._creds: dict[str, Credentials] = {}
        self._sessions: list[Any] = []
        if not self.secure:
            return
        self.folder = Path(tempfile.mkdtemp(prefix="hil-secure-"))
        try:
            dictionary, suffix = self.folder / DICTIONARY_NAME, credentials_file_name("")
            self._creds = write_identities("hil run", self.robots, self.folder, dictionary, suffix)
        except BaseException:
            self.close()
            raise

    def credentials(self, role: str, robot: str | None = None) -> Credentials | None:
        """The login of ``role`` (for ``robot``, default the first); None when not secure."""
        return self._creds[login(role, robot or self.robots[0])] if self.secure else None

    def child_env(self, child: str, robot: str | None = None) -> dict[str, str]:
        """Environment entries for ``child`` ("router", "controller", "plant"; of ``robot``,
        default the first): its own credentials file or dictionary, any other cleared."""
        env = dict.fromkeys(ENV_VARS, "")
        if self.folder is not None:
            if child == "router":
                env[ENV_DICTIONARY] = str(self.folder / DICTIONARY_NAME)
            else:
                user = login(CHILD_ROLES[child], robot or self.robots[0])
                env[ENV_FILE] = str(self.folder / credentials_file_name(user))
        return env

    def router_args(self) -> list[str]:
        return ["--secure", f"--robots={','.join(self.robots)}"] if self.secure else []

    def announcer(self, session: Any, endpoint: str) -> Any:
        """The session that publishes the start message: the recorder's own when not secure,
        else a second client session as ``run`` (the recorder may not publish)."""
        if not self.secure:
            return session
        own = open_session(endpoint, mode="client", credentials=self._creds["run"])
        self._sessions.append(own)
        return own

    def close(self) -> None:
        """Close the sessions opened here and delete the credentials folder."""
        for s in self._sessions:
            with contextlib.suppress(Exception):
                s.close()
        self._sessions.clear()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


def main(argv: list[str] | None = None) -> int:
    """``init DIR [ROBOT ...]``: a deployment's credentials, never overwriting a file."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) < 2 or args[0] != "init":
        print("usage: python -m hil.bench.secure init DIR [ROBOT ...]", file=sys.stderr)
        return 2
    robots = args[2:] or list(DEPLOY_ROBOTS)
    root = Path(args[1])
    (root / "credentials").mkdir(mode=0o700, parents=True, exist_ok=True)
    dictionary = root / "zenoh-users.txt"
    try:
        write_identities("init", robots, root / "credentials", dictionary, ".env")
    except FileExistsError as exc:
        print(f"error: {exc.filename} exists; not overwritten", file=sys.stderr)
        return 2
    print(f"{dictionary} (the router's) and {root / 'credentials'}/<login>.env, mode 0600")
    return 0


if __name__ == "__main__":
    sys.exit(main())
