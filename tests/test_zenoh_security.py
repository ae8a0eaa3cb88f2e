"""Zenoh security on loopback: user/password authentication, TLS and mutual TLS, and the ACL that
lets only operators send commands (params, tare) while anyone authenticated reads state.
Certificates are made at test time with the `cryptography` package."""

from __future__ import annotations

import dataclasses
import datetime
import ipaddress
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from admittance.daemon import config
from admittance.daemon.config import ZenohConfig
from admittance.daemon.messages import Codec, JointState, State
from admittance.daemon.zenoh_iface import Client, DaemonInterface, security_of
from admittance.daemon.zenoh_security import access_control, security_entries
from admittance.errors import ConfigError, DeviceError

from helpers import free_endpoint

PREFIX = "lab/arm1"


class Handler:
    def __init__(self):
        self.values = {"1.virtual_damping": 0.05}
        self.tares = []

    def get_params(self):
        return dict(self.values)

    def set_params(self, request):
        self.values.update({f"1.{k}": v for k, v in request.items()})
        return True, ""

    def tare(self, samples):
        self.tares.append(samples)
        return True, ""


def serve(zcfg: ZenohConfig):
    """A DaemonInterface pumped like the supervisor does, until the returned stop() is called."""
    handler = Handler()
    iface = DaemonInterface(zcfg, Codec("json"), handler)
    iface.serve()  # the queryables and the token, as the supervisor declares them once its loop runs
    done = threading.Event()
    state = State(cycle=1, joints=[JointState(id=1, t=0.0, force=0.0, tau=0.0, theta=0.0, omega=0.0, goal_tick=2048)])

    def pump():
        while not done.is_set():
            iface.poll()
            iface.publish_state(state)
            done.wait(0.01)

    thread = threading.Thread(target=pump, daemon=True)
    thread.start()

    def stop():
        done.set()
        thread.join()
        iface.close()

    return handler, stop


def client_for(endpoint: str, tmp_path: Path, **keys) -> Client:
    zen = config.absolute_zenoh_paths(ZenohConfig(connect=[endpoint], **keys), tmp_path)
    return Client([endpoint], {k: v for k, v in security_of(zen).items() if k != "access_control"})


def reads_state(client: Client, timeout: float = 5.0) -> bool:
    sub = client.try_stream(PREFIX)
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            if any(kind == "state" for kind, _ in sub.drain()):
                return True
            time.sleep(0.05)
        return False
    finally:
        sub.close()


def can_command(client: Client) -> bool:
    try:
        return client.query(f"{PREFIX}/params", {"virtual_damping": 0.07}, timeout=1.5) == {"accepted": True} and \
            client.query(f"{PREFIX}/tare", {"samples": 10}, timeout=1.5) == {"accepted": True}
    except DeviceError:  # nobody answered: the query never reached a queryable
        return False


@pytest.fixture
def users(tmp_path):
    (tmp_path / "users.txt").write_text("operator:op-secret\nviewer:look-only\n")
    for name, password in (("operator", "op-secret"), ("viewer", "look-only"), ("intruder", "guess")):
        (tmp_path / f"{name}.pw").write_text(password + "\n")
    return tmp_path


def test_user_password_and_acl_only_operators_set_or_tare(users):
    endpoint = free_endpoint()
    daemon = config.absolute_zenoh_paths(
        ZenohConfig(prefix=PREFIX, listen=[endpoint], auth_dictionary="users.txt", operators=["operator"]), users)
    handler, stop = serve(daemon)
    try:
        with client_for(endpoint, users, auth_user="operator", auth_password_file="operator.pw") as op:
            assert reads_state(op) and can_command(op)
        assert handler.values["1.virtual_damping"] == 0.07 and handler.tares == [10]
        with client_for(endpoint, users, auth_user="viewer", auth_password_file="viewer.pw") as viewer:
            assert reads_state(viewer)  # state is readable by any authenticated session
            assert not can_command(viewer)  # ... but not params nor tare
        for keys in ({}, {"auth_user": "intruder", "auth_password_file": "intruder.pw"}):
            with client_for(endpoint, users, **keys) as stranger:  # no login, or a wrong one: no link at all
                assert not reads_state(stranger, timeout=1.0) and not can_command(stranger)
        assert handler.tares == [10]
    finally:
        stop()


def make_pki(folder: Path) -> None:
    """A CA and three certificates (the daemon on localhost, an operator, a viewer), PEM files."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.timezone.utc)

    def name(cn):
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def write(stem, key, cert):
        (folder / f"{stem}.key").write_bytes(key.private_bytes(serialization.Encoding.PEM,
                                                               serialization.PrivateFormat.PKCS8,
                                                               serialization.NoEncryption()))
        (folder / f"{stem}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (x509.CertificateBuilder().subject_name(name("lab-ca")).issuer_name(name("lab-ca"))
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=1))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True).sign(ca_key, hashes.SHA256()))
    write("ca", ca_key, ca)
    for cn in ("localhost", "operator", "viewer"):
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder().subject_name(name(cn)).issuer_name(ca.subject).public_key(key.public_key())
                .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
                .not_valid_after(now + datetime.timedelta(days=1))
                .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                            x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                               critical=False)
                .sign(ca_key, hashes.SHA256()))
        write(cn, key, cert)


def test_mutual_tls_and_acl_by_certificate_name(tmp_path):
    pytest.importorskip("cryptography")
    make_pki(tmp_path)
    endpoint = free_endpoint().replace("tcp/127.0.0.1", "tls/localhost")
    daemon = config.absolute_zenoh_paths(ZenohConfig(
        prefix=PREFIX, listen=[endpoint], tls_ca="ca.pem", tls_certificate="localhost.pem",
        tls_private_key="localhost.key", tls_client_auth=True, operators=["operator"]), tmp_path)
    handler, stop = serve(daemon)
    try:
        def tls(cn):
            keys = {"tls_ca": "ca.pem"}
            if cn:
                keys.update(tls_certificate=f"{cn}.pem", tls_private_key=f"{cn}.key", tls_client_auth=True)
            return client_for(endpoint, tmp_path, **keys)

        with tls("operator") as op:
            assert reads_state(op) and can_command(op)
        with tls("viewer") as viewer:
            assert reads_state(viewer) and not can_command(viewer)
        with tls(None) as anonymous:  # TLS without a client certificate: refused by mTLS
            assert not reads_state(anonymous, timeout=1.0)
        assert handler.tares == [10]
    finally:
        stop()


def test_the_acl_denies_everything_but_reads_and_operator_commands():
    acl = access_control(["lab"], ["alice"])
    assert acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert "query" in rules["command"]["messages"] and rules["command"]["key_exprs"] == ["lab/**"]
    assert "query" not in rules["read"]["messages"] and "@ros2_lv/**" in rules["read"]["key_exprs"]
    assert "put" not in rules["read"]["messages"] and rules["receive"]["flows"] == ["egress"]
    assert rules["publish"]["flows"] == ["ingress"] and "put" in rules["publish"]["messages"]
    policies = {tuple(p["rules"]): p["subjects"] for p in acl["policies"]}
    assert policies[("command", "publish")] == ["operator-users", "operator-certificates"]
    assert "publish" not in policies[("read", "receive", "ros2-graph")]


@pytest.mark.parametrize("keys, message", [
    ({"auth_user": "a"}, "auth_user and auth_password_file"),
    ({"operators": ["alice"]}, "operators: needs a way to tell who connects"),
    ({"listen": ["tls/localhost:7447"]}, "tls_certificate: required to listen"),
    ({"connect": ["tls/localhost:7447"]}, "tls_ca: required with a tls/ endpoint"),
    ({"tls_client_auth": True}, "tls_client_auth: needs tls_ca"),
    ({"tls_certificate": "c.pem"}, "tls_certificate and tls_private_key"),
])
def test_security_keys_that_do_not_fit_together_are_one_line_errors(keys, message):
    with pytest.raises(ConfigError, match=message):
        config.check_zenoh_security(dataclasses.replace(ZenohConfig(), **keys), "daemon.toml")


def test_missing_or_bad_security_files_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="auth_dictionary: file .* not found"):
        security_entries(ZenohConfig(auth_dictionary="nope.txt"), tmp_path)
    (tmp_path / "two-lines.pw").write_text("a\nb\n")
    with pytest.raises(ConfigError, match="password on one line"):
        security_entries(ZenohConfig(auth_user="u", auth_password_file="two-lines.pw"), tmp_path)
    (tmp_path / "users.txt").write_text("u:p\n")
    (tmp_path / "u.pw").write_text("p\n")
    entries = security_entries(ZenohConfig(auth_dictionary="users.txt", auth_user="u", auth_password_file="u.pw",
                                           operators=["u"]), tmp_path)
    assert entries["transport/auth/usrpwd/password"] == "p" and entries["access_control"]["enabled"]


def test_a_refused_login_and_an_acl_refusal_are_one_clear_line_each(users):
    endpoint = free_endpoint()
    daemon = config.absolute_zenoh_paths(
        ZenohConfig(prefix=PREFIX, listen=[endpoint], auth_dictionary="users.txt", operators=["operator"]), users)
    handler, stop = serve(daemon)
    try:
        with client_for(endpoint, users, auth_user="intruder", auth_password_file="intruder.pw") as intruder:
            with pytest.raises(DeviceError) as refused:
                intruder.query(f"{PREFIX}/params", {"virtual_damping": 0.07}, timeout=1.5)
        assert str(refused.value) == (f"{endpoint} refused this session (user 'intruder'): check auth_user and "
                                      "its password file, or the TLS certificate, in --zenoh-config")
        with client_for(endpoint, users, auth_user="viewer", auth_password_file="viewer.pw") as viewer:
            assert reads_state(viewer)
            with pytest.raises(DeviceError, match=f"the daemon at {PREFIX} is up but did not answer {PREFIX}/params: "
                                                  "the router's access control lets only its operators send "
                                                  "commands, and this session has user 'viewer'"):
                viewer.query(f"{PREFIX}/params", {"virtual_damping": 0.07}, timeout=1.5)
        # the command line, in its own process (zenoh's log is set once per process): one line, no raw log
        (users / "intruder.toml").write_text(f'[zenoh]\nconnect = ["{endpoint}"]\nauth_user = "intruder"\n'
                                             f'auth_password_file = "intruder.pw"\n')
        cli = subprocess.run([str(Path(sys.executable).parent / "admittance"), "set", "virtual_damping=0.07",
                              "--prefix", PREFIX, "--zenoh-config", str(users / "intruder.toml")],
                             capture_output=True, text=True, timeout=60)
        assert cli.returncode == 3 and cli.stdout == "", cli.stdout
        assert cli.stderr == f"admittance set: error: {refused.value}\n", cli.stderr
    finally:
        stop()
    with client_for(free_endpoint(), users) as nobody, pytest.raises(DeviceError, match="nothing answers at tcp/"):
        nobody.query(f"{PREFIX}/params", timeout=0.5)
    assert handler.values.get("1.virtual_damping") != 0.07
