"""Key files, certificates and the endpoint policy: make_keys writes what load_keys reads, every
error is one line naming the file; plain text off loopback refused unless asked for by name;
tls/ endpoints get mutual TLS from the keys."""

import json
import os
import stat

import pytest

from teleop.link.endpoints import acl_settings, check_endpoint, peer_common_name, tls_settings
from teleop.link.keys import (
    KeyFileError,
    LinkKeys,
    load_keys,
    load_pairing_key,
    make_keys,
    one_run_keys,
    write_pairing_key,
)
from teleop.util.errors import ConfigError


def _one_line(e):
    return "\n" not in str(e.value)


def test_make_keys_writes_what_load_keys_reads(tmp_path):
    files = make_keys(tmp_path / "k", hosts=["127.0.0.1", "localhost", "slave.example"])
    assert set(files) == {"pairing.key", "ca.pem", "ca.key", "master.pem", "master.key", "slave.pem", "slave.key"}
    for name in ("pairing.key", "ca.key", "master.key", "slave.key"):
        assert stat.S_IMODE(os.stat(files[name]).st_mode) == 0o600
    m, s = load_keys(tmp_path / "k", "master"), load_keys(tmp_path / "k", "slave")
    assert m.secret == s.secret and (m.name, s.name) == ("teleop-master", "teleop-slave")
    assert m.has_tls and s.cert_pem.name == "slave.pem"
    assert m.secret.hex() not in repr(m)
    from cryptography import x509
    cert = x509.load_pem_x509_certificate(files["slave.pem"].read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert [str(ip) for ip in san.get_values_for_type(x509.IPAddress)] == ["127.0.0.1"]
    assert san.get_values_for_type(x509.DNSName) == ["localhost", "slave.example"]
    with pytest.raises(KeyFileError, match="exists"):
        make_keys(tmp_path / "k")


def test_pairing_key_only_folder(tmp_path):
    make_keys(tmp_path, tls=False)
    k = load_keys(tmp_path, "slave")
    assert k.name == "slave" and not k.has_tls and len(k.secret) == 32


@pytest.mark.parametrize("text, mode, reason", [
    (None, 0o600, "no such pairing key file"),
    ("teleop pairing key v1\n" + "ab" * 32 + "\n", 0o644, "readable by others"),
    ("hello\n" + "ab" * 32 + "\n", 0o600, "not a pairing key file"),
    ("teleop pairing key v1\n" + "zz" * 32 + "\n", 0o600, "not hexadecimal"),
    ("teleop pairing key v1\n" + "ab" * 16 + "\n", 0o600, "has 16 bytes"),
])
def test_pairing_key_errors_name_the_file(tmp_path, text, mode, reason):
    p = tmp_path / "pairing.key"
    if text is not None:
        p.write_text(text)
        p.chmod(mode)
    with pytest.raises(KeyFileError, match=reason) as e:
        load_pairing_key(p)
    assert str(p) in str(e.value) and _one_line(e)


def test_pairing_key_round_trip_with_comments(tmp_path):
    key = write_pairing_key(tmp_path / "k")
    (tmp_path / "k").write_text("# made for a test\n" + (tmp_path / "k").read_text())
    assert load_pairing_key(tmp_path / "k") == key


def test_certificate_errors_name_the_file(tmp_path):
    make_keys(tmp_path / "a")
    make_keys(tmp_path / "b")
    (tmp_path / "a" / "master.pem").write_bytes((tmp_path / "b" / "master.pem").read_bytes())
    with pytest.raises(KeyFileError, match="not issued by the CA") as e:
        load_keys(tmp_path / "a", "master")
    assert "master.pem" in str(e.value) and _one_line(e)
    (tmp_path / "b" / "slave.key").write_bytes((tmp_path / "b" / "master.key").read_bytes())
    with pytest.raises(KeyFileError, match="does not match the certificate"):
        load_keys(tmp_path / "b", "slave")
    (tmp_path / "b" / "ca.pem").write_text("not a certificate")
    with pytest.raises(KeyFileError, match=r"ca\.pem: not a PEM certificate"):
        load_keys(tmp_path / "b", "master")
    with pytest.raises(KeyFileError, match="no such keys folder"):
        load_keys(tmp_path / "nowhere", "master")


def test_one_run_keys_are_private(tmp_path):
    path, m, s = one_run_keys()
    try:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600 and stat.S_IMODE(path.parent.stat().st_mode) == 0o700
        assert load_pairing_key(path) == m.secret == s.secret and (m.name, s.name) == ("master", "slave")
    finally:
        path.unlink()
        path.parent.rmdir()


def test_link_keys_are_checked():
    with pytest.raises(KeyFileError):
        LinkKeys(b"short", "m")
    with pytest.raises(KeyFileError):
        LinkKeys(bytes(32), "two\nlines")


@pytest.mark.parametrize("ep", ["tcp/127.0.0.1:7447", "tcp/127.3.2.1:1", "tcp/[::1]:7447", "tcp/localhost:7447",
                                "udp/127.0.0.1:7447", "tls/10.0.0.2:7447", "tls/host.example:7447",
                                "unixsock-stream//tmp/teleop.sock", "tcp/127.0.0.1:7447#iface=lo"])
def test_allowed_endpoints(ep):
    check_endpoint(ep)


@pytest.mark.parametrize("ep", ["tcp/10.0.0.2:7447", "tcp/0.0.0.0:7447", "udp/192.168.1.5:7447",
                                "tcp/[::]:7447", "tcp/slave.example:7447", "ws/10.0.0.2:80"])
def test_plain_text_off_loopback_is_refused_unless_asked_for(ep):
    with pytest.raises(ConfigError, match="allow_plaintext_network") as e:
        check_endpoint(ep)
    assert ep in str(e.value) and _one_line(e)
    check_endpoint(ep, allow_plaintext_network=True)


@pytest.mark.parametrize("ep", ["quic/10.0.0.2:7447", "serial//dev/ttyUSB0", "tcp/nope", "nonsense"])
def test_unknown_endpoints_are_refused(ep):
    with pytest.raises(ConfigError):
        check_endpoint(ep)


def test_tls_settings_from_the_keys(tmp_path):
    make_keys(tmp_path)
    k = load_keys(tmp_path, "master")
    assert tls_settings(k, None, "tcp/127.0.0.1:7447") == {}
    t = tls_settings(k, None, "tls/10.0.0.2:7447")
    assert json.loads(t["transport/link/tls/connect_certificate"]) == str(tmp_path / "master.pem")
    assert json.loads(t["transport/link/tls/root_ca_certificate"]) == str(tmp_path / "ca.pem")
    assert t["transport/link/tls/enable_mtls"] == "true" and t["transport/link/tls/verify_name_on_connect"] == "true"
    t = tls_settings(k, "tls/0.0.0.0:7447", None)
    assert "transport/link/tls/listen_private_key" in t and "transport/link/tls/verify_name_on_connect" not in t
    with pytest.raises(ConfigError, match="needs this side's certificate"):
        tls_settings(LinkKeys(k.secret, "m"), None, "tls/10.0.0.2:7447")


def test_make_config_applies_the_policy(tmp_path):
    pytest.importorskip("zenoh")
    from teleop.link.zenoh_link import make_config

    with pytest.raises(ConfigError, match=r"tcp/10\.0\.0\.2:7447"):
        make_config(connect="tcp/10.0.0.2:7447")
    with pytest.raises(ConfigError, match="pass the endpoints"):
        make_config(listen="tcp/127.0.0.1:7447", config_json5={"connect/endpoints": '["tcp/10.0.0.2:7447"]'})
    c = make_config(connect="tcp/10.0.0.2:7447", allow_plaintext_network=True, connect_timeout_s=2)
    assert json.loads(c.get_json("scouting/gossip/enabled")) is False
    assert json.loads(c.get_json("connect/timeout_ms")) == 2000


@pytest.mark.parametrize("role, reads, writes", [("slave", "cmd", "fb"), ("master", "fb", "cmd")])
def test_a_tls_side_lets_only_its_peers_certificate_put_what_it_reads_and_hear_what_it_puts(role, reads, writes):
    assert acl_settings(role, "s", "tcp/127.0.0.1:7447", None) == {}  # on loopback the MAC is the boundary
    acl = json.loads(acl_settings(role, "s", "tls/0.0.0.0:7447" if role == "slave" else None,
                                  "tls/10.0.0.2:7447" if role == "master" else None)["access_control"])
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["peer_puts"]["flows"] == ["ingress"] and rules["peer_puts"]["key_exprs"] == [f"teleop/s/{reads}"]
    assert rules["peer_hears"]["flows"] == ["egress"] and rules["peer_hears"]["key_exprs"] == [f"teleop/s/{writes}"]
    kinds = {"put", "declare_subscriber"}
    assert all(r["permission"] == "allow" and set(r["messages"]) <= kinds for r in rules.values())
    assert acl["subjects"] == [{"id": "peer", "cert_common_names": [peer_common_name(role)]}]
    assert peer_common_name(role) == f"teleop-{'master' if role == 'slave' else 'slave'}"
    assert set(acl["policies"][0]["rules"]) == set(rules) and acl["policies"][0]["subjects"] == ["peer"]


def test_make_config_keeps_the_links_own_access_control(tmp_path):
    pytest.importorskip("zenoh")
    from teleop.link.zenoh_link import make_config

    make_keys(tmp_path)
    c = make_config(listen="tls/127.0.0.1:7447", keys=load_keys(tmp_path, "slave"), role="slave", session="s")
    assert json.loads(c.get_json("access_control/default_permission")) == "deny"
    with pytest.raises(ConfigError, match="its own access control"):
        make_config(listen="tls/127.0.0.1:7447", keys=load_keys(tmp_path, "slave"), role="slave",
                    config_json5={"access_control/enabled": "false"})
