"""Which Zenoh endpoints the link may use, and the TLS settings of those that need them.

The policy (:func:`check_endpoint`):

- ``tcp/``, ``udp/`` and ``ws/`` (plain text) on a loopback address (127.0.0.0/8, ::1,
  ``localhost``) only; anywhere else they are refused unless ``allow_plaintext_network=True``
  (the frames are still authenticated, but anyone on the path reads them, and can cut them);
- ``tls/``: anywhere, with mutual TLS from the keys folder (:func:`tls_settings`) and Zenoh's
  access control (:func:`acl_settings`): only the peer's certificate (common name
  ``teleop-<peer role>``) may put on the one key this side reads, only it receives what this side
  puts, and everything else is denied by default, so another holder of a certificate from the same
  CA neither drives nor overhears the pair (the frames' MAC and the pairing also refuse it);
- ``unixsock-stream/``: a local socket file, allowed;
- anything else is refused.
"""

from __future__ import annotations

import ipaddress
import json

from teleop.link.keys import LinkKeys
from teleop.util.errors import ConfigError

PLAIN = ("tcp", "udp", "ws")
LOCAL = ("unixsock-stream",)
TLS = ("tls",)


def split_endpoint(endpoint: str) -> tuple[str, str, str]:
    """(protocol, host, port) of ``proto/host:port[?config][#metadata]`` (IPv6 in brackets)."""
    if not isinstance(endpoint, str) or "/" not in endpoint:
        raise ConfigError(f"Zenoh endpoint {endpoint!r}: expected 'protocol/address', e.g. tcp/127.0.0.1:7447")
    proto, rest = endpoint.split("/", 1)
    addr = rest.split("?", 1)[0].split("#", 1)[0]
    if proto in LOCAL:
        return proto, addr, ""
    host, sep, port = addr.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"Zenoh endpoint {endpoint!r}: expected host:port after '{proto}/'")
    return proto, host.strip("[]"), port


def is_loopback(host: str) -> bool:
    """True for a loopback address or the name ``localhost`` (no other name is looked up)."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_endpoint(endpoint: str, allow_plaintext_network: bool = False) -> str:
    """The endpoint's protocol, if the policy (module docstring) lets the link use it; else
    ConfigError naming the endpoint and the reason."""
    proto, host, _ = split_endpoint(endpoint)
    if proto in TLS or proto in LOCAL:
        return proto
    if proto not in PLAIN:
        raise ConfigError(f"Zenoh endpoint {endpoint!r}: protocol {proto!r} is not supported by the link "
                          f"(use tls/ between hosts, tcp/ on loopback)")
    if not is_loopback(host) and not allow_plaintext_network:
        raise ConfigError(f"Zenoh endpoint {endpoint!r}: plain-text {proto}/ off loopback is refused "
                          f"(anyone on the network reads the link): use tls/{host}:PORT with the "
                          f"certificates of 'teleop keys', or pass --allow-plaintext-network "
                          f"(allow_plaintext_network=True)")
    return proto


def tls_settings(keys: LinkKeys | None, listen: str | None, connect: str | None) -> dict[str, str]:
    """The Zenoh settings (json5 values) for mutual TLS on the ``tls/`` endpoints among
    ``listen`` and ``connect``: the CA, this side's certificate and key, client certificates
    required, the server's name checked. Empty when neither is ``tls/``; ConfigError when one
    is and ``keys`` has no certificates."""
    tls = [ep for ep in (listen, connect) if ep and split_endpoint(ep)[0] in TLS]
    if not tls:
        return {}
    if keys is None or not keys.has_tls:
        raise ConfigError(f"Zenoh endpoint {tls[0]!r}: tls/ needs this side's certificate, key and the CA "
                          f"(a keys folder from 'teleop keys'); none given")
    out = {"transport/link/tls/root_ca_certificate": json.dumps(str(keys.ca_pem)),
           "transport/link/tls/enable_mtls": "true"}
    for side, ep in (("listen", listen), ("connect", connect)):
        if ep and split_endpoint(ep)[0] in TLS:
            out[f"transport/link/tls/{side}_certificate"] = json.dumps(str(keys.cert_pem))
            out[f"transport/link/tls/{side}_private_key"] = json.dumps(str(keys.key_pem))
    if connect and split_endpoint(connect)[0] in TLS:
        out["transport/link/tls/verify_name_on_connect"] = "true"
    return out


#: The Zenoh messages the link exchanges (its publisher's puts and the subscriptions that route them);
#: every other kind (queries, replies, liveliness, deletes) is denied on a TLS link.
ACL_MESSAGES = {"data": ["put"], "interest": ["declare_subscriber"]}


def peer_common_name(role: str) -> str:
    """The common name of the peer's certificate as ``teleop keys`` issues it: the master's peer is
    ``teleop-slave``, the slave's ``teleop-master``."""
    return f"teleop-{'slave' if role == 'master' else 'master'}"


def acl_settings(role: str, session: str, listen: str | None, connect: str | None) -> dict[str, str]:
    """Zenoh access control (json5 settings) for a side that uses a ``tls/`` endpoint: default deny;
    the peer's certificate (:func:`peer_common_name`) may put on ``teleop/<session>/<in key>``
    (ingress) and receive this side's puts on ``teleop/<session>/<out key>`` (egress), and declare
    subscribers on those two keys. Empty when no endpoint is ``tls/`` (on loopback the frames' MAC
    is the access boundary: Zenoh's ACL can only name a peer by its certificate)."""
    if not any(ep and split_endpoint(ep)[0] in TLS for ep in (listen, connect)):
        return {}
    out_key, in_key = ("cmd", "fb") if role == "master" else ("fb", "cmd")
    keys = {k: f"teleop/{session}/{k}" for k in (out_key, in_key)}
    rules = [{"id": "peer_puts", "permission": "allow", "flows": ["ingress"], "messages": ACL_MESSAGES["data"],
              "key_exprs": [keys[in_key]]},
             {"id": "peer_hears", "permission": "allow", "flows": ["egress"], "messages": ACL_MESSAGES["data"],
              "key_exprs": [keys[out_key]]},
             {"id": "routes", "permission": "allow", "flows": ["ingress", "egress"],
              "messages": ACL_MESSAGES["interest"], "key_exprs": sorted(keys.values())}]
    acl = {"enabled": True, "default_permission": "deny", "rules": rules,
           "subjects": [{"id": "peer", "cert_common_names": [peer_common_name(role)]}],
           "policies": [{"id": "the_pair", "rules": [r["id"] for r in rules], "subjects": ["peer"]}]}
    return {"access_control": json.dumps(acl)}
