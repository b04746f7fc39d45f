"""The guide's zenoh configs (docs/machines.md) are valid zenoh 1.x configs, and its TLS ones restrict access as it says.

The TLS check makes a throwaway CA and certificates with the ``openssl`` command (skipped without
it), opens the guide's router config (mTLS, access control) in this process on a free loopback
port and the guide's robot config as clients of it: the robot's certificate gets zenslam's keys
through, a key outside the session does not, a certificate of the same CA whose name no policy
lists gets nothing through, and a client without a certificate cannot connect.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from test_docs import doc_block

from zenslam.runtime import bus

CONFIG_NAMES = ("router.json5", "server.json5", "robot.json5", "router_tls.json5", "robot_tls.json5")


def readme_json5(name: str) -> str:
    """The zenoh config block named ``name`` (docs/machines.md)."""
    return doc_block("json5", name)


@pytest.mark.parametrize("name", CONFIG_NAMES)
def test_readme_zenoh_configs_are_valid(name: str):
    config = zenoh.Config.from_json5(readme_json5(name))
    assert config.get_json("mode").strip('"') in ("router", "client")


def _make_certificates(folder: Path) -> None:
    """ca.pem, and <name>.pem / <name>-key.pem signed by it for the router, robot1 and an intruder."""

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=folder, check=True, capture_output=True, timeout=60)

    curve = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
    openssl("req", "-x509", *curve, "-keyout", "ca-key.pem", "-out", "ca.pem", "-days", "2", "-subj", "/CN=zenslam-test-ca")
    for name in ("router", "robot1", "intruder"):
        (folder / f"{name}.cnf").write_text(
            "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
            "keyUsage=digitalSignature,keyEncipherment\nextendedKeyUsage=serverAuth,clientAuth\n"
        )
        openssl("req", *curve, "-keyout", f"{name}-key.pem", "-out", f"{name}.csr", "-subj", f"/CN={name}")
        openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem", "-CAcreateserial",
                "-out", f"{name}.pem", "-days", "2", "-extfile", f"{name}.cnf")  # fmt: skip


def _with_paths(config: str, folder: Path) -> str:
    """``config`` with its certificate file names made absolute in ``folder``."""
    return re.sub(r'"([\w-]+\.pem)"', lambda m: f'"{folder / m.group(1)}"', config)


@contextmanager
def _open(config: str) -> Iterator[zenoh.Session]:
    session = zenoh.open(zenoh.Config.from_json5(config))
    try:
        yield session
    finally:
        session.close()


@pytest.mark.skipif(shutil.which("openssl") is None, reason="the openssl command makes the test certificates")
def test_readme_tls_configs_admit_only_the_listed_certificates_and_keys(tmp_path: Path):
    _make_certificates(tmp_path)
    host, port = bus.free_tcp_endpoint().removeprefix("tcp/").split(":")
    router = _with_paths(readme_json5("router_tls.json5"), tmp_path).replace("tls/0.0.0.0:7447", f"tls/{host}:{port}")
    robot = _with_paths(readme_json5("robot_tls.json5"), tmp_path).replace("tls/zenslam-router:7447", f"tls/localhost:{port}")
    intruder = robot.replace("robot1", "intruder")
    without_certificate = re.sub(r"\s*connect_(certificate|private_key):.*", "", robot)
    received: list[tuple[str, bytes]] = []
    last = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        received.append((str(sample.key_expr), sample.payload.to_bytes()))
        if sample.payload.to_bytes() == b"last":
            last.set()

    with _open(router), _open(robot) as listener, _open(robot) as sender, _open(intruder) as other:
        listener.declare_subscriber("zenslam/field1/**", on_sample)
        listener.declare_subscriber("elsewhere/**", on_sample)
        publisher = sender.declare_publisher("zenslam/field1/frontend/pose")
        assert bus.wait_for_subscribers(publisher, timeout_s=30.0)
        other.put("zenslam/field1/frontend/pose", b"intruder")
        sender.put("elsewhere/key", b"outside the session")
        publisher.put(b"last")  # after the others on the same link: anything let through arrives before it
        assert last.wait(30.0)
    assert received == [("zenslam/field1/frontend/pose", b"last")]
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        with _open(without_certificate):
            pass
