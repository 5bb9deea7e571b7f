"""Joining a Dask scheduler is a trust decision: TLS with a key, or plain TCP on this machine only.

Dask's protocol unpickles what it receives, so whoever can talk to the scheduler, or sit on the
network path to it, can run code in this process. ``tls://`` with a CA file, a certificate and its
key (:class:`distributed.security.Security`) encrypts the link and admits only holders of a
certificate from that CA. A plain ``tcp://`` address is accepted on this machine (loopback or its
own addresses), and elsewhere only when the caller says ``insecure``: on a network they trust.
"""

from __future__ import annotations

import ipaddress
import os
import socket
from urllib.parse import urlsplit

from ..errors import CliffTerrainError

TLS_OPTIONS = ("--tls-ca-file", "--tls-cert", "--tls-key")


def scheduler_security(address, *, ca_file=None, cert=None, key=None, insecure=False):
    """The :class:`distributed.security.Security` for joining `address`, or None for plain TCP.

    Parameters
    ----------
    address : str
        ``tls://host:port``, ``tcp://host:port`` or ``host:port`` (TCP).
    ca_file, cert, key : str, optional
        PEM files: the CA that signed the cluster's certificates, this client's certificate and its
        private key. All three for ``tls://``; none for TCP.
    insecure : bool, optional
        Join a plain-TCP scheduler on another machine.

    Raises
    ------
    CliffTerrainError
        A ``tls://`` address without its three files (or with a file missing), TLS files with a
        TCP address, or a TCP address off this machine without `insecure`.
    """
    scheme, host = _split(address)
    files = {"--tls-ca-file": ca_file, "--tls-cert": cert, "--tls-key": key}
    given = {name: path for name, path in files.items() if path}
    if scheme == "tls":
        missing = [name for name in TLS_OPTIONS if name not in given]
        if missing:
            raise CliffTerrainError(f"the TLS scheduler `{address}` needs {', '.join(missing)}")
        for name, path in given.items():
            if not os.path.isfile(path):
                raise CliffTerrainError(f"{name} {str(path)!r} is not a file")
        from distributed.security import Security

        return Security(
            tls_ca_file=ca_file, tls_client_cert=cert, tls_client_key=key, require_encryption=True
        )
    if given:
        raise CliffTerrainError(
            f"{', '.join(given)} given for the unencrypted scheduler `{address}`: use a tls:// address"
        )
    if not insecure and not on_this_machine(host):
        raise CliffTerrainError(
            f"refusing the plain-TCP scheduler `{address}` on another machine: Dask unpickles what it "
            "receives, so anyone on the way could run code here; use tls:// with "
            f"{', '.join(TLS_OPTIONS)}, or --insecure on a network you trust"
        )
    return None


def _split(address):
    """(scheme, host) of a Dask address (no scheme: TCP)."""
    text = str(address)
    parts = urlsplit(text if "://" in text else f"tcp://{text}")
    if not parts.hostname:
        raise CliffTerrainError(
            f"`--scheduler` must be like tls://host:8786 or tcp://host:8786, got {text!r}"
        )
    return parts.scheme.lower(), parts.hostname


def on_this_machine(host):
    """True when `host` is a loopback address or one of this machine's own addresses."""
    try:
        addresses = {info[4][0] for info in socket.getaddrinfo(host, None)}
    except OSError:
        return False
    own = set()
    for name in (socket.gethostname(), socket.getfqdn()):
        try:
            own |= {info[4][0] for info in socket.getaddrinfo(name, None)}
        except OSError:
            pass
    return all(ipaddress.ip_address(a.split("%")[0]).is_loopback or a in own for a in addresses)
