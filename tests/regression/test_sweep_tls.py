"""Sweeps over TLS to the Dask scheduler, and the checks made before any packet is sent.

A `dask scheduler` and one `dask worker` on 127.0.0.1 with certificates signed by a CA made
here (`cryptography`, the test extra), as docs/guides/sweeps.md tells users to start them; the
client runs a 2-point sweep over `tls://` whose point outputs must equal a local cluster's. A
client without a certificate of that CA is refused in one line. The certificate checks
(missing key, a CA that did not sign the certificate, an expired certificate, a key of another
certificate) and the plaintext rules (warning off loopback, refusal under --require-tls before
any connection) need no scheduler. No test sends a packet to an address other than 127.0.0.1.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import json
import re
import ssl
from pathlib import Path

import pytest

from poevp_optics.apps.sweep import cluster, tls
from poevp_optics.apps.sweep.cluster import ClusterError, connect
from poevp_optics.cli import main

from tests.conftest import ROOT
from tests.regression.test_sweep_cluster import DaskProcesses, _points

x509 = pytest.importorskip("cryptography.x509")
from cryptography.hazmat.primitives import hashes, serialization  # noqa: E402
from cryptography.hazmat.primitives.asymmetric import ec  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID  # noqa: E402

SCENE = "scenes/smoke"
GRID = ["--grid", "mask.target=0.3,0.6"]              # 2 smoke points
NOW = dt.datetime.now(dt.timezone.utc)
DAY = dt.timedelta(days=1)


# ---------------------------------------------------------------------------- certificates
class Pki:
    """A CA and certificates it signs, written as PEM files into `folder` (EC P-256 keys: fast
    to make; Dask and OpenSSL take them as they take RSA)."""

    def __init__(self, folder: Path, name: str = "poevp test CA"):
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)
        self.key = ec.generate_private_key(ec.SECP256R1())
        self.name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
        self.cert = (x509.CertificateBuilder().subject_name(self.name).issuer_name(self.name)
                     .public_key(self.key.public_key()).serial_number(x509.random_serial_number())
                     .not_valid_before(NOW - DAY).not_valid_after(NOW + 30 * DAY)
                     .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
                     .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False),
                                    critical=True)
                     .sign(self.key, hashes.SHA256()))
        self.ca_file = self._write("ca.pem", self.cert.public_bytes(serialization.Encoding.PEM))

    def _write(self, name: str, data: bytes) -> Path:
        path = self.folder / name
        path.write_bytes(data)
        path.chmod(0o600)
        return path

    def issue(self, name: str, *, not_before=None, not_after=None) -> tuple[Path, Path]:
        """(certificate, key) files for `name`, valid for server and client use on 127.0.0.1."""
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
                .issuer_name(self.name).public_key(key.public_key()).serial_number(x509.random_serial_number())
                .not_valid_before(not_before or NOW - DAY).not_valid_after(not_after or NOW + 30 * DAY)
                .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                            x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                               critical=False)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .sign(self.key, hashes.SHA256()))
        key_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                    serialization.NoEncryption())
        return (self._write(f"{name}.pem", cert.public_bytes(serialization.Encoding.PEM)),
                self._write(f"{name}-key.pem", key_pem))


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


def _tls_flags(pki: Pki, cert: Path, key: Path) -> list[str]:
    return ["--tls-ca-file", str(pki.ca_file), "--tls-cert", str(cert), "--tls-key", str(key)]


# ---------------------------------------------------------------------------- a TLS cluster
class TlsDaskProcesses(DaskProcesses):
    """test_sweep_cluster's scheduler and workers, started with TLS flags and a tls:// address."""

    def __init__(self, root: Path, pki: Pki):
        super().__init__(root)
        self.pki = pki
        self.scheduler_cert = pki.issue("scheduler")
        self.worker_cert = pki.issue("worker")

    def start_scheduler(self) -> Path:
        self._start(["scheduler", "--no-dashboard", "--protocol", "tls", "--host", "127.0.0.1", "--port", "0",
                     *self._tls(self.scheduler_cert), "--scheduler-file", str(self.scheduler_file)],
                    "scheduler", ROOT)
        self._wait_file()
        return self.scheduler_file

    def _wait_file(self):
        import time

        t0 = time.time()
        while not self.scheduler_file.is_file():
            assert time.time() - t0 < 60, (self.logs / "scheduler.log").read_text()[-2000:]
            time.sleep(0.1)

    def start_worker(self, name: str, pythonpath: Path = ROOT):
        p = self._start(["worker", "--scheduler-file", str(self.scheduler_file), "--nthreads", "1",
                         "--no-nanny", "--name", name, *self._tls(self.worker_cert)], name, pythonpath)
        self.workers[name] = p
        return p

    def _tls(self, cert_key) -> list[str]:
        return _tls_flags(self.pki, *cert_key)

    @property
    def address(self) -> str:
        return json.loads(self.scheduler_file.read_text())["address"]

    def wait_workers(self, n: int, timeout_s: float = 120) -> None:
        import time

        from distributed import Client, Security

        client = self.pki.issue("waiter")
        sec = Security(tls_ca_file=str(self.pki.ca_file), tls_client_cert=str(client[0]),
                       tls_client_key=str(client[1]), require_encryption=True)
        with Client(self.address, security=sec, timeout=30) as c:
            t0 = time.time()
            while len(c.scheduler_info(n_workers=-1)["workers"]) != n:
                assert time.time() - t0 < timeout_s, f"{n} workers did not connect"
                time.sleep(0.2)


@pytest.fixture
def tls_cluster(tmp_path):
    procs = TlsDaskProcesses(tmp_path / "dask", Pki(tmp_path / "pki"))
    try:
        yield procs
    finally:
        procs.stop()


@pytest.mark.slow
def test_sweep_over_tls_equals_local_and_a_client_without_the_cas_certificate_is_refused(
        tmp_path, monkeypatch, capsys, tls_cluster):
    procs = tls_cluster
    procs.start_scheduler()
    procs.start_worker("w0")
    monkeypatch.chdir(ROOT)
    monkeypatch.delenv(tls.REQUIRE_ENV, raising=False)
    address = procs.address
    assert address.startswith("tls://127.0.0.1:")
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(tmp_path / "local"), "--workers", "1"])
    io = capsys.readouterr()
    assert rc == 0, io.out + io.err
    local = _points(tmp_path / "local")
    assert len(local) == 2
    procs.wait_workers(1)
    client = procs.pki.issue("client")
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(tmp_path / "tls"), "--scheduler", address,
               *_tls_flags(procs.pki, *client), "--require-tls"])
    io = capsys.readouterr()
    assert rc == 0, io.out + io.err
    assert "scene bundle of" in io.out and "warning" not in io.err
    assert _points(tmp_path / "tls") == local
    # through the scheduler file, with the files from Dask's configuration (no flags)
    import dask

    with dask.config.set({"distributed.comm.tls.ca-file": str(procs.pki.ca_file),
                          "distributed.comm.tls.client.cert": str(client[0]),
                          "distributed.comm.tls.client.key": str(client[1])}):
        c, local_cluster = connect(scheduler_file=procs.scheduler_file)
    try:
        assert local_cluster is None and c.scheduler.address == address
        assert c.security.require_encryption and c.security.tls_client_cert == str(client[0])
        assert c.submit(pow, 2, 10, pure=False).result(timeout=60) == 1024
    finally:
        c.close()
    # a certificate from another CA, presented with that CA: the scheduler's certificate does not
    # verify against it (the client refuses the scheduler) ...
    other = Pki(tmp_path / "other", "another CA")
    stranger = other.issue("stranger")
    out = tmp_path / "refused"
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(out), "--scheduler", address,
               *_tls_flags(other, *stranger)])
    err = _one_line_error(capsys)
    assert rc == 2
    assert re.fullmatch(rf"poevp: error: --scheduler {re.escape(address)}: the scheduler's certificate does "
                        rf"not verify against --tls-ca-file {re.escape(str(other.ca_file))} \((self-signed "
                        r"certificate in certificate chain|unable to get local issuer certificate)\); the "
                        r"scheduler must use a certificate that CA signed", err), err
    # ... and with our CA file but the stranger's certificate, the scheduler refuses the client
    # (checked here first: the CA did not sign it)
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(out), "--scheduler", address,
               *_tls_flags(procs.pki, *stranger)])
    err = _one_line_error(capsys)
    assert rc == 2
    assert err.startswith(f"poevp: error: --tls-cert {stranger[0]}: does not verify against --tls-ca-file "
                          f"{procs.pki.ca_file} (unable to get local issuer certificate): the CA did not "
                          "sign it"), err
    # no certificate at all
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(out), "--scheduler", address])
    err = _one_line_error(capsys)
    assert rc == 2 and "TLS needs --tls-ca-file and --tls-cert" in err, err
    assert not out.exists()


def test_scheduler_refuses_a_certificate_the_client_check_cannot_see(tmp_path, capsys, tls_cluster):
    """The scheduler trusts only its own CA; a client whose CA file holds both CAs passes its own
    check (its certificate verifies against that file) and the scheduler then refuses it: one
    line, not a traceback or a 30 s time-out."""
    procs = tls_cluster
    procs.start_scheduler()
    other = Pki(tmp_path / "other", "another CA")
    stranger = other.issue("stranger")
    both = tmp_path / "both-cas.pem"
    both.write_bytes(procs.pki.ca_file.read_bytes() + other.ca_file.read_bytes())
    with pytest.raises(ClusterError) as e:
        connect(scheduler=procs.address, tls_ca_file=str(both), tls_cert=str(stranger[0]),
                tls_key=str(stranger[1]), timeout_s=20)
    msg = str(e.value)
    # the scheduler's alert, or (when its close overtakes the alert) the end of the connection
    refused = (f"--scheduler {procs.address}: the scheduler refused --tls-cert {stranger[0]} (tlsv1 alert "
               f"unknown ca): it trusts another CA than --tls-ca-file {both}")
    closed = re.escape(f"--scheduler {procs.address}: the scheduler closed the connection during TLS set-up (") + \
        r"[^()]*(EOF|reset by peer)[^()]*" + re.escape(f"): it refused --tls-cert {stranger[0]} (a CA it does not trust?) or does "
                                      "not speak TLS on that port")
    assert msg == refused or re.fullmatch(closed, msg), msg


def test_a_local_cluster_talks_tls_when_plaintext_is_refused(monkeypatch):
    """--require-tls with no scheduler: the embedded cluster's scheduler listens on loopback,
    which every user of the machine reaches, so it gets a certificate of its own, in memory."""
    import distributed

    monkeypatch.delenv(tls.REQUIRE_ENV, raising=False)
    client, local = connect(workers=1, n_points=1, require_tls=True)
    try:
        assert local.scheduler_address.startswith("tls://127.0.0.1:")
        assert client.submit(pow, 3, 4, pure=False).result(timeout=60) == 81
    finally:
        client.close()
        local.close()

    def no_cryptography(*a, **k):
        raise ImportError("cryptography")

    monkeypatch.setattr(distributed.Security, "temporary", no_cryptography)
    with pytest.raises(ClusterError, match=r"^--require-tls: the local cluster would talk plaintext .* needs the "
                                           r"cryptography package"):
        connect(workers=1, n_points=1, require_tls=True)


# ---------------------------------------------------------------------------- certificate files
@pytest.fixture
def pki(tmp_path):
    return Pki(tmp_path / "pki")


def _check(ca, cert, key):
    tls.check_tls_files(tls.tls_sources(str(ca), str(cert), str(key) if key else None))


def test_good_files_pass_and_validity_dates_are_read_from_the_certificate(pki):
    cert, key = pki.issue("client", not_before=NOW - 2 * DAY, not_after=NOW + 5 * DAY)
    _check(pki.ca_file, cert, key)
    der = ssl.PEM_cert_to_DER_cert(cert.read_text())
    got = tls.cert_validity(der)
    want = x509.load_pem_x509_certificate(cert.read_bytes())
    assert got == (want.not_valid_before_utc, want.not_valid_after_utc)
    # GeneralizedTime (years from 2050 on, RFC 5280 4.1.2.5) as well as UTCTime
    late, _ = pki.issue("late", not_after=dt.datetime(2051, 3, 4, 5, 6, 7, tzinfo=dt.timezone.utc))
    assert tls.cert_validity(ssl.PEM_cert_to_DER_cert(late.read_text()))[1] == \
        dt.datetime(2051, 3, 4, 5, 6, 7, tzinfo=dt.timezone.utc)


def test_missing_key_file_is_one_line_naming_it(pki):
    cert, key = pki.issue("client")
    key.unlink()
    with pytest.raises(tls.TlsError, match=rf"^--tls-key {re.escape(str(key))}: no such file$"):
        _check(pki.ca_file, cert, key)


def test_a_ca_that_did_not_sign_the_certificate_is_named(pki, tmp_path):
    other = Pki(tmp_path / "other", "another CA")
    cert, key = other.issue("client")
    with pytest.raises(tls.TlsError) as e:
        _check(pki.ca_file, cert, key)
    assert str(e.value).startswith(f"--tls-cert {cert}: does not verify against --tls-ca-file {pki.ca_file} "
                                   "(unable to get local issuer certificate): the CA did not sign it")


def test_an_expired_certificate_is_named_with_its_date(pki):
    end = (NOW - 3 * DAY).replace(microsecond=0)
    cert, key = pki.issue("client", not_before=NOW - 40 * DAY, not_after=end)
    with pytest.raises(tls.TlsError, match=rf"^--tls-cert {re.escape(str(cert))}: its certificate expired on "
                                           rf"{end:%Y-%m-%d %H:%M} UTC$"):
        _check(pki.ca_file, cert, key)
    soon, key2 = pki.issue("future", not_before=NOW + 2 * DAY)
    with pytest.raises(tls.TlsError, match=r"its certificate is not valid before"):
        _check(pki.ca_file, soon, key2)


def test_a_key_of_another_certificate_is_named(pki):
    cert, _ = pki.issue("client")
    _, other_key = pki.issue("other")
    with pytest.raises(tls.TlsError, match=rf"^--tls-key {re.escape(str(other_key))}: not the key of --tls-cert "
                                           rf"{re.escape(str(cert))}"):
        _check(pki.ca_file, cert, other_key)


def test_an_unparseable_ca_file_and_a_passphrase_key_are_named(pki, tmp_path):
    cert, key = pki.issue("client")
    junk = tmp_path / "junk.pem"
    junk.write_text("not a certificate\n")
    with pytest.raises(tls.TlsError, match=rf"^--tls-ca-file {re.escape(str(junk))}: not a PEM CA certificate"):
        _check(junk, cert, key)
    locked = tmp_path / "locked-key.pem"
    loaded = serialization.load_pem_private_key(key.read_bytes(), None)
    locked.write_bytes(loaded.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                            serialization.BestAvailableEncryption(b"secret")))
    with pytest.raises(tls.TlsError, match=rf"^--tls-key {re.escape(str(locked))}: the key is protected by a "
                                           "passphrase"):
        _check(pki.ca_file, cert, locked)


def test_the_cli_prints_a_certificate_problem_as_one_line_before_connecting(pki, tmp_path, monkeypatch, capsys):
    cert, key = pki.issue("client", not_before=NOW - 40 * DAY, not_after=NOW - DAY)
    monkeypatch.setattr("distributed.Client", _no_connection)
    monkeypatch.chdir(ROOT)
    out = tmp_path / "sw"
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(out), "--scheduler", "tls://127.0.0.1:9",
               *_tls_flags(pki, cert, key)])
    err = _one_line_error(capsys)
    assert rc == 2 and err.startswith(f"poevp: error: --tls-cert {cert}: its certificate expired on "), err
    assert not out.exists()


# ---------------------------------------------------------------------------- plaintext
def _no_connection(*args, **kwargs):
    raise AssertionError("a connection was attempted")


@pytest.mark.parametrize("host, loopback", [
    ("127.0.0.1", True), ("127.8.9.10", True), ("[::1]", True), ("localhost", True),
    ("[::ffff:127.0.0.1]", True), ("10.0.0.5", False), ("192.0.2.1", False), ("[2001:db8::1]", False),
    ("sched.example.org", False), ("0.0.0.0", False)])
def test_plaintext_warning_only_off_loopback(host, loopback):
    line = tls.plaintext_warning(f"--scheduler tcp://{host}:8786", f"tcp://{host}:8786")
    assert (line is None) == loopback
    if line:
        assert "\n" not in line and line.startswith("poevp: warning: ")
        assert "run code on every worker" in line and "unencrypted" in line and "--tls-ca-file" in line
    assert tls.plaintext_warning("x", f"tls://{host}:8786") is None


def test_connect_warns_for_a_plaintext_address_off_loopback_and_then_connects(monkeypatch):
    """The warning comes before the connection; the connection itself is replaced (no packet
    leaves this machine)."""
    monkeypatch.delenv(tls.REQUIRE_ENV, raising=False)
    calls, lines = [], []

    def client(address, **kw):
        calls.append((address, kw.get("security"), len(lines)))     # warnings printed so far
        return "client"

    monkeypatch.setattr("distributed.Client", client)
    assert connect(scheduler="tcp://192.0.2.1:8786", warn=lines.append) == ("client", None)
    assert calls == [("tcp://192.0.2.1:8786", None, 1)] and len(lines) == 1
    assert connect(scheduler="tcp://127.0.0.1:8786", warn=lines.append) == ("client", None)
    assert calls[1] == ("tcp://127.0.0.1:8786", None, 1) and len(lines) == 1   # loopback: no warning


@pytest.mark.parametrize("setting", ["flag", "env", "dask"])
def test_refuse_plaintext_before_any_connection(setting, monkeypatch, tmp_path):
    import dask

    monkeypatch.setattr("distributed.Client", _no_connection)
    monkeypatch.delenv(tls.REQUIRE_ENV, raising=False)
    if setting == "env":
        monkeypatch.setenv(tls.REQUIRE_ENV, "1")
    with dask.config.set({"distributed.comm.require-encryption": setting == "dask"}):
        with pytest.raises(ClusterError, match=r"^--scheduler tcp://192\.0\.2\.1:8786: plaintext connection "
                                               r"refused \((--require-tls|POEVP_REQUIRE_TLS=1|"
                                               r"distributed\.comm\.require-encryption)\)"):
            connect(scheduler="tcp://192.0.2.1:8786", require_tls=setting == "flag")
        sf = tmp_path / "sched.json"
        sf.write_text(json.dumps({"address": "tcp://127.0.0.1:8786"}))
        with pytest.raises(ClusterError, match=r"^--scheduler-file .*: plaintext connection refused"):
            connect(scheduler_file=sf, require_tls=setting == "flag")


def test_cli_refuses_plaintext_with_require_tls_and_a_bad_env_value(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr("distributed.Client", _no_connection)
    monkeypatch.delenv(tls.REQUIRE_ENV, raising=False)
    monkeypatch.chdir(ROOT)
    out = tmp_path / "sw"
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(out), "--scheduler", "tcp://192.0.2.1:8786",
               "--require-tls"])
    err = _one_line_error(capsys)
    assert rc == 2 and err.startswith("poevp: error: --scheduler tcp://192.0.2.1:8786: plaintext connection "
                                      "refused (--require-tls)"), err
    monkeypatch.setenv(tls.REQUIRE_ENV, "maybe")
    rc = main(["sweep", SCENE, *GRID, "--quiet", "--out", str(out), "--scheduler", "tcp://192.0.2.1:8786"])
    err = _one_line_error(capsys)
    assert rc == 2 and err == "poevp: error: POEVP_REQUIRE_TLS=maybe: expected 1 (refuse plaintext schedulers) or 0"
    assert not out.exists()


def test_tls_flags_with_a_plaintext_address_or_a_local_cluster_are_refused(monkeypatch, pki):
    monkeypatch.setattr("distributed.Client", _no_connection)
    cert, key = pki.issue("client")
    with pytest.raises(ClusterError, match=r"a plaintext address, but --tls-ca-file is given"):
        connect(scheduler="tcp://127.0.0.1:8786", tls_ca_file=str(pki.ca_file), tls_cert=str(cert))
    with pytest.raises(ClusterError, match=r"^--tls-cert: only with --scheduler or --scheduler-file"):
        cluster.check_local_flags(None, str(cert), None)
