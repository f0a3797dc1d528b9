"""Which client applications may open an OPC UA session: the trust folder of client certificates.

OPC 10000-4 (CreateSession) has the server validate the client's application instance certificate,
and OPC 10000-2 / 10000-6 describe trust lists: a server trusts the certificates an administrator put
in its trusted store and rejects every other one with ``Bad_CertificateUntrusted``, keeping a copy in a
rejected store for the administrator to inspect and, if wanted, move over. That is what this does:

- ``trusted/``: DER or PEM certificates; a client whose certificate (SHA-256 fingerprint, the exact
  certificate: application instance certificates are mostly self-signed) is not among them is refused
  before any session exists, whatever its user name and password. Re-read at every CreateSession, so
  adding or removing a file takes effect without a restart;
- ``rejected/``: each refused certificate once (at most ``MAX_REJECTED`` files), named by its common
  name and fingerprint: moving one into ``trusted/`` admits that client;
- the certificate must also be within its validity period and name the client's ApplicationUri
  (asyncua's ``CertificateValidator``, time range and URI checks).

No certificate at all (a SecurityPolicy#None channel) never gets this far: the user manager refuses
such sessions (``opcua_server``).
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path
from typing import Callable

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding

MAX_REJECTED = 100  # a flood of strangers cannot fill the disk
SUFFIXES = (".der", ".pem", ".crt", ".cer")


def fingerprint(cert: x509.Certificate) -> str:
    return hashlib.sha256(cert.public_bytes(Encoding.DER)).hexdigest()


def load_certificate(path: Path) -> x509.Certificate:
    data = Path(path).read_bytes()
    if b"-----BEGIN CERTIFICATE-----" in data:
        return x509.load_pem_x509_certificate(data)
    return x509.load_der_x509_certificate(data)


def _common_name(cert: x509.Certificate) -> str:
    names = cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)
    return str(names[0].value) if names else "unnamed"


class ClientTrustList:
    """asyncua's certificate validator hook (``Server.set_certificate_validator``): the trust folder."""

    def __init__(self, trusted_dir: Path, rejected_dir: Path, log: Callable[[str], None] = lambda s: None):
        self.trusted_dir, self.rejected_dir, self.log = Path(trusted_dir), Path(rejected_dir), log
        self._basic = CertificateValidator(CertificateValidatorOptions.BASIC_VALIDATION
                                           | CertificateValidatorOptions.PEER_CLIENT)
        self._unreadable: set[str] = set()

    def ensure_folders(self) -> None:
        self.trusted_dir.mkdir(parents=True, exist_ok=True)
        self.rejected_dir.mkdir(parents=True, exist_ok=True)

    def trusted(self) -> dict[str, str]:
        """fingerprint -> file name of every readable certificate in the trust folder (read now)."""
        out: dict[str, str] = {}
        for path in sorted(self.trusted_dir.glob("*")):
            if path.suffix.lower() not in SUFFIXES or not path.is_file():
                continue
            try:
                out[fingerprint(load_certificate(path))] = path.name
            except (OSError, ValueError) as exc:
                if str(path) not in self._unreadable:  # said once, not at every session
                    self._unreadable.add(str(path))
                    self.log(f"OPC UA: {path} is not a readable certificate (DER or PEM), ignored: {exc}")
        return out

    async def __call__(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        await self._basic(cert, app)  # validity period, ApplicationUri in the certificate
        fp = fingerprint(cert)
        name = self.trusted().get(fp)
        if name is None:
            where = self._keep_rejected(cert, fp)
            self.log(f"OPC UA: refused a session of client {app.ApplicationUri!r} (certificate "
                     f"{_common_name(cert)!r}, SHA-256 {fp[:16]}...): not in the trust folder {self.trusted_dir}"
                     + (f"; to admit it, move {where} there" if where else ""))
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)

    def _keep_rejected(self, cert: x509.Certificate, fp: str) -> Path | None:
        safe = re.sub(r"[^A-Za-z0-9._-]+", "_", _common_name(cert))[:40]
        path = self.rejected_dir / f"{safe}-{fp[:16]}.der"
        try:
            if not path.exists():
                if sum(1 for _ in self.rejected_dir.glob("*.der")) >= MAX_REJECTED:
                    return None
                self.rejected_dir.mkdir(parents=True, exist_ok=True)
                path.write_bytes(cert.public_bytes(Encoding.DER))
            return path
        except OSError:
            return None
