"""The robot service over gRPC: :class:`RemoteRobot` (the client the env uses with
``env.robot = "remote:HOST:PORT"``) and the server of ``lagrseq robot serve --sim``.

The service is ``lagrseq/robot/proto/robot.proto``; its generated code is committed next to it.
grpcio and protobuf (the ``arm`` extra) are imported when a client or server is built. Everything
a server answers is checked (grid size, outcome names, occupancy values, image size): a wrong
answer is one :class:`~lagrseq.robot.RobotError` line, as is a server that does not answer.
"""

from __future__ import annotations

import io
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from lagrseq.robot import OUTCOMES, JointState, PlacementResult, Robot, RobotError

MAX_MESSAGE_BYTES = 16 * 1024 * 1024
"""Largest message either side accepts (a 1920 x 1440 PNG fits)."""
CONNECT_TIMEOUT_S = 10.0
"""How long a client waits for the service to answer at all, when it connects."""


def parse_address(spec: str) -> tuple[str, int]:
    """``remote:HOST:PORT`` -> (HOST, PORT)."""
    kind, _, address = spec.partition(":")
    host, _, port = address.rpartition(":")
    if kind != "remote" or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise RobotError(f"robot {spec!r}; expected remote:HOST:PORT with a port in 1..65535")
    return host.strip("[]"), int(port)


def _grpc() -> Any:
    try:
        import grpc

        from lagrseq.robot.proto import robot_pb2, robot_pb2_grpc
    except ImportError as exc:
        raise RobotError(f"the robot service needs grpcio and protobuf ({exc}): pip install 'lagrseq[arm]'") from None
    return grpc, robot_pb2, robot_pb2_grpc


class RemoteRobot:
    """A :class:`~lagrseq.robot.Robot` behind a robot service (gRPC)."""

    def __init__(self, host: str, port: int, timeout_s: float = 60.0, connect_timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        self.grpc, self.pb, pb_grpc = _grpc()
        self.address = f"{host}:{port}" if ":" not in host else f"[{host}]:{port}"
        self.timeout_s = timeout_s
        options = [
            ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
            ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
        ]
        self.channel = self.grpc.insecure_channel(self.address, options=options)
        connect_timeout_s = min(connect_timeout_s, timeout_s)
        try:
            self.grpc.channel_ready_future(self.channel).result(timeout=connect_timeout_s)
        except self.grpc.FutureTimeoutError:
            self.channel.close()
            raise RobotError(
                f"no robot service answers at {self.address} (waited {connect_timeout_s:g} s); start one with "
                f"`lagrseq robot serve --sim --port {port}` or fix env.robot"
            ) from None
        self.stub = pb_grpc.RobotStub(self.channel)
        description = self._call("Describe", self.pb.DescribeRequest())
        self.rows, self.cols = int(description.rows), int(description.cols)
        if not (0 < self.rows <= 64 and 0 < self.cols <= 64):
            raise RobotError(f"robot service {self.address} describes a {self.rows}x{self.cols} grid; expected at most 64x64")
        self.description = str(description.robot)[:200]
        self.joint_names = tuple(str(n)[:100] for n in description.joint_names)

    def _call(self, method: str, request: Any, timeout_s: float | None = None) -> Any:
        try:
            return getattr(self.stub, method)(request, timeout=timeout_s or self.timeout_s)
        except self.grpc.RpcError as exc:
            code = exc.code() if hasattr(exc, "code") else None
            details = (exc.details() if hasattr(exc, "details") else "") or ""
            name = code.name if code is not None else "ERROR"
            if code == self.grpc.StatusCode.UNAVAILABLE:
                raise RobotError(
                    f"robot service {self.address} is unavailable ({method}: {details[:120]}); "
                    "is `lagrseq robot serve` still running?"
                ) from None
            raise RobotError(f"robot service {self.address}: {method} failed: {name}: {details[:200]}") from None

    def place(self, row: int, col: int) -> PlacementResult:
        reply = self._call("Place", self.pb.PlaceRequest(row=int(row), col=int(col)))
        if reply.outcome not in OUTCOMES or (reply.row, reply.col) != (row, col):
            raise RobotError(
                f"robot service {self.address} answered Place({row}, {col}) with cell ({reply.row}, {reply.col}) "
                f"and outcome {reply.outcome[:40]!r}; expected the same cell and one of {', '.join(OUTCOMES)}"
            )
        values = (reply.offset_mm, reply.tilt_deg, reply.height_mm)
        if not all(np.isfinite(values)):
            raise RobotError(f"robot service {self.address} answered Place with non-finite measurements {values}")
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
        names, positions = tuple(str(n)[:100] for n in reply.names), tuple(float(q) for q in reply.positions)
        if len(names) != len(positions) or len(names) > 64 or not all(np.isfinite(positions)):
            raise RobotError(f"robot service {self.address} answered GetJointState with {len(names)} names and {len(positions)} positions")
        return JointState(names, positions)

    def render(self, width: int, height: int) -> np.ndarray | None:
        try:
            reply = self.stub.Render(self.pb.RenderRequest(width=width, height=height), timeout=self.timeout_s)
        except self.grpc.RpcError as exc:
            if exc.code() == self.grpc.StatusCode.UNIMPLEMENTED:
                return None  # a robot without a camera
            return self._call("Render", self.pb.RenderRequest(width=width, height=height))  # the error, worded
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
def servicer(robot: Robot, description: str) -> Any:
    """A gRPC servicer of ``robot`` (calls are serialised: one robot, one motion at a time)."""
    grpc, pb, pb_grpc = _grpc()
    from lagrseq.robot.render import png_bytes

    lock = threading.Lock()

    class Servicer(pb_grpc.RobotServicer):  # type: ignore[misc, name-defined]
        def Describe(self, request: Any, context: Any) -> Any:
            with lock:
                names = robot.joint_state().names
            cell = getattr(getattr(robot, "workspace", None), "cell_size", 0.05)
            return pb.Description(rows=robot.rows, cols=robot.cols, cell_size=cell, joint_names=names, robot=description)

        def Place(self, request: Any, context: Any) -> Any:
            if not (0 <= request.row < robot.rows and 0 <= request.col < robot.cols):
                context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"cell ({request.row}, {request.col}) is outside the {robot.rows}x{robot.cols} grid")
            with lock:
                r = robot.place(request.row, request.col)
            return pb.Placement(row=r.row, col=r.col, outcome=r.outcome, offset_mm=r.offset_mm, tilt_deg=r.tilt_deg,
                                height_mm=r.height_mm, landed_row=r.landed_row, landed_col=r.landed_col, sim_steps=r.sim_steps)

        def Clear(self, request: Any, context: Any) -> Any:
            with lock:
                robot.clear()
            return pb.ClearReply()

        def Observe(self, request: Any, context: Any) -> Any:
            with lock:
                grid = robot.observe()
            return pb.Occupancy(rows=robot.rows, cols=robot.cols, cells=[int(c) for c in np.asarray(grid).ravel()])

        def GetJointState(self, request: Any, context: Any) -> Any:
            with lock:
                state = robot.joint_state()
            return pb.JointState(names=state.names, positions=state.positions)

        def Render(self, request: Any, context: Any) -> Any:
            if not (16 <= request.width <= 1920 and 16 <= request.height <= 1440):
                context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"image {request.width}x{request.height}; expected 16..1920 x 16..1440")
            with lock:
                rgb = robot.render(request.width, request.height)
            if rgb is None:
                context.abort(grpc.StatusCode.UNIMPLEMENTED, "this robot has no camera")
                return None
            return pb.Image(width=request.width, height=request.height, png=png_bytes(rgb))

    return Servicer()


def start_server(robot: Robot, host: str = "127.0.0.1", port: int = 0, description: str = "") -> tuple[Any, int]:
    """Serve ``robot`` on ``host:port`` (0: a free port); returns the started server and its port."""
    from concurrent.futures import ThreadPoolExecutor

    grpc, _, pb_grpc = _grpc()
    options = [
        ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
        ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
    ]
    server = grpc.server(ThreadPoolExecutor(max_workers=2), options=options)
    pb_grpc.add_RobotServicer_to_server(servicer(robot, description or type(robot).__name__), server)
    try:
        bound = server.add_insecure_port(f"{host}:{port}" if ":" not in host else f"[{host}]:{port}")
    except RuntimeError:
        bound = 0
    if not bound:
        raise RobotError(f"cannot listen on {host}:{port} (in use, or not an address of this machine); pick another --port")
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


def serve_sim(host: str, port: int, say: Callable[[str], None] = print) -> None:
    """``lagrseq robot serve --sim``: serve a simulated UR5e until Ctrl-C."""
    check_listen(host, port)  # before pybullet and gRPC start (and print lines of their own)
    from lagrseq.robot.sim import SimRobot

    robot = SimRobot()
    try:
        import pybullet

        version = getattr(pybullet, "__version__", "")
        server, bound = start_server(robot, host, port, f"simulated UR5e (pybullet {version})".replace(" )", ")"))
        say(f"lagrseq robot: serving a simulated UR5e on {host}:{bound} (Ctrl-C stops)")
        try:
            server.wait_for_termination()
        finally:
            server.stop(grace=1).wait()
    finally:
        robot.close()
