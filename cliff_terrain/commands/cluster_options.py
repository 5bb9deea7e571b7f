"""The Dask options ``season`` and ``heights --windowed`` share: local workers, or an existing
scheduler (TLS with its three PEM files, or plain TCP on this machine only:
:mod:`cliff_terrain.season.security`), declared and checked once."""

from __future__ import annotations


def add_cluster_arguments(parser, *, workers_help, timeout=10.0):
    """``--workers``, ``--scheduler``, the ``--tls-*`` files, ``--insecure``, ``--timeout`` and
    ``--memory-limit`` on `parser`."""
    parser.add_argument("--workers", type=int, default=None, help=workers_help)
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="an existing Dask scheduler: tls://host:port with the --tls-* files, or tcp://host:port "
        "on this machine (elsewhere only with --insecure); its workers must see the input files at "
        "the same paths",
    )
    parser.add_argument(
        "--tls-ca-file", default=None, metavar="PEM", help="CA that signed the cluster's certificates"
    )
    parser.add_argument("--tls-cert", default=None, metavar="PEM", help="this client's certificate")
    parser.add_argument("--tls-key", default=None, metavar="PEM", help="this client's private key")
    parser.add_argument(
        "--insecure",
        action="store_true",
        help="join a plain-TCP scheduler on another machine (Dask unpickles what it receives: only on "
        "a network you trust)",
    )
    parser.add_argument(
        "--timeout",
        type=float,
        default=timeout,
        help=f"seconds to wait for --scheduler (default {timeout:g})",
    )
    parser.add_argument(
        "--memory-limit",
        default="auto",
        help="memory per local worker, e.g. 2GiB (default: the machine's memory shared out)",
    )


def cluster_security(args):
    """The scheduler's :class:`distributed.security.Security` (or None), checked before any work.

    Raises
    ------
    CliffTerrainError
        The ``--tls-*`` files without a ``tls://`` scheduler, or what
        :func:`~cliff_terrain.season.security.scheduler_security` refuses.
    """
    from ..errors import CliffTerrainError
    from ..season.security import scheduler_security

    if args.scheduler:
        return scheduler_security(
            args.scheduler,
            ca_file=args.tls_ca_file,
            cert=args.tls_cert,
            key=args.tls_key,
            insecure=args.insecure,
        )
    if args.tls_ca_file or args.tls_cert or args.tls_key:
        raise CliffTerrainError("--tls-ca-file, --tls-cert and --tls-key are for a tls:// --scheduler")
    return None
