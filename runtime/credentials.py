"""Zenoh credentials of a service: from a private file or the environment, never from a scenario.

A client of an authenticating router (``deploy/``, ``hil run --secure``) proves who it is with a
user name and a password. They come from, in this order of preference:

- ``HIL_ZENOH_CREDENTIALS=/path/to/file``: a file of ``KEY=VALUE`` lines
  (``HIL_ZENOH_USER=controller``, ``HIL_ZENOH_PASSWORD=...``; blank lines and ``#`` comments
  allowed), the same syntax as a systemd ``EnvironmentFile=``. It must be private: a file that
  other users may read or write, or the group may write, is refused (``chmod 600 FILE``);
  group read is allowed only inside systemd's ``$CREDENTIALS_DIRECTORY`` (``LoadCredential=``
  grants the service's user read access through an ACL, which ``stat`` shows as a group bit);
- ``HIL_ZENOH_USER`` and ``HIL_ZENOH_PASSWORD`` themselves.

Setting both ways at once is an error, and so is a user without a password. An empty variable
counts as unset (``hil run`` clears them for its children). The router's user dictionary
(``user:password`` lines, Zenoh's format) is named by ``HIL_ZENOH_DICTIONARY`` and is checked
the same way.

Nothing here is ever written to a run folder or a recording: scenarios, ``run_settings.json``
and hop logs hold no credential, and :class:`Credentials` does not show its password in
``repr``. Only :func:`runtime.zsession.session_config` applies credentials to a session.
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from protocol.errors import BadInputError

ENV_FILE = "HIL_ZENOH_CREDENTIALS"
ENV_USER = "HIL_ZENOH_USER"
ENV_PASSWORD = "HIL_ZENOH_PASSWORD"
ENV_DICTIONARY = "HIL_ZENOH_DICTIONARY"
ENV_VARS = (ENV_FILE, ENV_USER, ENV_PASSWORD, ENV_DICTIONARY)
SYSTEMD_CREDENTIALS_DIR = "CREDENTIALS_DIRECTORY"

# One chunk of Zenoh's dictionary line "user:password": no ':' in a user name, no blanks.
USER_RE = re.compile(r"[A-Za-z0-9_.\-]{1,64}")
_MAX_FILE_BYTES = 64 * 1024


class CredentialsError(BadInputError):
    """Credentials that are missing a part, malformed, or not private (exit code 2)."""


@dataclass(frozen=True)
class Credentials:
    user: str
    password: str = field(repr=False)
    source: str = "environment"

    def __post_init__(self) -> None:
        if not USER_RE.fullmatch(self.user):
            raise CredentialsError(
                f"Zenoh user {self.user!r} ({self.source}) is not 1-64 characters of [A-Za-z0-9_.-]"
            )
        pw = self.password
        if not pw or pw != pw.strip() or any(c in pw for c in "\r\n\0"):
            raise CredentialsError(
                f"the Zenoh password of {self.user!r} ({self.source}) is empty, has a line "
                "break or starts or ends with a blank"
            )


def check_private_file(path: str | Path, what: str = "credentials file") -> Path:
    """``path`` if it is a regular file only its owner can read (see the module docstring);
    raises :class:`CredentialsError` saying what to do otherwise."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise CredentialsError(f"{what} {p}: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise CredentialsError(f"{what} {p} is not a regular file")
    mode = stat.S_IMODE(st.st_mode)
    bad = stat.S_IRWXO | stat.S_IWGRP | stat.S_IXGRP
    systemd_dir = os.environ.get(SYSTEMD_CREDENTIALS_DIR)
    inside_systemd = bool(systemd_dir) and p.resolve().parent == Path(systemd_dir).resolve()
    if not inside_systemd:
        bad |= stat.S_IRGRP
    if mode & bad:
        raise CredentialsError(
            f"{what} {p} has mode {mode:04o}: other users could read or change it. "
            f"Credentials must be private: chmod 600 {p}"
        )
    return p


def parse_credentials(text: str, source: str) -> Credentials:
    """``HIL_ZENOH_USER=...`` and ``HIL_ZENOH_PASSWORD=...`` lines (EnvironmentFile syntax)."""
    values: dict[str, str] = {}
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        key, eq, value = line.partition("=")
        key = key.strip()
        if key.startswith("export "):
            key = key[len("export ") :].strip()
        value = value.strip()
        if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"":
            value = value[1:-1]
        if not eq or key not in (ENV_USER, ENV_PASSWORD):
            raise CredentialsError(
                f"{source}, line {n}: expected {ENV_USER}=... or {ENV_PASSWORD}=..."
            )
        if key in values:
            raise CredentialsError(f"{source}, line {n}: {key} given twice")
        values[key] = value
    missing = [k for k in (ENV_USER, ENV_PASSWORD) if not values.get(k)]
    if missing:
        raise CredentialsError(f"{source}: {' and '.join(missing)} missing")
    return Credentials(values[ENV_USER], values[ENV_PASSWORD], source)


def read_credentials_file(path: str | Path) -> Credentials:
    p = check_private_file(path)
    data = p.read_bytes()[: _MAX_FILE_BYTES + 1]
    if len(data) > _MAX_FILE_BYTES:
        raise CredentialsError(f"credentials file {p} is larger than {_MAX_FILE_BYTES} bytes")
    try:
        text = data.decode()
    except UnicodeDecodeError:
        raise CredentialsError(f"credentials file {p} is not UTF-8 text") from None
    return parse_credentials(text, f"credentials file {p}")


def from_environment(environ: Mapping[str, str] | None = None) -> Credentials | None:
    """The process's credentials (module docstring), or None when none are set."""
    env = os.environ if environ is None else environ
    path = env.get(ENV_FILE, "")
    user = env.get(ENV_USER, "")
    password = env.get(ENV_PASSWORD, "")
    if path:
        if user or password:
            raise CredentialsError(f"set either {ENV_FILE} or {ENV_USER}/{ENV_PASSWORD}, not both")
        return read_credentials_file(path)
    if not user and not password:
        return None
    if not (user and password):
        raise CredentialsError(f"{ENV_USER} and {ENV_PASSWORD} must be set together")
    return Credentials(user, password, f"{ENV_USER}/{ENV_PASSWORD}")


def dictionary_from_environment(environ: Mapping[str, str] | None = None) -> Path | None:
    """The router's user dictionary named by ``HIL_ZENOH_DICTIONARY`` (checked private)."""
    env = os.environ if environ is None else environ
    path = env.get(ENV_DICTIONARY, "")
    if not path:
        return None
    p = check_private_file(path, "Zenoh user dictionary")
    for n, raw in enumerate(p.read_text().splitlines(), 1):
        line = raw.strip()
        if line and not USER_RE.fullmatch(line.partition(":")[0].strip()):
            raise CredentialsError(f"Zenoh user dictionary {p}, line {n}: not user:password")
    return p


def credentials_text(creds: Credentials) -> str:
    """The file :func:`read_credentials_file` reads back."""
    return f"{ENV_USER}={creds.user}\n{ENV_PASSWORD}={creds.password}\n"


def dictionary_text(creds: Iterable[Credentials]) -> str:
    """Zenoh's usrpwd ``dictionary_file``: one ``user:password`` line per user."""
    return "".join(f"{c.user}:{c.password}\n" for c in creds)


def write_private(path: str | Path, text: str) -> Path:
    """Create ``path`` with mode 0600 (never over an existing file, never through a link)."""
    p = Path(path)
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    return p
