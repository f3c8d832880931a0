"""``lagrseq robot serve`` on an address it cannot listen on is one line before the simulator
starts."""

from __future__ import annotations

import socket

import pytest

from tests.support.cli import refused


@pytest.mark.parametrize("host", ["bad host", "", "10.255.255.1", "[::1", "a" * 300])
def test_robot_serve_on_an_address_it_cannot_listen_on_is_one_line_before_the_simulator_starts(host: str) -> None:
    error = refused("robot", "serve", "--sim", "--host", host, "--port", "0")
    assert "cannot listen on" in error and "--host" in error


def test_robot_serve_on_a_port_in_use_is_one_line() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        assert f"cannot listen on 127.0.0.1:{port}" in refused("robot", "serve", "--sim", "--port", str(port))


