"""The robot service's guard: a token, TLS, loopback by default, bounded table and calls, every
call logged with its peer. Real gRPC on 127.0.0.1 (and 0.0.0.0 where the bind itself is the
point), real TLS with a self-signed pair made here by the ``openssl`` command line (the
``cryptography`` package is not a dependency of lagrseq)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from lagrseq.robot import JointState, PlacementResult, RobotError

grpc = pytest.importorskip("grpc")

from lagrseq.robot.proto import robot_pb2, robot_pb2_grpc  # noqa: E402
from lagrseq.robot.remote import (  # noqa: E402
    RemoteRobot,
    ServiceSecurity,
    read_token,
    security_for,
    start_server,
)

TOKEN = "s3cret-token-for-tests-0123456789"
ROOT = Path(__file__).resolve().parents[2]


class TableRobot:
    """A Robot with no physics: a placement lands where it was asked (slow_s: each takes that long)."""

    rows, cols = 5, 5

    def __init__(self, slow_s: float = 0.0) -> None:
        self.grid = np.zeros((5, 5), dtype=np.int8)
        self.slow_s = slow_s

    def place(self, row: int, col: int) -> PlacementResult:
        time.sleep(self.slow_s)
        self.grid[row, col] = 1
        return PlacementResult(row, col, "placed", landed_row=row, landed_col=col)

    def clear(self) -> None:
        self.grid[:] = 0

    def observe(self) -> np.ndarray:
        return self.grid.copy()

    def joint_state(self) -> JointState:
        return JointState(("a", "b"), (0.0, 1.0))

    def render(self, width: int, height: int) -> None:
        return None

    def close(self) -> None:
        pass


def token_file(tmp_path: Path, token: str = TOKEN, name: str = "token") -> Path:
    path = tmp_path / name
    path.write_text(token + "\n")
    path.chmod(0o600)
    return path


@pytest.fixture(scope="module")
def tls_pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A self-signed certificate for localhost / 127.0.0.1 and its key (openssl CLI)."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command line is not installed")
    folder = tmp_path_factory.mktemp("tls")
    cert, key = folder / "cert.pem", folder / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
         "-keyout", str(key), "-out", str(cert), "-days", "1", "-subj", "/CN=localhost",
         "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1"],
        check=True, capture_output=True, timeout=60,
    )
    key.chmod(0o600)
    return cert, key


def serve(robot: object, security: ServiceSecurity, host: str = "127.0.0.1") -> tuple[object, int, list[str]]:
    lines: list[str] = []
    server, port = start_server(robot, host, 0, "test table", security, log=lines.append)  # type: ignore[arg-type]
    return server, port, lines


def raw_place(port: int, metadata: tuple[tuple[str, str], ...] = ()) -> object:
    with grpc.insecure_channel(f"127.0.0.1:{port}") as channel:
        return robot_pb2_grpc.RobotStub(channel).Place(robot_pb2.PlaceRequest(row=1, col=1), timeout=10, metadata=metadata)


def test_a_call_without_the_token_is_unauthenticated_and_logged(tmp_path: Path) -> None:
    robot = TableRobot()
    server, port, lines = serve(robot, ServiceSecurity(token=TOKEN))
    try:
        with pytest.raises(grpc.RpcError) as refused:
            raw_place(port)
        assert refused.value.code() == grpc.StatusCode.UNAUTHENTICATED
        assert robot.grid.sum() == 0  # the arm did not move
        with pytest.raises(RobotError, match="UNAUTHENTICATED") as error:
            RemoteRobot("127.0.0.1", port, timeout_s=10)
        assert "\n" not in str(error.value) and "env.robot_token_file" in str(error.value)
        assert any("Place" in line and "refused (UNAUTHENTICATED: no token)" in line and "127.0.0.1" in line for line in lines)
    finally:
        server.stop(grace=None)


def test_a_wrong_token_is_refused_and_the_right_one_works(tmp_path: Path) -> None:
    robot = TableRobot()
    server, port, lines = serve(robot, ServiceSecurity(token=TOKEN))
    try:
        with pytest.raises(grpc.RpcError) as refused:
            raw_place(port, (("authorization", "Bearer " + TOKEN[:-1] + "X"),))
        assert refused.value.code() == grpc.StatusCode.UNAUTHENTICATED
        with pytest.raises(RobotError, match="UNAUTHENTICATED"):
            RemoteRobot("127.0.0.1", port, timeout_s=10, token_file=token_file(tmp_path, "wrong-token-0123456789abcdef"))
        remote = RemoteRobot("127.0.0.1", port, timeout_s=10, token_file=token_file(tmp_path, name="right"))
        try:
            assert remote.place(2, 3).ok and remote.observe()[2, 3] == 1
        finally:
            remote.close()
        assert any("wrong token" in line for line in lines)
        assert any(line.startswith("Place(2, 3) from ipv4:127.0.0.1:") for line in lines)
        assert not any(TOKEN in line for line in lines)
    finally:
        server.stop(grace=None)


def test_tls_with_a_self_signed_pair(tmp_path: Path, tls_pair: tuple[Path, Path]) -> None:
    cert, key = tls_pair
    robot = TableRobot()
    security = security_for("127.0.0.1", str(token_file(tmp_path)), str(cert), str(key))
    server, port, _ = serve(robot, security)
    try:
        remote = RemoteRobot("127.0.0.1", port, timeout_s=10, tls=True, tls_ca=cert, token_file=token_file(tmp_path, name="t2"))
        try:
            assert remote.description == "test table" and remote.place(0, 4).ok
        finally:
            remote.close()
        with pytest.raises(RobotError, match="UNAUTHENTICATED"):  # TLS alone does not let a stranger in
            RemoteRobot("127.0.0.1", port, timeout_s=10, tls=True, tls_ca=cert)
        with pytest.raises(RobotError, match="no robot service answers"):  # plain text to a TLS port
            RemoteRobot("127.0.0.1", port, timeout_s=2, connect_timeout_s=2)
    finally:
        server.stop(grace=None)


def test_a_non_loopback_bind_needs_token_and_tls(tmp_path: Path, tls_pair: tuple[Path, Path]) -> None:
    cert, key = tls_pair
    for token, tls in ((None, False), (str(token_file(tmp_path)), False), (None, True)):
        with pytest.raises(RobotError, match="refusing to serve the robot on 0.0.0.0") as refused:
            security_for("0.0.0.0", token, str(cert) if tls else None, str(key) if tls else None)
        assert "\n" not in str(refused.value)
    with pytest.raises(RobotError, match="without a token and TLS"):
        start_server(TableRobot(), "0.0.0.0", 0)  # type: ignore[arg-type]
    security = security_for("0.0.0.0", str(token_file(tmp_path)), str(cert), str(key))
    server, port, _ = serve(TableRobot(), security, host="0.0.0.0")
    try:
        with pytest.raises(grpc.RpcError) as refused:  # no TLS, no token: the handshake fails
            raw_place(port)
        assert refused.value.code() == grpc.StatusCode.UNAVAILABLE
    finally:
        server.stop(grace=None)


def test_the_command_line_refuses_0000_without_token_and_tls(tmp_path: Path) -> None:
    lagrseq = [sys.executable, "-m", "lagrseq", "robot", "serve", "--sim", "--host", "0.0.0.0", "--port", "0"]
    loose = tmp_path / "loose"
    loose.write_text(TOKEN)
    loose.chmod(0o644)
    cases = {
        (): "without --token-file and --tls-cert/--tls-key",
        ("--token-file", str(token_file(tmp_path))): "without --tls-cert/--tls-key",
        ("--host", "127.0.0.1", "--token-file", str(loose)): "can be read by others (mode 0644); make it private",
        ("--host", "127.0.0.1", "--tls-cert", str(loose)): "give both or neither",
    }
    for extra, expected in cases.items():
        done = subprocess.run([*lagrseq, *extra], capture_output=True, text=True, timeout=60, cwd=ROOT)
        assert done.returncode == 2 and expected in done.stderr, (extra, done.stderr)
        assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr
        assert TOKEN not in done.stderr + done.stdout


def test_a_damaged_tls_cert_or_key_is_one_clear_line_before_grpc_starts(tmp_path: Path, tls_pair: tuple[Path, Path]) -> None:
    """A truncated --tls-cert or --tls-key is named in one line, not three gRPC log lines and a
    vague "in use ... or a bad TLS certificate/key": the files are checked (OpenSSL through
    ``ssl``) before any server starts."""
    cert, key = tls_pair
    lines = cert.read_text().splitlines()
    cut_cert = tmp_path / "cut-cert.pem"
    cut_cert.write_text("\n".join(lines[:3]) + "\n")  # BEGIN and two lines: the end is missing
    body_cut = tmp_path / "body-cut.pem"
    body_cut.write_text("\n".join([lines[0], lines[1], lines[-1]]) + "\n")  # BEGIN ... END, most of the body gone
    key_lines = key.read_text().splitlines()
    cut_key = tmp_path / "cut-key.pem"
    cut_key.write_text("\n".join(key_lines[:2]) + "\n")
    other = tmp_path / "other"
    other.mkdir()
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
         "-keyout", str(other / "key.pem"), "-out", str(other / "cert.pem"), "-days", "1", "-subj", "/CN=other"],
        check=True, capture_output=True, timeout=60,
    )
    for path in (cut_key, other / "key.pem"):
        path.chmod(0o600)
    cases = {
        (cut_cert, key): f"--tls-cert {cut_cert} is not a PEM certificate: cut short",
        (body_cut, key): f"--tls-cert {body_cut} is not a PEM certificate: OpenSSL cannot read it",
        (key, key): f"--tls-cert {key} is not a PEM certificate",
        (cert, cut_key): f"--tls-key {cut_key} is not a PEM private key: cut short",
        (cert, other / "key.pem"): f"--tls-key {other / 'key.pem'} is not an unencrypted PEM private key of the certificate",
        (cert, cert): f"--tls-key {cert} is not an unencrypted PEM private key",
    }
    for (cert_file, key_file), expected in cases.items():
        done = subprocess.run(
            [sys.executable, "-m", "lagrseq", "robot", "serve", "--sim", "--port", "0", "--tls-cert", str(cert_file), "--tls-key", str(key_file)],
            capture_output=True, text=True, timeout=60, cwd=ROOT,
        )
        errors = [line for line in done.stderr.splitlines() if not line.startswith("pybullet build time")]
        assert done.returncode == 2 and len(errors) == 1, (cert_file.name, key_file.name, done.stderr)
        assert expected in errors[0], errors[0]
        assert "in use" not in errors[0]


def test_the_table_is_bounded_until_clear() -> None:
    robot = TableRobot()
    server, port, lines = serve(robot, ServiceSecurity(max_objects=3))
    remote = RemoteRobot("127.0.0.1", port, timeout_s=10)
    try:
        for cell in range(3):
            assert remote.place(0, cell).ok
        with pytest.raises(RobotError, match="FAILED_PRECONDITION: the table holds 3 objects.*call Clear first"):
            remote.place(1, 0)
        assert robot.grid.sum() == 3
        remote.clear()
        assert remote.place(1, 0).ok
        assert any("Place refused: 3 objects" in line for line in lines)
    finally:
        remote.close()
        server.stop(grace=None)


def test_concurrent_calls_and_request_sizes_are_bounded() -> None:
    server, port, _ = serve(TableRobot(slow_s=1.0), ServiceSecurity(max_concurrent_calls=1))
    codes: list[object] = []

    def place() -> None:
        try:
            raw_place(port)
            codes.append("ok")
        except grpc.RpcError as exc:
            codes.append(exc.code())

    try:
        threads = [threading.Thread(target=place) for _ in range(3)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(30)
        assert codes.count("ok") >= 1 and grpc.StatusCode.RESOURCE_EXHAUSTED in codes, codes
        # a request far above any real one (10 kB of an unknown field): refused before it is parsed
        with grpc.insecure_channel(f"127.0.0.1:{port}") as channel, pytest.raises(grpc.RpcError) as big:
            send = channel.unary_unary("/lagrseq.robot.v1.Robot/Place", request_serializer=bytes, response_deserializer=bytes)
            send(b"\x7a\xd0\x4e" + b"p" * 10_000, timeout=10)
        assert big.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
    finally:
        server.stop(grace=None)


class Liar(robot_pb2_grpc.RobotServicer):  # type: ignore[misc]
    """A robot service whose Describe answer is hostile."""

    def __init__(self, **fields: object) -> None:
        self.fields = {"rows": 5, "cols": 5, "cell_size": 0.05, "joint_names": ["a"], "robot": "liar", **fields}

    def Describe(self, request: object, context: object) -> object:
        return robot_pb2.Description(**self.fields)


@pytest.mark.parametrize(
    ("fields", "expected"),
    [
        ({"robot": "x" * 5_000_000}, "describes itself in 5000000 characters"),
        ({"robot": "bad\nname"}, "unprintable"),
        ({"joint_names": ["j"] * 1000}, "with 1000 joint names"),
        ({"joint_names": ["j" * 10_000]}, "longest 10000 characters"),
        ({"cell_size": float("nan")}, "describes cells of nan m"),
        ({"cell_size": 1e300}, "expected 0 to 1 m"),
        ({"rows": 100000}, "expected at most 64x64"),
    ],
)
def test_every_describe_field_is_checked(fields: dict[str, object], expected: str) -> None:
    from concurrent.futures import ThreadPoolExecutor

    server = grpc.server(ThreadPoolExecutor(1), options=[("grpc.max_send_message_length", 64 * 1024 * 1024)])
    robot_pb2_grpc.add_RobotServicer_to_server(Liar(**fields), server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    try:
        with pytest.raises(RobotError, match="robot service 127.0.0.1") as error:
            RemoteRobot("127.0.0.1", port, timeout_s=10)
        assert expected in str(error.value) and len(str(error.value)) < 400 and "\n" not in str(error.value)
    finally:
        server.stop(grace=None)


def test_a_token_is_never_sent_in_clear_text_to_another_machine(tmp_path: Path) -> None:
    with pytest.raises(RobotError, match="refusing to send the robot token to 192.0.2.1:50051 in clear text"):
        RemoteRobot("192.0.2.1", 50051, timeout_s=1, token_file=token_file(tmp_path))


def test_token_files_are_checked(tmp_path: Path) -> None:
    short = token_file(tmp_path, "short", "short")
    with pytest.raises(RobotError, match="at least 16 printable ASCII"):
        read_token(short)
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(RobotError, match="is a FIFO"):
        read_token(tmp_path / "fifo")
    assert read_token(token_file(tmp_path)) == TOKEN
