"""The network face: TLS with client certificates and access control, passed to Zenoh through
``[zenoh] config_file``, against a real ``stereod run`` on loopback; and what the bus learns
about the machine (no paths, nothing from the Zenoh file).

Certificates are made for each test run (a CA, the daemon, a trusted consumer, an operator and
an intruder whose certificate the same CA signed); no key is ever committed."""

from __future__ import annotations

import datetime
import ipaddress
import json
import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from stereod.client import query_config, wait_alive
from stereod.vision.calibration import canonical, save

from .conftest import free_endpoint
from .processes import start_stereod
from .sockets import process_sockets

pytestmark = pytest.mark.slow


def _name(cn: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])


def make_pki(d: Path, names: list[str]) -> None:
    """``ca.pem`` and, for each name, ``<name>.pem`` and ``<name>.key`` (CN = name, valid for
    localhost and 127.0.0.1), signed by that CA; keys are EC P-256, valid for a day."""
    now = datetime.datetime.now(datetime.timezone.utc)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(_name("stereod test CA"))
        .issuer_name(_name("stereod test CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(ca_key, hashes.SHA256())
    )
    (d / "ca.pem").write_bytes(ca.public_bytes(serialization.Encoding.PEM))
    san = x509.SubjectAlternativeName(
        [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
    )
    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (
            x509.CertificateBuilder()
            .subject_name(_name(name))
            .issuer_name(ca.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(san, critical=False)
            .sign(ca_key, hashes.SHA256())
        )
        (d / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        (d / f"{name}.key").write_bytes(
            key.private_bytes(
                serialization.Encoding.PEM,
                serialization.PrivateFormat.PKCS8,
                serialization.NoEncryption(),
            )
        )


READ = ["declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"]
SERVE = ["put", "delete", "reply", "liveliness_token"]


def daemon_zenoh_file(d: Path, endpoint: str) -> Path:
    """The daemon's Zenoh file: listen on TLS, clients must show a certificate of our CA, and
    an ACL: consumers may subscribe and query under stereod/**, operators may also publish
    there, anyone else nothing."""
    everything = [*READ, *SERVE, "declare_queryable"]
    conf = {
        "mode": "peer",
        "listen": {"endpoints": [endpoint]},
        "scouting": {"multicast": {"enabled": False}, "delay": 0},
        "transport": {
            "link": {
                "tls": {
                    "root_ca_certificate": str(d / "ca.pem"),
                    "listen_private_key": str(d / "stereod.key"),
                    "listen_certificate": str(d / "stereod.pem"),
                    "enable_mtls": True,
                }
            }
        },
        "access_control": {
            "enabled": True,
            "default_permission": "deny",
            "rules": [
                {
                    "id": "read",
                    "messages": READ,
                    "flows": ["ingress"],
                    "permission": "allow",
                    "key_exprs": ["stereod/**"],
                },
                {
                    "id": "serve",
                    "messages": SERVE,
                    "flows": ["egress"],
                    "permission": "allow",
                    "key_exprs": ["stereod/**"],
                },
                {
                    "id": "operate",
                    "messages": everything,
                    "flows": ["ingress", "egress"],
                    "permission": "allow",
                    "key_exprs": ["stereod/**"],
                },
            ],
            "subjects": [
                {"id": "consumers", "cert_common_names": ["consumer"]},
                {"id": "operators", "cert_common_names": ["operator"]},
            ],
            "policies": [
                {"rules": ["read", "serve"], "subjects": ["consumers"]},
                {"rules": ["operate"], "subjects": ["operators"]},
            ],
        },
    }
    path = d / "zenoh.json5"
    path.write_text(json.dumps(conf, indent=1))
    return path


def client(d: Path, endpoint: str, name: str | None) -> zenoh.Config:
    """A client session's config: TLS to ``endpoint``, with ``name``'s certificate if any."""
    tls: dict[str, object] = {"root_ca_certificate": str(d / "ca.pem")}
    if name is not None:
        tls |= {
            "enable_mtls": True,
            "connect_private_key": str(d / f"{name}.key"),
            "connect_certificate": str(d / f"{name}.pem"),
        }
    conf = {
        "mode": "client",
        "connect": {"endpoints": [endpoint], "timeout_ms": 3000},
        "scouting": {"multicast": {"enabled": False}, "delay": 0},
        "transport": {"link": {"tls": tls}},
    }
    return zenoh.Config.from_json5(json.dumps(conf))


def listening_on(pid: int, port: int) -> bool:
    """Whether process ``pid`` listens on TCP ``port`` (its session is open)."""
    return any(s.listening and s.port == port for s in process_sockets(pid))


def wait(pred: Callable[[], bool], timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.05)
    return pred()


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, str]]:
    """A running ``stereod run`` behind TLS, mTLS and the ACL above; (folder, endpoint)."""
    tmp_path = tmp_path_factory.mktemp("secured")
    make_pki(tmp_path, ["stereod", "consumer", "operator", "intruder"])
    endpoint = free_endpoint().replace("tcp/127.0.0.1", "tls/localhost")
    zfile = daemon_zenoh_file(tmp_path, endpoint)
    save(canonical(0.06, 60.0, 160, 120), tmp_path / "minoru-cal.json")
    cfg = tmp_path / "stereod.toml"
    cfg.write_text(
        f'[rig]\ncalibration = "{tmp_path}/minoru-cal.json"\n'
        '[driver]\nname = "synthetic"\n[driver.options]\nlive = true\nloop = true\n'
        "width_px = 160\nheight_px = 120\nfps = 15\n"
        f'[zenoh]\nconfig_file = "{zfile}"\n[daemon]\nstatus_period_s = 0.5\n'
    )
    proc = start_stereod("run", "--config", str(cfg), cwd=tmp_path)
    try:
        port = int(endpoint.rsplit(":", 1)[1])
        up = wait(lambda: proc.poll() is not None or listening_on(proc.pid, port), timeout=60)
        assert up and proc.poll() is None, "the daemon did not listen"
        yield tmp_path, endpoint
        assert proc.poll() is None, proc.communicate(timeout=10)[1]
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err


def test_a_client_without_a_certificate_cannot_connect(secured: tuple[Path, str]) -> None:
    d, endpoint = secured
    with zenoh.open(client(d, endpoint, "consumer")) as s:  # the control: a certificate works
        assert wait_alive(s, rig="minoru", timeout_s=20)
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(client(d, endpoint, None))


def test_the_acl_denies_a_foreign_client_publishing_and_querying(
    secured: tuple[Path, str],
) -> None:
    d, endpoint = secured
    with zenoh.open(client(d, endpoint, "consumer")) as consumer:
        assert wait_alive(consumer, rig="minoru", timeout_s=20)
        got: list[tuple[str, bytes]] = []
        consumer.declare_subscriber(
            "stereod/minoru/**", lambda s: got.append((str(s.key_expr), s.payload.to_bytes()))
        )
        assert wait(lambda: any(k == "stereod/minoru/status" for k, _ in got))
        assert query_config(consumer, rig="minoru")["rig"]["name"] == "minoru"
        for name, allowed in (("operator", True), ("intruder", False)):
            with zenoh.open(client(d, endpoint, name)) as other:
                time.sleep(0.5)  # its declarations reach the daemon
                forged = f"forged by {name}".encode()
                other.put("stereod/minoru/objects", forged)
                replies = list(other.get("stereod/minoru/config", timeout=3.0))
                answered = [r for r in replies if r.ok is not None]
                arrived = wait(lambda f=forged: any(p == f for _, p in got), 3.0)
                assert arrived == allowed, f"{name}: a put into stereod/minoru/** {arrived=}"
                assert bool(answered) == allowed, f"{name}: config query answered={answered}"
                received: list[bytes] = []
                other.declare_subscriber(
                    "stereod/minoru/status", lambda s, r=received: r.append(s.payload.to_bytes())
                )
                assert wait(lambda r=received: bool(r), 3.0) == allowed, name


def test_the_bus_learns_no_paths_and_nothing_from_the_zenoh_file(
    secured: tuple[Path, str],
) -> None:
    d, endpoint = secured
    with zenoh.open(client(d, endpoint, "consumer")) as s:
        assert wait_alive(s, rig="minoru", timeout_s=20)
        statuses: list[dict] = []
        s.declare_subscriber(
            "stereod/minoru/status", lambda m: statuses.append(json.loads(m.payload.to_bytes()))
        )
        cfg = query_config(s, rig="minoru")
        calibration = [r.ok.payload.to_bytes() for r in s.get("stereod/minoru/calibration")]
        assert wait(lambda: len(statuses) >= 2)
    text = json.dumps(cfg) + json.dumps(statuses) + b"".join(calibration).decode()
    assert str(d) not in text, "a path of the machine on the bus"
    for secret in ("stereod.key", "ca.pem", "BEGIN", "access_control", "tls"):
        assert secret not in text, f"{secret!r} on the bus"
    assert cfg["zenoh"]["config_file"] == "zenoh.json5"
    assert cfg["rig"]["calibration"] == "minoru-cal.json"


def test_the_readme_zenoh_file_is_one_zenoh_accepts() -> None:
    """The Deployment page's example of a secured Zenoh file parses with the installed Zenoh,
    and its ACL has the shape the tests above run (read and serve for listed certificate
    names)."""
    text = (Path(__file__).resolve().parent.parent / "docs" / "deployment.md").read_text()
    block = re.search(r"```json5\n(.*?)```", text, re.S)
    assert block, "no json5 block in docs/deployment.md"
    zenoh.Config.from_json5(block.group(1))
    for word in ('default_permission: "deny"', "enable_mtls: true", "cert_common_names"):
        assert word in block.group(1)


DOCS = Path(__file__).resolve().parent.parent / "docs"


def docs_json5(page: str, marker: str, paths: dict[str, Path]) -> str:
    """The json5 block of ``docs/<page>`` that holds ``marker``, its paths replaced by
    ``paths`` (each documented path to a file of this test's PKI)."""
    blocks = re.findall(r"```json5\n(.*?)```", (DOCS / page).read_text(), re.S)
    block = next(b for b in blocks if marker in b)
    for documented, here in paths.items():
        assert documented in block, f"{documented} not in {page}'s block"
        block = block.replace(documented, str(here))
    return block


def client_block(d: Path, page: str, name: str) -> str:
    """The JSON5 block of docs page ``page`` whose certificate is ``<name>.pem``, its CA,
    certificate and key those of this test's consumer in ``d``."""
    return docs_json5(
        page,
        f"{name}.pem",
        {
            "/etc/stereod/tls/ca.pem": d / "ca.pem",
            f"/etc/stereod/tls/{name}.pem": d / "consumer.pem",
            f"/etc/stereod/tls/{name}.key": d / "consumer.key",
        },
    )


def test_the_documented_consumer_file_reaches_the_secured_daemon(
    secured: tuple[Path, str], tmp_path: Path
) -> None:
    """The Deployment page's consumer file, its paths this test's, lets `stereod subscribe
    --zenoh-config` and `client.zenoh_config(config_file=...)` read the daemon behind mTLS;
    the same file without ``enable_mtls`` is refused the link (the page says why it is
    there)."""
    d, endpoint = secured
    block = client_block(d, "deployment.md", "dashboard")
    good = tmp_path / "dashboard.json5"
    good.write_text(block)
    proc = start_stereod(
        "subscribe", "stereod/minoru/status", "--json", "--count", "1", "--duration", "30",
        "--connect", endpoint, "--zenoh-config", str(good),
    )  # fmt: skip
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert json.loads(out.splitlines()[0])["state"] == "running"
    from stereod.client import zenoh_config

    with zenoh.open(zenoh_config(endpoint, config_file=good)) as s:
        assert wait_alive(s, rig="minoru", timeout_s=20)
    without = tmp_path / "no-mtls.json5"
    without.write_text(re.sub(r"enable_mtls: true,?", "", block))
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(zenoh_config(endpoint, config_file=without))


def test_the_documented_rig_file_presents_its_certificate(
    secured: tuple[Path, str], tmp_path: Path
) -> None:
    """The three-host page's rig file (the client side of the TLS link to the router), its
    paths this test's, connects to a listener that requires a client certificate."""
    d, endpoint = secured
    block = client_block(d, "deployment-room.md", "rig-a")
    f = tmp_path / "rig.json5"
    f.write_text(block)
    from stereod.client import zenoh_config

    with zenoh.open(zenoh_config(endpoint, config_file=f)) as s:
        assert wait_alive(s, rig="minoru", timeout_s=20)
