"""The robot service over gRPC: :class:`RemoteRobot` (the client the env uses with
``env.robot = "remote:HOST:PORT"`` or ``"remote+tls:HOST:PORT"``) and the server of
``lagrseq robot serve --sim``.

The service is ``lagrseq/robot/proto/robot.proto``; its generated code is committed next to it.
grpcio and protobuf (the ``arm`` extra) are imported when a client or server is built. Everything
a server answers is checked (grid size, string sizes, outcome names, cells and measurements in
range, occupancy values, image size): a wrong answer is one :class:`~lagrseq.robot.RobotError`
line, as is a server that does not answer.

Security (docs/security.md): the service moves an arm, so who may call it matters.

* It listens on loopback by default. Any other address needs BOTH a token file (a shared secret
  the client sends as ``authorization: Bearer TOKEN`` metadata on every call, compared with
  :func:`hmac.compare_digest`) AND TLS (``--tls-cert``/``--tls-key``); without both the server
  refuses to start. A client sends its token only over TLS, or to a loopback address.
* Bounded: request messages (:data:`MAX_REQUEST_BYTES`), concurrent calls
  (:data:`MAX_CONCURRENT_CALLS`; more are refused with RESOURCE_EXHAUSTED), objects on the table
  (``max_objects``; a full table refuses ``Place`` with FAILED_PRECONDITION until ``Clear``).
* Every call is logged with its peer's address, refused ones included.
"""

from __future__ import annotations

import hmac
import io
import ipaddress
import math
import os
import stat
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq import keys
from lagrseq.paths import input_path
from lagrseq.progress import Reporter
from lagrseq.robot import OUTCOMES, JointState, PlacementResult, Robot, RobotError
from lagrseq.text import printable

MAX_MESSAGE_BYTES = 16 * 1024 * 1024
"""Largest answer a client accepts (a 1920 x 1440 PNG fits)."""
MAX_REQUEST_BYTES = 4096
"""Largest request the server accepts (every request of the service is a few bytes)."""
MAX_CONCURRENT_CALLS = 8
"""Calls the server holds at once (the robot serves one at a time); more: RESOURCE_EXHAUSTED."""
MAX_OBJECTS = 64
"""Default bound on the objects on the table (an episode places at most one per step of its
50-step horizon, and only on empty cells of the 5 x 5 grid); ``Place`` on a full table is refused
until ``Clear``."""
CONNECT_TIMEOUT_S = 10.0
"""How long a client waits for the service to answer at all, when it connects."""
MAX_TOKEN_BYTES = 4096
MIN_TOKEN_CHARS = 16
MAX_DESCRIPTION_CHARS = 200
MAX_NAME_CHARS = 100
MAX_JOINTS = 64
MAX_MEASUREMENT = 1e6
"""Largest magnitude a Placement's mm and degree fields may have (the table is 1.3 m wide)."""
MAX_SIM_STEPS = 10**7
SCHEMES = ("remote", "remote+tls")


def parse_address(spec: str) -> tuple[str, int]:
    """``remote:HOST:PORT`` or ``remote+tls:HOST:PORT`` -> (HOST, PORT)."""
    kind, _, address = spec.partition(":")
    host, _, port = address.rpartition(":")
    if kind not in SCHEMES or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise RobotError(f"robot {spec!r}; expected remote:HOST:PORT or remote+tls:HOST:PORT with a port in 1..65535")
    return host.strip("[]"), int(port)


def is_loopback(host: str) -> bool:
    """``host`` names this machine only (127.0.0.0/8, ::1, localhost)."""
    if host.lower() in ("localhost", "localhost.localdomain"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def read_token(path: str | os.PathLike[str], flag: str = "--token-file") -> str:
    """The shared secret in ``path``: a regular file readable by its owner only (mode 0600 or
    stricter), at most 4 KiB, holding one line of at least 16 printable ASCII characters (a gRPC
    metadata value). The token itself never appears in a message."""
    file = input_path(path, f"{flag}", "file", RobotError)
    mode = file.stat().st_mode
    if os.name == "posix" and mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise RobotError(f"{flag} {file} can be read by others (mode {stat.S_IMODE(mode):04o}); make it private: chmod 600 {file}")
    with file.open("rb") as handle:
        data = handle.read(MAX_TOKEN_BYTES + 1)
    if len(data) > MAX_TOKEN_BYTES:
        raise RobotError(f"{flag} {file} is larger than {MAX_TOKEN_BYTES} bytes; a token file holds one line")
    try:
        token = data.decode("ascii").strip()
    except UnicodeDecodeError:
        token = ""
    if len(token) < MIN_TOKEN_CHARS or not all(33 <= ord(ch) < 127 for ch in token):
        raise RobotError(
            f"{flag} {file}: expected one line of at least {MIN_TOKEN_CHARS} printable ASCII characters without spaces; "
            "make one with: python -c 'import secrets; print(secrets.token_urlsafe(32))' > FILE"
        )
    keys.remember(token)  # blanked out of every line printed and every log written, as an API key is
    return token


def _read_pem(path: str | os.PathLike[str], flag: str) -> bytes:
    file = input_path(path, flag, "file", RobotError)
    with file.open("rb") as handle:
        data = handle.read(1024 * 1024 + 1)
    if len(data) > 1024 * 1024 or b"-----BEGIN" not in data:
        raise RobotError(f"{flag} {file}: expected a PEM file (-----BEGIN ...) of at most 1 MiB")
    return data


def _grpc() -> Any:
    try:
        import grpc

        from lagrseq.robot.proto import robot_pb2, robot_pb2_grpc
    except ImportError as exc:
        raise RobotError(f"the robot service needs grpcio and protobuf ({exc}): pip install 'lagrseq[arm]'") from None
    return grpc, robot_pb2, robot_pb2_grpc


class RemoteRobot:
    """A :class:`~lagrseq.robot.Robot` behind a robot service (gRPC)."""

    def __init__(
        self,
        host: str,
        port: int,
        timeout_s: float = 60.0,
        connect_timeout_s: float = CONNECT_TIMEOUT_S,
        *,
        tls: bool = False,
        tls_ca: str | os.PathLike[str] | None = None,
        token_file: str | os.PathLike[str] | None = None,
    ) -> None:
        """``tls``: talk TLS, trusting the CA certificate in ``tls_ca`` (PEM; None: the system's
        roots); ``token_file``: send its token on every call (only over TLS or to loopback)."""
        self.grpc, self.pb, pb_grpc = _grpc()
        self.address = f"{host}:{port}" if ":" not in host else f"[{host}]:{port}"
        self.timeout_s = timeout_s
        if tls_ca and not tls:
            raise RobotError(f"a TLS CA certificate is set but the robot is remote:{self.address}; write remote+tls:{self.address}")
        self.metadata: tuple[tuple[str, str], ...] = ()
        if token_file:
            if not tls and not is_loopback(host):
                raise RobotError(
                    f"refusing to send the robot token to {self.address} in clear text; serve with --tls-cert/--tls-key "
                    f"and write env.robot = \"remote+tls:{self.address}\""
                )
            self.metadata = (("authorization", f"Bearer {read_token(token_file, 'env.robot_token_file')}"),)
        options = [
            ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
            ("grpc.max_send_message_length", MAX_REQUEST_BYTES),
        ]
        if tls:
            roots = _read_pem(tls_ca, "env.robot_tls_ca") if tls_ca else None
            credentials = self.grpc.ssl_channel_credentials(root_certificates=roots)
            self.channel = self.grpc.secure_channel(self.address, credentials, options=options)
        else:
            self.channel = self.grpc.insecure_channel(self.address, options=options)
        connect_timeout_s = min(connect_timeout_s, timeout_s)
        try:
            self.grpc.channel_ready_future(self.channel).result(timeout=connect_timeout_s)
        except self.grpc.FutureTimeoutError:
            self.channel.close()
            hint = " (TLS: check env.robot_tls_ca and that the server was started with --tls-cert)" if tls else ""
            raise RobotError(
                f"no robot service answers at {self.address} (waited {connect_timeout_s:g} s){hint}; start one with "
                f"`lagrseq robot serve --sim --port {port}` or fix env.robot"
            ) from None
        self.stub = pb_grpc.RobotStub(self.channel)
        try:
            self._describe(self._call("Describe", self.pb.DescribeRequest()))
        except BaseException:
            self.channel.close()
            raise

    def _describe(self, description: Any) -> None:
        """Check every field of a Describe answer: sizes and ranges."""
        self.rows, self.cols = int(description.rows), int(description.cols)
        if not (0 < self.rows <= 64 and 0 < self.cols <= 64):
            raise RobotError(f"robot service {self.address} describes a {self.rows}x{self.cols} grid; expected at most 64x64")
        cell = float(description.cell_size)
        if not (math.isfinite(cell) and 0 <= cell <= 1):
            raise RobotError(f"robot service {self.address} describes cells of {cell!r} m; expected 0 to 1 m")
        robot, names = str(description.robot), list(description.joint_names)
        if len(robot) > MAX_DESCRIPTION_CHARS or not robot.isprintable():
            raise RobotError(
                f"robot service {self.address} describes itself in {len(robot)} characters (or unprintable ones); "
                f"expected at most {MAX_DESCRIPTION_CHARS} printable characters"
            )
        self._check_names(names, "Describe")
        self.description = robot
        self.joint_names = tuple(str(n) for n in names)

    def _check_names(self, names: list[Any], method: str) -> None:
        if len(names) > MAX_JOINTS or any(len(n) > MAX_NAME_CHARS or not str(n).isprintable() for n in names):
            raise RobotError(
                f"robot service {self.address} answered {method} with {len(names)} joint names (longest "
                f"{max((len(n) for n in names), default=0)} characters); expected at most {MAX_JOINTS} printable names "
                f"of at most {MAX_NAME_CHARS} characters"
            )

    def _call(self, method: str, request: Any, timeout_s: float | None = None) -> Any:
        try:
            return getattr(self.stub, method)(request, timeout=timeout_s or self.timeout_s, metadata=self.metadata)
        except self.grpc.RpcError as exc:
            raise self._error(method, exc) from None

    def _error(self, method: str, exc: Any) -> RobotError:
        code = exc.code() if hasattr(exc, "code") else None
        details = " ".join(((exc.details() if hasattr(exc, "details") else "") or "").split())
        name = code.name if code is not None else "ERROR"
        if code == self.grpc.StatusCode.UNAVAILABLE:
            return RobotError(
                f"robot service {self.address} is unavailable ({method}: {details[:120]}); "
                "is `lagrseq robot serve` still running?"
            )
        if code == self.grpc.StatusCode.UNAUTHENTICATED:
            return RobotError(
                f"robot service {self.address} refused {method}: UNAUTHENTICATED ({details[:120]}); "
                "give the service's token file with --set env.robot_token_file=FILE"
            )
        return RobotError(f"robot service {self.address}: {method} failed: {name}: {details[:200]}")

    def place(self, row: int, col: int) -> PlacementResult:
        reply = self._call("Place", self.pb.PlaceRequest(row=int(row), col=int(col)))
        if reply.outcome not in OUTCOMES or (reply.row, reply.col) != (row, col):
            raise RobotError(
                f"robot service {self.address} answered Place({row}, {col}) with cell ({reply.row}, {reply.col}) "
                f"and outcome {reply.outcome[:40]!r}; expected the same cell and one of {', '.join(OUTCOMES)}"
            )
        values = (reply.offset_mm, reply.tilt_deg, reply.height_mm)
        if not all(math.isfinite(v) and abs(v) <= MAX_MEASUREMENT for v in values):
            raise RobotError(f"robot service {self.address} answered Place with measurements {values}; expected finite values below {MAX_MEASUREMENT:g}")
        landed_ok = all(-1 <= v < limit for v, limit in ((reply.landed_row, self.rows), (reply.landed_col, self.cols)))
        if not landed_ok or not 0 <= reply.sim_steps <= MAX_SIM_STEPS:
            raise RobotError(
                f"robot service {self.address} answered Place with landing cell ({reply.landed_row}, {reply.landed_col}) "
                f"and {reply.sim_steps} steps; expected a cell of the {self.rows}x{self.cols} grid (or -1) and 0..{MAX_SIM_STEPS} steps"
            )
        return PlacementResult(
            int(reply.row), int(reply.col), str(reply.outcome), float(reply.offset_mm), float(reply.tilt_deg),
            float(reply.height_mm), int(reply.landed_row), int(reply.landed_col), int(reply.sim_steps),
        )

    def clear(self) -> None:
        self._call("Clear", self.pb.ClearRequest())

    def observe(self) -> np.ndarray:
        reply = self._call("Observe", self.pb.ObserveRequest())
        cells = list(reply.cells)
        if (reply.rows, reply.cols) != (self.rows, self.cols) or len(cells) != self.rows * self.cols or any(c not in (0, 1) for c in cells):
            raise RobotError(
                f"robot service {self.address} answered Observe with a {reply.rows}x{reply.cols} grid of "
                f"{len(cells)} values; expected {self.rows}x{self.cols} values of 0 or 1"
            )
        return np.array(cells, dtype=np.int8).reshape(self.rows, self.cols)

    def joint_state(self) -> JointState:
        reply = self._call("GetJointState", self.pb.JointStateRequest())
        self._check_names(list(reply.names), "GetJointState")
        names, positions = tuple(str(n) for n in reply.names), tuple(float(q) for q in reply.positions)
        if len(names) != len(positions) or not all(np.isfinite(positions)):
            raise RobotError(f"robot service {self.address} answered GetJointState with {len(names)} names and {len(positions)} positions")
        return JointState(names, positions)

    def render(self, width: int, height: int) -> np.ndarray | None:
        try:
            reply = self.stub.Render(self.pb.RenderRequest(width=width, height=height), timeout=self.timeout_s, metadata=self.metadata)
        except self.grpc.RpcError as exc:
            if exc.code() == self.grpc.StatusCode.UNIMPLEMENTED:
                return None  # a robot without a camera
            raise self._error("Render", exc) from None
        return _decode_png(reply.png, width, height, self.address)

    def close(self) -> None:
        self.channel.close()


def _decode_png(data: bytes, width: int, height: int, address: str) -> np.ndarray:
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as image:
            if image.format != "PNG" or image.size != (width, height):
                raise ValueError(f"a {image.format} image of {image.size}")
            return np.asarray(image.convert("RGB"), dtype=np.uint8)
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise RobotError(f"robot service {address} answered Render({width}, {height}) with {str(exc)[:120]}; expected a PNG of that size") from None


# ------------------------------------------------------------------------------------------
# The server
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ServiceSecurity:
    """Who may call the service and how much: see the module docstring."""

    token: str | None = None
    """The shared secret every call must carry (``authorization: Bearer TOKEN``); None: no check
    (loopback only)."""
    tls_cert: bytes | None = None
    """PEM certificate chain and private key of the server; None: plain TCP (loopback only)."""
    tls_key: bytes | None = None
    max_objects: int = MAX_OBJECTS
    """Objects on the table at most; ``Place`` on a full table is refused until ``Clear``."""
    max_concurrent_calls: int = MAX_CONCURRENT_CALLS

    def __repr__(self) -> str:  # never the token or the key
        return (
            f"ServiceSecurity(token={'set' if self.token else None}, tls={self.tls_cert is not None}, "
            f"max_objects={self.max_objects}, max_concurrent_calls={self.max_concurrent_calls})"
        )


def security_for(
    host: str, token_file: str | None = None, tls_cert: str | None = None, tls_key: str | None = None,
    max_objects: int = MAX_OBJECTS,
) -> ServiceSecurity:
    """``robot serve``'s options as a :class:`ServiceSecurity`, refusing (one line) a bind to
    anything but loopback without both a token file and TLS."""
    if (tls_cert is None) != (tls_key is None):
        raise RobotError("TLS needs both --tls-cert FILE and --tls-key FILE (PEM); give both or neither")
    if not is_loopback(host) and (token_file is None or tls_cert is None):
        missing = " and ".join(m for m, absent in (("--token-file", token_file is None), ("--tls-cert/--tls-key", tls_cert is None)) if absent)
        raise RobotError(
            f"refusing to serve the robot on {host} without {missing}: anyone who reaches the port could move the arm; "
            "give --token-file FILE (a shared secret, chmod 600) and --tls-cert FILE --tls-key FILE, or serve on 127.0.0.1 "
            "(see docs/security.md)"
        )
    if not 1 <= max_objects <= 10_000:
        raise RobotError(f"--max-objects {max_objects}; expected 1 to 10000")
    cert_pem = _read_pem(tls_cert, "--tls-cert") if tls_cert is not None else None
    key_pem = _read_pem(tls_key, "--tls-key") if tls_key is not None else None
    if cert_pem is not None and key_pem is not None:
        check_tls_pair(cert_pem, key_pem, str(tls_cert), str(tls_key))
    return ServiceSecurity(
        token=read_token(token_file) if token_file is not None else None,
        tls_cert=cert_pem,
        tls_key=key_pem,
        max_objects=max_objects,
    )


def check_tls_pair(cert_pem: bytes, key_pem: bytes, cert_name: str, key_name: str) -> None:
    """One clear line, before any server starts (gRPC would print its own log lines and fail
    vaguely), unless ``cert_pem`` holds whole PEM certificates and ``key_pem`` the unencrypted
    PEM private key that goes with the first: both are loaded by the ``ssl`` module (OpenSSL,
    what gRPC uses too), from private temporary copies of the bytes that were read."""
    import ssl
    import tempfile

    shown_cert, shown_key = printable(cert_name), printable(key_name)
    for pem, flag, shown, what in ((cert_pem, "--tls-cert", shown_cert, "certificate"), (key_pem, "--tls-key", shown_key, "private key")):
        begins, ends = pem.count(b"-----BEGIN "), pem.count(b"-----END ")
        if begins != ends:
            raise RobotError(f"{flag} {shown} is not a PEM {what}: cut short ({begins} -----BEGIN lines, {ends} -----END lines); give the whole file")
    with tempfile.TemporaryDirectory(prefix="lagrseq-tls-check-") as folder:
        cert_copy, key_copy = Path(folder) / "cert.pem", Path(folder) / "key.pem"
        for path, data in ((cert_copy, cert_pem), (key_copy, key_pem)):
            descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(descriptor, "wb") as handle:
                handle.write(data)
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        try:
            context.load_verify_locations(cafile=str(cert_copy))
        except (ssl.SSLError, ValueError) as exc:
            raise RobotError(f"--tls-cert {shown_cert} is not a PEM certificate: {_ssl_reason(exc)}; give the certificate (chain) file, e.g. made by openssl req -x509") from None
        try:
            context.load_cert_chain(certfile=str(cert_copy), keyfile=str(key_copy), password=lambda: b"")
        except (ssl.SSLError, ValueError) as exc:
            raise RobotError(
                f"--tls-key {shown_key} is not an unencrypted PEM private key of the certificate in --tls-cert {shown_cert}: "
                f"{_ssl_reason(exc)}; give the key made with the certificate (openssl ... -nodes)"
            ) from None


def _ssl_reason(exc: BaseException) -> str:
    """An ``ssl`` error in a few words, on one line (OpenSSL's "PEM lib" says only that the file
    could not be read)."""
    reason = getattr(exc, "reason", None)
    if reason is None or reason == "PEM_LIB" or "PEM lib" in str(exc):
        return "OpenSSL cannot read it (damaged, cut short, encrypted with a passphrase, or another kind of PEM)"
    return printable(" ".join(str(reason).lower().replace("_", " ").split()))


def _stderr_log(line: str) -> None:
    print(f"{time.strftime('%Y-%m-%dT%H:%M:%S')} lagrseq robot: {line}", file=sys.stderr, flush=True)


def servicer(
    robot: Robot, description: str, security: ServiceSecurity | None = None, log: Callable[[str], None] | None = None,
) -> Any:
    """A gRPC servicer of ``robot`` (calls are serialised: one robot, one motion at a time).
    Every call is checked against ``security`` (its token, the table's bound) and logged with
    its peer through ``log`` (default: a line on stderr)."""
    grpc, pb, pb_grpc = _grpc()
    servicer_class = type("Servicer", (_RobotCalls, pb_grpc.RobotServicer), {})
    return servicer_class(robot, description, security or ServiceSecurity(), log or _stderr_log, grpc, pb)


class _RobotCalls:
    """The robot service's calls, mixed into the generated servicer by :func:`servicer`."""

    def __init__(self, robot: Robot, description: str, guard: ServiceSecurity, log: Callable[[str], None],
                 grpc: Any, pb: Any) -> None:
        from lagrseq.robot.render import png_bytes

        self._robot, self._description, self._guard, self._log = robot, description, guard, log
        self._grpc, self._pb, self._png_bytes = grpc, pb, png_bytes
        self._expected = f"Bearer {guard.token}".encode() if guard.token else None
        self._lock = threading.Lock()
        self._placed = 0  # objects on the table (placements since the last Clear)

    def _admit(self, method: str, context: Any, what: str = "") -> None:
        """Refuse a call without the token (UNAUTHENTICATED); log every call with its peer."""
        peer = context.peer()
        if self._expected is not None:
            given = dict(context.invocation_metadata()).get("authorization", "")
            if not hmac.compare_digest(self._expected, given.encode("utf-8", "replace")):
                self._log(f"{method} from {peer}: refused (UNAUTHENTICATED: {'wrong token' if given else 'no token'})")
                context.abort(self._grpc.StatusCode.UNAUTHENTICATED, "this robot service needs its token (authorization: Bearer TOKEN)")
        self._log(f"{method}{what} from {peer}")

    def Describe(self, request: Any, context: Any) -> Any:
        self._admit("Describe", context)
        robot = self._robot
        with self._lock:
            names = robot.joint_state().names
        cell = getattr(getattr(robot, "workspace", None), "cell_size", 0.05)
        return self._pb.Description(rows=robot.rows, cols=robot.cols, cell_size=cell, joint_names=names, robot=self._description)

    def Place(self, request: Any, context: Any) -> Any:
        self._admit("Place", context, f"({request.row}, {request.col})")
        robot = self._robot
        if not (0 <= request.row < robot.rows and 0 <= request.col < robot.cols):
            context.abort(self._grpc.StatusCode.INVALID_ARGUMENT, f"cell ({request.row}, {request.col}) is outside the {robot.rows}x{robot.cols} grid")
        with self._lock:
            if self._placed >= self._guard.max_objects:
                self._log(f"Place refused: {self._placed} objects on the table (the bound)")
                context.abort(
                    self._grpc.StatusCode.FAILED_PRECONDITION,
                    f"the table holds {self._placed} objects, the most this service allows; call Clear first",
                )
            r = robot.place(request.row, request.col)
            self._placed += 1
        return self._pb.Placement(row=r.row, col=r.col, outcome=r.outcome, offset_mm=r.offset_mm, tilt_deg=r.tilt_deg,
                                  height_mm=r.height_mm, landed_row=r.landed_row, landed_col=r.landed_col, sim_steps=r.sim_steps)

    def Clear(self, request: Any, context: Any) -> Any:
        self._admit("Clear", context)
        with self._lock:
            self._robot.clear()
            self._placed = 0
        return self._pb.ClearReply()

    def Observe(self, request: Any, context: Any) -> Any:
        self._admit("Observe", context)
        with self._lock:
            grid = self._robot.observe()
        return self._pb.Occupancy(rows=self._robot.rows, cols=self._robot.cols, cells=[int(c) for c in np.asarray(grid).ravel()])

    def GetJointState(self, request: Any, context: Any) -> Any:
        self._admit("GetJointState", context)
        with self._lock:
            state = self._robot.joint_state()
        return self._pb.JointState(names=state.names, positions=state.positions)

    def Render(self, request: Any, context: Any) -> Any:
        self._admit("Render", context, f"({request.width}, {request.height})")
        if not (16 <= request.width <= 1920 and 16 <= request.height <= 1440):
            context.abort(self._grpc.StatusCode.INVALID_ARGUMENT, f"image {request.width}x{request.height}; expected 16..1920 x 16..1440")
        with self._lock:
            rgb = self._robot.render(request.width, request.height)
        if rgb is None:
            context.abort(self._grpc.StatusCode.UNIMPLEMENTED, "this robot has no camera")
            return None
        return self._pb.Image(width=request.width, height=request.height, png=self._png_bytes(rgb))


def start_server(
    robot: Robot, host: str = "127.0.0.1", port: int = 0, description: str = "",
    security: ServiceSecurity | None = None, log: Callable[[str], None] | None = None,
) -> tuple[Any, int]:
    """Serve ``robot`` on ``host:port`` (0: a free port); returns the started server and its
    port. Anything but loopback needs a token and TLS in ``security``."""
    from concurrent.futures import ThreadPoolExecutor

    grpc, _, pb_grpc = _grpc()
    security = security or ServiceSecurity()
    if not is_loopback(host) and (security.token is None or security.tls_cert is None):
        raise RobotError(f"refusing to serve the robot on {host} without a token and TLS (see docs/security.md)")
    options = [
        ("grpc.max_receive_message_length", MAX_REQUEST_BYTES),
        ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
    ]
    server = grpc.server(
        ThreadPoolExecutor(max_workers=2), options=options, maximum_concurrent_rpcs=security.max_concurrent_calls,
    )
    pb_grpc.add_RobotServicer_to_server(servicer(robot, description or type(robot).__name__, security, log), server)
    address = f"{host}:{port}" if ":" not in host else f"[{host}]:{port}"
    try:
        if security.tls_cert is not None and security.tls_key is not None:
            credentials = grpc.ssl_server_credentials([(security.tls_key, security.tls_cert)])
            bound = server.add_secure_port(address, credentials)
        else:
            bound = server.add_insecure_port(address)
    except RuntimeError:
        bound = 0
    if not bound:
        raise RobotError(f"cannot listen on {host}:{port} (in use, not an address of this machine, or a bad TLS certificate/key); pick another --port or check --tls-cert/--tls-key")
    server.start()
    return server, bound


def check_listen(host: str, port: int) -> None:
    """``--host``/``--port``: an address of this machine with the port free; RobotError (one
    line) otherwise."""
    import socket

    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        family, kind, proto, _, address = infos[0]
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            probe.bind(address)
    except (OSError, UnicodeError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or type(exc).__name__
        raise RobotError(f"cannot listen on {host}:{port} ({reason}); give an address of this machine (--host) and a free --port") from None


def serve_sim(
    host: str, port: int, reporter: Reporter | None = None, security: ServiceSecurity | None = None,
    log: Callable[[str], None] | None = None,
) -> None:
    """``lagrseq robot serve --sim``: serve a simulated UR5e until Ctrl-C (or SIGTERM); its address
    is said to ``reporter`` (None: printed), each call logged through ``log`` (:func:`servicer`)."""
    reporter = reporter or Reporter()
    security = security or ServiceSecurity()
    if not is_loopback(host) and (security.token is None or security.tls_cert is None):
        raise RobotError(f"refusing to serve the robot on {host} without a token and TLS (see docs/security.md)")
    check_listen(host, port)  # before pybullet and gRPC start (and print lines of their own)
    from lagrseq.robot.sim import SimRobot

    robot = SimRobot()
    try:
        import pybullet

        version = getattr(pybullet, "__version__", "")
        server, bound = start_server(robot, host, port, f"simulated UR5e (pybullet {version})".replace(" )", ")"), security, log)
        guard = ("token" if security.token else "no token") + (", TLS" if security.tls_cert else ", no TLS")
        reporter.say(f"lagrseq robot: serving a simulated UR5e on {host}:{bound} ({guard}; at most {security.max_objects} objects; Ctrl-C stops)")
        try:
            server.wait_for_termination()
        finally:
            server.stop(grace=1).wait()
    finally:
        robot.close()
