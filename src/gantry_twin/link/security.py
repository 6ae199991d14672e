"""Who may talk to ``gantry-twin serve`` and how (docs/live-link.md, "Security").

- Bound to loopback (127.0.0.0/8, ::1, localhost): no security needed; anonymous clients may read and browse.
- Bound to any other address: the server refuses to start unless ``--users FILE`` is given; it then offers only
  Basic256Sha256 with SignAndEncrypt, with a self-signed certificate made on first use in the user's config
  directory (``$XDG_CONFIG_HOME/gantry-twin/opcua``, never the repository), and only users of the file log in.
- Nobody writes a variable. The methods Start, Stop and Reset are for users with the ``operator`` role.

The users file (YAML): ``users: {NAME: {role: viewer|operator, salt: HEX, scrypt: HEX}}``, where ``scrypt`` is
``hashlib.scrypt(password, salt=salt, n=2**14, r=8, p=1, dklen=32)``; :func:`user_entry` makes one.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
import os
import secrets
import socket
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from asyncua import ua
from asyncua.crypto.permission_rules import PermissionRuleset, User, UserRole
from asyncua.server.user_managers import UserManager

from gantry_twin.inputs import read_input_file

ROLES = ("viewer", "operator")
SCRYPT = {"n": 2**14, "r": 8, "p": 1, "dklen": 32}
#: The requests a viewer (and an anonymous client on loopback) may make: sessions, reading, browsing, subscribing.
READ_REQUESTS = tuple(
    getattr(ua.ObjectIds, f"{name}Request_Encoding_DefaultBinary")
    for name in (
        "CreateSession",
        "CloseSession",
        "ActivateSession",
        "Read",
        "Browse",
        "BrowseNext",
        "GetEndpoints",
        "FindServers",
        "TranslateBrowsePathsToNodeIds",
        "RegisterNodes",
        "UnregisterNodes",
        "CreateSubscription",
        "ModifySubscription",
        "DeleteSubscriptions",
        "CreateMonitoredItems",
        "ModifyMonitoredItems",
        "DeleteMonitoredItems",
        "SetMonitoringMode",
        "SetPublishingMode",
        "Publish",
        "Republish",
    )
)
CALL_REQUEST = ua.ObjectIds.CallRequest_Encoding_DefaultBinary


class SecurityError(ValueError):
    """The security asked for cannot be had; the message is one line naming the option."""


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and names that resolve only to them (localhost)."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False
    return bool(infos) and all(ipaddress.ip_address(info[4][0]).is_loopback for info in infos)


def hash_password(password: str, salt: bytes) -> bytes:
    return hashlib.scrypt(password.encode("utf-8"), salt=salt, **SCRYPT)


def user_entry(password: str, role: str = "viewer") -> dict[str, str]:
    """A users file's entry for ``password`` (a fresh salt)."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
    salt = secrets.token_bytes(16)
    return {"role": role, "salt": salt.hex(), "scrypt": hash_password(password, salt).hex()}


@dataclass(frozen=True)
class Account:
    role: str
    salt: bytes
    digest: bytes


def read_users(path: Path) -> dict[str, Account]:
    """The users file (module docstring); SecurityError naming the file and the field on the first problem."""
    where = f"--users {path}"
    try:
        data = yaml.safe_load(read_input_file(path, "a users YAML file"))
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise SecurityError(f"{where}: cannot read it ({str(exc).splitlines()[0] if str(exc) else exc})") from None
    users = data.get("users") if isinstance(data, dict) else None
    if not isinstance(users, dict) or not users:
        raise SecurityError(f"{where}: expected 'users: {{NAME: {{role, salt, scrypt}}}}' with at least one user")
    out = {}
    for name, entry in users.items():
        field_ = f"{where}: users.{name}"
        if not isinstance(entry, dict) or set(entry) != {"role", "salt", "scrypt"}:
            raise SecurityError(f"{field_}: expected exactly the keys role, salt, scrypt")
        if entry["role"] not in ROLES:
            raise SecurityError(f"{field_}.role: one of {', '.join(ROLES)}, got {entry['role']!r}")
        try:
            salt, digest = bytes.fromhex(str(entry["salt"])), bytes.fromhex(str(entry["scrypt"]))
        except ValueError:
            raise SecurityError(f"{field_}: salt and scrypt must be hexadecimal") from None
        if len(salt) < 16 or len(digest) != SCRYPT["dklen"]:
            raise SecurityError(f"{field_}: salt of at least 16 bytes and a {SCRYPT['dklen']}-byte scrypt digest")
        out[str(name)] = Account(entry["role"], salt, digest)
    return out


class _Users(UserManager):
    def __init__(self, accounts: dict[str, Account], anonymous: bool) -> None:
        self.accounts, self.anonymous = accounts, anonymous

    def get_user(self, iserver, username=None, password=None, certificate=None) -> User | None:
        if username is None:
            return User(role=UserRole.Anonymous) if self.anonymous else None
        account = self.accounts.get(username)
        if account is None or password is None:
            return None
        if not hmac.compare_digest(hash_password(str(password), account.salt), account.digest):
            return None
        return User(role=UserRole.User, name=username)


class _Permissions(PermissionRuleset):
    """Reading for every session the user manager let in; Call for operators; nothing else (no writes, no node
    management)."""

    def __init__(self, accounts: dict[str, Account]) -> None:
        self.accounts = accounts
        self.read = {ua.NodeId(i) for i in READ_REQUESTS}
        self.call = ua.NodeId(CALL_REQUEST)

    def check_validity(self, user, action_type_id, body) -> bool:
        if action_type_id in self.read:
            return True
        if action_type_id == self.call:
            account = self.accounts.get(getattr(user, "name", None) or "")
            return account is not None and account.role == "operator"
        return False


def config_dir() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "gantry-twin" / "opcua"


@dataclass
class Security:
    """The server's security for ``host`` (module docstring); :meth:`for_host` checks it before anything starts."""

    host: str
    accounts: dict[str, Account] = field(default_factory=dict)
    cert_dir: Path | None = None

    @classmethod
    def for_host(cls, host: str, users: Path | None, cert_dir: Path | None = None) -> Security:
        accounts = read_users(Path(users)) if users is not None else {}
        if not is_loopback(host) and not accounts:
            raise SecurityError(
                f"--host {host}: not a loopback address; serving beyond this machine needs --users FILE "
                "(salted password hashes; the server then offers only Basic256Sha256 SignAndEncrypt)"
            )
        return cls(host, accounts, cert_dir)

    @property
    def secured(self) -> bool:
        return not is_loopback(self.host)

    def user_manager(self) -> UserManager:
        return _Users(self.accounts, anonymous=not self.secured)

    async def apply(self, server) -> None:
        """Set the endpoints' policies, identity tokens and permissions on an asyncua server before it starts."""
        permissions = _Permissions(self.accounts)
        if not self.secured:
            server.set_security_policy([ua.SecurityPolicyType.NoSecurity], permission_ruleset=permissions)
            tokens = [ua.AnonymousIdentityToken] + ([ua.UserNameIdentityToken] if self.accounts else [])
            server.set_identity_tokens(tokens)
            return
        from asyncua.crypto.cert_gen import setup_self_signed_certificate
        from cryptography.x509.oid import ExtendedKeyUsageOID

        where = self.cert_dir or config_dir()
        try:
            where.mkdir(parents=True, exist_ok=True)
            key, cert = where / "server-key.pem", where / "server-cert.der"
            await setup_self_signed_certificate(
                key,
                cert,
                "urn:gantry-twin:server",
                socket.gethostname(),
                [ExtendedKeyUsageOID.SERVER_AUTH],
                {"commonName": "gantry-twin", "organizationName": "gantry-twin"},
            )
            await server.load_certificate(str(cert))
            await server.load_private_key(str(key))
        except OSError as exc:
            raise SecurityError(f"certificate directory {where}: {exc.strerror or exc}") from None
        policy = [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt]
        server.set_security_policy(policy, permission_ruleset=permissions)
        server.set_identity_tokens([ua.UserNameIdentityToken])
