"""Who may talk to the sweep's Dask scheduler: TLS settings, checked before the first packet.

A Dask scheduler runs whatever its clients submit, on every worker, and a sweep's scene bundle
and point outputs travel through it. Over a plaintext `tcp://` address anyone who reaches the
port can do both; over `tls://` both ends present certificates signed by the cluster's CA
(Dask's `Security`: https://distributed.dask.org/en/stable/tls.html).

* `address_transport`: the scheme and host of a scheduler address; `is_loopback` (127.0.0.0/8,
  ::1, localhost) and `plaintext_warning` (one line for a plaintext address that is not).
* `tls_required`: whether plaintext is refused outright: `--require-tls` (also spelled
  `--require-encryption`, Dask's name), `POEVP_REQUIRE_TLS=1`, or Dask's
  `distributed.comm.require-encryption`.
* `tls_sources`: the CA, certificate and key each from its flag or else from Dask's
  configuration (`distributed.comm.tls.ca-file`, `.client.cert`, `.client.key`), named by
  where it came from; `check_tls_files` reads and parses them (one line naming the file for a
  missing or unreadable file, a certificate outside its validity dates, a key that is not the
  certificate's, a certificate the CA did not sign); `client_security` builds the Security.
* `tls_connect_error`: the one line for a TLS failure while connecting (the scheduler's
  certificate not signed by our CA, our certificate refused by the scheduler).

Only the standard library's `ssl` (OpenSSL) is used: the validity dates are read from the
certificate's DER encoding (`cert_validity`), the CA check is an in-memory TLS handshake in
which a server context built as Dask's scheduler builds its own verifies our certificate.
"""

from __future__ import annotations

import ipaddress
import os
import re
import ssl
import tempfile
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

#: Dask address schemes whose traffic is encrypted (distributed.comm: TLS over TCP, websockets).
ENCRYPTED_SCHEMES = frozenset({"tls", "wss"})
#: Schemes that never leave the process.
IN_PROCESS_SCHEMES = frozenset({"inproc"})
#: The client's TLS flags and the Dask configuration keys read when a flag is not given
#: (distributed/distributed.yaml `comm.tls`; Security._set_field reads the same keys).
CONFIG_KEYS = {"--tls-ca-file": "distributed.comm.tls.ca-file",
               "--tls-cert": "distributed.comm.tls.client.cert",
               "--tls-key": "distributed.comm.tls.client.key"}
#: The environment variable that refuses plaintext like --require-tls.
REQUIRE_ENV = "POEVP_REQUIRE_TLS"
_TRUE, _FALSE = ("1", "true", "yes", "on"), ("", "0", "false", "no", "off")


class TlsError(ValueError):
    """A TLS setting or file that cannot work; one line naming the flag (or key) and the file.
    cluster.py raises it as ClusterError."""


# ---------------------------------------------------------------------------- transport
def address_transport(address: str) -> tuple[str, str]:
    """(scheme, host) of a Dask address, e.g. ('tls', '10.0.0.5'); a bare HOST:PORT takes
    Dask's default scheme (`distributed.comm.default-scheme`, tcp). ValueError if malformed."""
    from distributed.comm.addressing import parse_address, parse_host_port

    scheme, loc = parse_address(str(address))
    if scheme in IN_PROCESS_SCHEMES:
        return scheme, ""
    host, _port = parse_host_port(loc, default_port=8786)
    if not host:
        raise ValueError(f"no host in {address!r}")
    return scheme, host


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 (also IPv4-mapped ::ffff:127.x.y.z) and the name localhost,
    which reach only this machine."""
    name = host.strip("[]").lower().rstrip(".")
    if name == "localhost" or name.endswith(".localhost"):   # RFC 6761 6.3: always loopback
        return True
    try:
        ip = ipaddress.ip_address(name.split("%")[0])
    except ValueError:
        return False
    mapped = getattr(ip, "ipv4_mapped", None)
    return ip.is_loopback or bool(mapped and mapped.is_loopback)


def plaintext_warning(where: str, address: str) -> str | None:
    """The one-line warning for a plaintext scheduler address that leaves this machine, else None.
    `where` names the flag, e.g. '--scheduler tcp://10.0.0.5:8786'."""
    scheme, host = address_transport(address)
    if scheme in ENCRYPTED_SCHEMES or scheme in IN_PROCESS_SCHEMES or is_loopback(host):
        return None
    return (f"poevp: warning: {where} is plaintext ({scheme}://): anyone who reaches that port can run "
            "code on every worker and read the sweep's outputs, and the scene bundle travels "
            "unencrypted; on a shared network use a tls:// scheduler with --tls-ca-file, --tls-cert "
            f"and --tls-key (--require-tls or {REQUIRE_ENV}=1 refuses plaintext)")


def tls_required(flag: bool = False) -> str | None:
    """What refuses plaintext, as the setting's name, or None: the flag (`--require-tls`),
    POEVP_REQUIRE_TLS=1 (also true/yes/on; 0/false/no/off or empty: not set), or Dask's
    `distributed.comm.require-encryption`. TlsError for another value of the variable."""
    import dask

    if flag:
        return "--require-tls"
    env = os.environ.get(REQUIRE_ENV)
    if env is not None:
        value = env.strip().lower()
        if value in _TRUE:
            return f"{REQUIRE_ENV}={env}"
        if value not in _FALSE:
            raise TlsError(f"{REQUIRE_ENV}={env}: expected 1 (refuse plaintext schedulers) or 0")
    if dask.config.get("distributed.comm.require-encryption", None):
        return "distributed.comm.require-encryption"
    return None


# ---------------------------------------------------------------------------- files
def tls_sources(ca_file: str | None, cert: str | None, key: str | None) -> dict[str, tuple[str, str]]:
    """{flag: (name, value)} for the CA, certificate and key that are set: a flag's value as
    given ('--tls-cert'), else Dask's configuration key. A value holding a newline is inline PEM
    (as Dask's configuration allows)."""
    import dask

    out = {}
    for flag, value in (("--tls-ca-file", ca_file), ("--tls-cert", cert), ("--tls-key", key)):
        if value:
            out[flag] = (flag, str(value))
        else:
            conf = dask.config.get(CONFIG_KEYS[flag], None)
            if conf:
                out[flag] = (CONFIG_KEYS[flag], str(conf))
    return out


def _der_element(der: bytes, i: int) -> tuple[int, int, int]:
    """(tag, start, end) of the content of the DER element at offset i (ITU-T X.690 8.1)."""
    tag, n = der[i], der[i + 1]
    i += 2
    if n & 0x80:
        k = n & 0x7F
        n = int.from_bytes(der[i:i + k], "big")
        i += k
    if i + n > len(der):
        raise ValueError("truncated DER element")
    return tag, i, i + n


def _der_children(der: bytes, start: int, end: int) -> list[tuple[int, int, int]]:
    out, i = [], start
    while i < end:
        el = _der_element(der, i)
        out.append(el)
        i = el[2]
    return out


def _der_time(der: bytes, tag: int, start: int, end: int) -> datetime:
    """UTCTime (tag 0x17, YYMMDDHHMMSSZ; YY >= 50 is 19YY, RFC 5280 4.1.2.5.1) or
    GeneralizedTime (0x18, YYYYMMDDHHMMSSZ) as an aware UTC datetime."""
    text = der[start:end].decode("ascii")
    if tag == 0x17:
        yy = int(text[:2])
        text = f"{1900 + yy if yy >= 50 else 2000 + yy}{text[2:]}"
    elif tag != 0x18:
        raise ValueError(f"validity time of tag {tag:#x}")
    return datetime.strptime(text, "%Y%m%d%H%M%SZ").replace(tzinfo=timezone.utc)


def cert_validity(der: bytes) -> tuple[datetime, datetime]:
    """(notBefore, notAfter) in UTC of a DER X.509 certificate (RFC 5280 4.1: Certificate ->
    tbsCertificate -> [version], serialNumber, signature, issuer, validity). ValueError if the
    bytes are not one."""
    try:
        tag, start, end = _der_element(der, 0)                 # Certificate SEQUENCE
        tag_tbs, start, end = _der_element(der, start)         # tbsCertificate SEQUENCE
        if tag != 0x30 or tag_tbs != 0x30:
            raise ValueError("not a SEQUENCE")
        fields = _der_children(der, start, end)
        if fields[0][0] == 0xA0:                               # [0] EXPLICIT version
            fields = fields[1:]
        tag, start, end = fields[3]                            # validity SEQUENCE
        times = _der_children(der, start, end)
        return _der_time(der, *times[0]), _der_time(der, *times[1])
    except (IndexError, UnicodeDecodeError) as e:
        raise ValueError(str(e)) from None


def pem_certificates(text: str) -> list[bytes]:
    """The DER bytes of every CERTIFICATE block in PEM text."""
    begin, end = "-----BEGIN CERTIFICATE-----", "-----END CERTIFICATE-----"
    out, i = [], 0
    while (i := text.find(begin, i)) >= 0:
        j = text.find(end, i)
        if j < 0:
            raise ValueError("a certificate block has no END line")
        out.append(ssl.PEM_cert_to_DER_cert(text[i:j + len(end)]))
        i = j + len(end)
    return out


@contextmanager
def _as_files(sources: dict[str, tuple[str, str]]):
    """{flag: path}: file values as they are, inline PEM written to a temporary folder (removed
    on exit), as Dask's Security does."""
    with tempfile.TemporaryDirectory(prefix="poevp-tls-") as tmp:
        paths = {}
        for flag, (_name, value) in sources.items():
            if "\n" in value:
                paths[flag] = os.path.join(tmp, flag.strip("-") + ".pem")
                with open(paths[flag], "w") as f:
                    f.write(value)
            else:
                paths[flag] = os.path.expanduser(value)
        yield paths


def _label(name: str, value: str) -> str:
    return f"{name} (inline PEM)" if "\n" in value else f"{name} {value}"


def check_tls_files(sources: dict[str, tuple[str, str]], *, now: datetime | None = None) -> None:
    """Every TLS file can serve a connection to a scheduler that trusts the same CA; else
    TlsError naming the flag (or configuration key) and the file. In order: each file exists
    and reads; the CA file parses; every certificate in the certificate file is inside its
    validity dates at `now` (default: the clock, UTC); the key is the certificate's (and not
    passphrase-protected: Dask cannot ask for one); the CA signed the certificate, verified as
    the scheduler verifies a client (purpose client, no hostname, Dask's flags)."""
    now = now or datetime.now(timezone.utc)
    labels = {flag: _label(*src) for flag, src in sources.items()}
    for flag, (_name, value) in sources.items():
        if "\n" in value:
            continue
        path = Path(value).expanduser()
        if not path.is_file():
            raise TlsError(f"{labels[flag]}: no such file")
        try:
            with open(path, "rb") as f:
                f.read(1)
        except OSError as e:
            raise TlsError(f"{labels[flag]}: cannot read it ({e.strerror or e})") from None
    with _as_files(sources) as paths:
        ca, cert, key = paths["--tls-ca-file"], paths["--tls-cert"], paths.get("--tls-key")
        try:
            ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_verify_locations(cafile=ca)
        except (ssl.SSLError, ValueError) as e:
            raise TlsError(f"{labels['--tls-ca-file']}: not a PEM CA certificate ({_reason(e)})") from None
        try:
            chain = pem_certificates(Path(cert).read_text(errors="replace"))
            if not chain:
                raise ValueError("no BEGIN CERTIFICATE block")
            dates = [cert_validity(der) for der in chain]
        except ValueError as e:
            raise TlsError(f"{labels['--tls-cert']}: not a PEM certificate ({e})") from None
        for n, (not_before, not_after) in enumerate(dates):
            which = "its certificate" if n == 0 else f"certificate {n + 1} in it"
            if now > not_after:
                raise TlsError(f"{labels['--tls-cert']}: {which} expired on {not_after:%Y-%m-%d %H:%M} UTC")
            if now < not_before:
                raise TlsError(f"{labels['--tls-cert']}: {which} is not valid before "
                               f"{not_before:%Y-%m-%d %H:%M} UTC")
        server = _client_verifier(ca, cert, key, labels)
        client = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
        client.check_hostname, client.verify_mode = False, ssl.CERT_NONE
        client.load_cert_chain(cert, key)
        try:
            _handshake(client, server)
        except ssl.SSLCertVerificationError as e:
            if e.verify_code in (9, 10):   # not yet valid / expired, and the chain's dates passed
                raise TlsError(f"{labels['--tls-ca-file']}: the CA certificate is outside its validity "
                               f"dates ({e.verify_message})") from None
            raise TlsError(f"{labels['--tls-cert']}: does not verify against {labels['--tls-ca-file']} "
                           f"({e.verify_message}){_verify_hint(e)}") from None
        except ssl.SSLError as e:
            raise TlsError(f"{labels['--tls-cert']}: a TLS handshake with it fails here "
                           f"({_reason(e)})") from None


def _client_verifier(ca: str, cert: str, key: str | None, labels: dict) -> ssl.SSLContext:
    """A server context as Dask's scheduler builds one (Security._get_tls_context with
    Purpose.CLIENT_AUTH: the CA, CERT_REQUIRED, no X509_STRICT), presenting our own
    certificate; TlsError when the key does not load or is not the certificate's."""
    asked = []
    key_label = labels.get("--tls-key", labels["--tls-cert"])

    def password():
        asked.append(True)
        return b""

    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH, cafile=ca)
    ctx.verify_mode = ssl.CERT_REQUIRED
    ctx.verify_flags &= ~getattr(ssl, "VERIFY_X509_STRICT", 0)
    try:
        ctx.load_cert_chain(cert, key, password=password)
    except ssl.SSLError as e:
        if asked:
            raise TlsError(f"{key_label}: the key is protected by a passphrase, which Dask cannot ask "
                           "for; give an unencrypted key (openssl pkey -in KEY -out KEY.plain), "
                           "readable by you alone") from None
        if "KEY_VALUES_MISMATCH" in str(e):
            raise TlsError(f"{key_label}: not the key of {labels['--tls-cert']} (key values "
                           "mismatch)") from None
        if key is None:
            raise TlsError(f"{key_label}: holds no private key; give the key file as --tls-key") from None
        raise TlsError(f"{key_label}: not a PEM private key for the certificate ({_reason(e)})") from None
    return ctx


def _handshake(client: ssl.SSLContext, server: ssl.SSLContext) -> None:
    """A TLS handshake between two contexts through memory buffers (no socket); raises what
    either side raises."""
    c_in, c_out, s_in, s_out = (ssl.MemoryBIO() for _ in range(4))
    c = client.wrap_bio(c_in, c_out, server_side=False)
    s = server.wrap_bio(s_in, s_out, server_side=True)
    done = [False, False]
    for _ in range(20):                    # TLS 1.2 and 1.3 finish in under 5 round trips
        for n, (obj, out, peer_in) in enumerate(((c, c_out, s_in), (s, s_out, c_in))):
            if not done[n]:
                try:
                    obj.do_handshake()
                    done[n] = True
                except ssl.SSLWantReadError:
                    pass
            data = out.read()
            if data:
                peer_in.write(data)
        if all(done):                      # the server verified the client's certificate
            return
    raise ssl.SSLError("the handshake did not finish")


def _verify_hint(e: ssl.SSLCertVerificationError) -> str:
    """Which file to look at for an OpenSSL verify code (openssl-verify(1) ERRORS)."""
    if e.verify_code in (2, 18, 19, 20, 21):    # issuer not found / self-signed / leaf signature
        return ": the CA did not sign it, so the scheduler would refuse it"
    if e.verify_code == 26:                    # unsupported certificate purpose
        return ": its extendedKeyUsage lacks clientAuth"
    return ""


def _reason(e: BaseException | str) -> str:
    """An ssl error's text without the '[SSL: CODE]' prefix and '(_ssl.c:N)' suffix, e.g.
    'tlsv1 alert unknown ca'; OpenSSL's reason code when nothing else is left."""
    text = " ".join(str(e).split())
    m = re.search(r"([^()\[\]]+?) \(_ssl\.c:\d+\)", text)
    return (m.group(1) if m else text).rsplit(": ", 1)[-1].strip() or getattr(e, "reason", None) or "TLS error"


def client_security(sources: dict[str, tuple[str, str]]):
    """distributed.Security for a client over TLS with these files (`require_encryption`: every
    connection this client opens must be TLS)."""
    from distributed import Security

    kw = {"tls_ca_file": sources["--tls-ca-file"][1], "tls_client_cert": sources["--tls-cert"][1]}
    if "--tls-key" in sources:
        kw["tls_client_key"] = sources["--tls-key"][1]
    try:
        return Security(require_encryption=True, **kw)
    except (ValueError, TypeError) as e:
        raise TlsError(f"the Dask TLS configuration: {' '.join(str(e).split())}") from None


# ---------------------------------------------------------------------------- at connect
def tls_connect_error(exc: BaseException, where: str, sources: dict[str, tuple[str, str]]) -> str | None:
    """The one line for a TLS failure inside `exc` (its cause and context chain), else None:
    the scheduler's certificate not verified by our CA, or the scheduler refusing ours."""
    seen, e = set(), exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, ssl.SSLError):
            break
        e = e.__cause__ or e.__context__
    else:
        e = None
    labels = {flag: _label(*src) for flag, src in sources.items()}
    ca, cert = labels.get("--tls-ca-file", "the CA"), labels.get("--tls-cert", "the certificate")
    if isinstance(e, ssl.SSLCertVerificationError):
        return (f"{where}: the scheduler's certificate does not verify against {ca} "
                f"({e.verify_message}); the scheduler must use a certificate that CA signed")
    text = str(e if e is not None else exc)      # Dask passes some only as text (comm/tcp.py)
    upper = text.upper()
    if "ALERT" in upper and "UNKNOWN_CA" in upper:
        return f"{where}: the scheduler refused {cert} ({_reason(text)}): it trusts another CA than {ca}"
    if "ALERT" in upper and "CERTIFICATE" in upper:
        return f"{where}: the scheduler refused {cert} ({_reason(text)})"
    # the scheduler's alert lost when its close overtook it: an EOF, or a reset (data of ours unread)
    if isinstance(e, ssl.SSLEOFError) or "EOF" in upper or "RESET BY PEER" in upper:
        return (f"{where}: the scheduler closed the connection during TLS set-up ({_reason(text)}): it "
                f"refused {cert} (a CA it does not trust?) or does not speak TLS on that port")
    if e is not None:
        return f"{where}: TLS with the scheduler failed ({_reason(e)}); is it a tls:// scheduler?"
    return None
