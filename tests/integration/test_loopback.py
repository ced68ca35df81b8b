"""The viewer's meshcat server listens on 127.0.0.1 only (unless asked), and says where."""

import psutil
import pytest

from teleop.viz.meshcat_view import start_server, stop_server


def _listening(pid: int) -> set:
    return {(c.laddr.ip, c.laddr.port) for c in psutil.Process(pid).net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN}


def test_the_server_binds_loopback_only_and_prints_that_address():
    proc, zmq_url, web_url = start_server()
    try:
        ports = _listening(proc.pid)
        assert ports and {ip for ip, _ in ports} == {"127.0.0.1"}, ports
        web_port = int(web_url.rsplit(":", 1)[1].split("/")[0])
        assert web_url.startswith("http://127.0.0.1:") and ("127.0.0.1", web_port) in ports
        assert zmq_url.startswith("tcp://127.0.0.1:")
    finally:
        stop_server(proc, None)


@pytest.mark.parametrize("host", ["0.0.0.0"])
def test_another_address_only_when_asked(host):
    proc, zmq_url, web_url = start_server(host=host)
    try:
        ports = _listening(proc.pid)
        assert (host, int(web_url.rsplit(":", 1)[1].split("/")[0])) in ports and web_url.startswith(f"http://{host}:")
        assert zmq_url.startswith("tcp://127.0.0.1:")  # the command socket stays on loopback
    finally:
        stop_server(proc, None)
