"""TLS between the client, the scheduler and the workers (Dask's ``Security``), from certificate files.

A run on a cluster can encrypt and authenticate every connection: the
scheduler, the workers and the client (``mercury-dem run``) each present a
certificate signed by one certificate authority (CA) and refuse peers that do
not. The files are PEM:

* ``ca_file``: the CA certificate every peer is checked against;
* ``cert`` / ``key``: this process's certificate and private key (the same pair
  may serve every role: the scripts in ``cluster/`` sign one certificate for the
  scheduler, the workers and the client, as ``Security.temporary()`` does).

``cluster/local/make-certs.sh`` writes such a directory (``ca.pem``,
``cert.pem``, ``key.pem``) with openssl. Nothing here generates keys: Dask's
own ``Security`` does the TLS; this module only turns the CLI's three paths into
one, checking the files first so a typo gives a message naming the file rather
than an SSL error from inside the event loop.

Dask also reads the same settings from its configuration (environment
variables such as ``DASK_DISTRIBUTED__COMM__TLS__CA_FILE``); :func:`tls_environment`
returns those variables, which is how the launch scripts hand TLS to a
``mercury-dem run`` started under them.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mercury_dem.exceptions import ConfigError

#: File names written by ``cluster/local/make-certs.sh`` (and expected by :meth:`TlsFiles.in_directory`).
CA_NAME, CERT_NAME, KEY_NAME = "ca.pem", "cert.pem", "key.pem"


@dataclass(frozen=True)
class TlsFiles:
    """The three PEM files of a TLS set-up (paths as given; checked by :meth:`check`)."""

    ca_file: Path
    cert: Path
    key: Path

    @classmethod
    def in_directory(cls, directory: str | Path) -> TlsFiles:
        """``ca.pem``, ``cert.pem`` and ``key.pem`` in ``directory`` (as written by make-certs.sh)."""
        d = Path(directory)
        return cls(d / CA_NAME, d / CERT_NAME, d / KEY_NAME)

    def check(self) -> TlsFiles:
        """Raise :class:`ConfigError` naming the first file that is missing, unreadable or not PEM."""
        for role, path, marker in (
            ("CA certificate (--tls-ca-file)", self.ca_file, "CERTIFICATE"),
            ("certificate (--tls-cert)", self.cert, "CERTIFICATE"),
            ("private key (--tls-key)", self.key, "PRIVATE KEY"),
        ):
            try:
                head = Path(path).read_text(errors="replace")
            except OSError as exc:
                raise ConfigError(
                    f"TLS {role} {path}: {exc.strerror}; generate a set with "
                    "'cluster/local/make-certs.sh DIR' or give the right path"
                ) from None
            if "-----BEGIN" not in head or marker not in head:
                raise ConfigError(f"TLS {role} {path} is not a PEM file holding a {marker.lower()}")
        return self


def tls_security(files: TlsFiles, require_encryption: bool = True) -> Any:
    """A ``distributed.security.Security`` using ``files`` for every role.

    Parameters
    ----------
    files : the CA, certificate and key (checked first; :class:`ConfigError` names a bad one)
    require_encryption : refuse plain-TCP connections (default True)

    Returns
    -------
    distributed.security.Security
        usable by ``Client``, ``LocalCluster`` (scheduler and workers) and ``connect(..., security=)``.
    """
    from distributed.security import Security

    files.check()
    ca, cert, key = (str(Path(p).resolve()) for p in (files.ca_file, files.cert, files.key))
    return Security(
        tls_ca_file=ca,
        tls_client_cert=cert, tls_client_key=key,
        tls_scheduler_cert=cert, tls_scheduler_key=key,
        tls_worker_cert=cert, tls_worker_key=key,
        require_encryption=require_encryption,
    )


def tls_environment(files: TlsFiles) -> dict[str, str]:
    """Environment variables that give a Dask process (client, scheduler, worker) this TLS set-up.

    Dask's configuration reads them at import, so ``Client(scheduler_file=...)``
    with no ``security=`` argument then connects over TLS.
    """
    files.check()
    ca, cert, key = (str(Path(p).resolve()) for p in (files.ca_file, files.cert, files.key))
    env = {"DASK_DISTRIBUTED__COMM__TLS__CA_FILE": ca, "DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION": "True"}
    for role in ("CLIENT", "SCHEDULER", "WORKER"):
        env[f"DASK_DISTRIBUTED__COMM__TLS__{role}__CERT"] = cert
        env[f"DASK_DISTRIBUTED__COMM__TLS__{role}__KEY"] = key
    return env


def add_tls_arguments(p: argparse.ArgumentParser) -> None:
    """``--tls-ca-file``, ``--tls-cert``, ``--tls-key`` (the names ``dask scheduler``/``dask worker`` use)."""
    g = p.add_argument_group("TLS (all three, or none)")
    g.add_argument("--tls-ca-file", metavar="PEM", help="CA certificate the scheduler and workers are signed by")
    g.add_argument("--tls-cert", metavar="PEM", help="this client's certificate")
    g.add_argument("--tls-key", metavar="PEM", help="this client's private key")


def security_from_args(args: argparse.Namespace) -> Any:
    """The ``Security`` named by ``--tls-ca-file/--tls-cert/--tls-key``, or None when none is given.

    Giving only some of the three is a :class:`ConfigError` (a silent plain-TCP
    fallback would defeat the point).
    """
    given: dict[str, str] = {k: getattr(args, k, None) or "" for k in ("tls_ca_file", "tls_cert", "tls_key")}
    if not any(given.values()):
        return None
    missing = [f"--{k.replace('_', '-')}" for k, v in given.items() if not v]
    if missing:
        raise ConfigError(f"TLS needs --tls-ca-file, --tls-cert and --tls-key together; missing {', '.join(missing)}")
    return tls_security(TlsFiles(Path(given["tls_ca_file"]), Path(given["tls_cert"]), Path(given["tls_key"])))


__all__ = [
    "TlsFiles", "tls_security", "tls_environment", "add_tls_arguments", "security_from_args",
    "CA_NAME", "CERT_NAME", "KEY_NAME",
]


def require_tls_settings(address: str, security: Any, source: str) -> None:
    """Raise :class:`ConfigError` when ``address`` is ``tls://`` and no certificate is configured.

    Dask's own failure there is ``TypeError: TLS expects a ssl_context argument ...`` from
    inside the event loop; this names the scheduler, where its address came from
    (``source``) and the two ways to give the certificates. ``security`` is a
    ``distributed.security.Security`` or ``None``; Dask's configuration (the
    ``DASK_DISTRIBUTED__COMM__TLS__*`` variables of ``env.sh``) counts too.
    """
    if not str(address).startswith("tls://"):
        return
    if security is not None and getattr(security, "tls_client_cert", None):
        return
    import dask

    if dask.config.get("distributed.comm.tls.client.cert", None) or dask.config.get(
            "distributed.comm.tls.ca-file", None) and dask.config.get("distributed.comm.tls.client.key", None):
        return
    raise ConfigError(
        f"scheduler {address} ({source}) requires TLS but no client certificate is configured: pass "
        "--tls-ca-file, --tls-cert and --tls-key (e.g. the ca.pem, cert.pem, key.pem of the deployment's tls/ "
        "directory), or 'source' the deployment's env.sh before running"
    )
