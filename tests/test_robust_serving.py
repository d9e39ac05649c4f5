"""``view --serve`` checks the Host header: a page of another site whose name is made to resolve to 127.0.0.1 (DNS
rebinding) cannot read the served cloud; the addresses and names a user opens the page by still can."""

from __future__ import annotations

import http.client
import threading

import pytest

from spotlights.viz import serve

PAGE = b"<html>the cloud</html>"


@pytest.fixture
def server():
    srv = serve.make_server(PAGE, "127.0.0.1", 0)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield srv.server_address[1]
    srv.shutdown()
    srv.server_close()


def _get(port: int, host_header: str | None, method: str = "GET") -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    try:
        conn.putrequest(method, "/", skip_host=True)
        if host_header is not None:
            conn.putheader("Host", host_header)
        conn.endheaders()
        r = conn.getresponse()
        return r.status, r.read()
    finally:
        conn.close()


@pytest.mark.parametrize(
    "host", ["evil.example", "evil.example:8000", "localhost.evil.example", "127.0.0.1.nip.io:80", "", None]
)
def test_a_request_naming_another_site_is_refused(server, host):
    status, body = _get(server, host)
    assert status == 403 and PAGE not in body


@pytest.mark.parametrize(
    "host", ["127.0.0.1", "127.0.0.1:{port}", "localhost:{port}", "LOCALHOST:9000", "[::1]:8000", "app.localhost"]
)
def test_the_names_a_user_opens_the_page_by_are_served(server, host):
    status, body = _get(server, host.format(port=server))  # an ssh -L tunnel may arrive on another port
    assert status == 200 and body == PAGE
    assert _get(server, host.format(port=server), "HEAD")[0] == 200


def test_host_rules_by_hand():
    local = serve.allowed_host_names("127.0.0.1")
    assert local == frozenset({"localhost"})
    assert serve.host_allowed("10.0.0.5:8000", local)  # an address literal: no name to rebind
    assert not serve.host_allowed("attacker.test", local)
    lan = serve.allowed_host_names("0.0.0.0")  # bound beyond loopback: this machine's own names too
    import socket

    assert serve.host_allowed(f"{socket.gethostname()}:8000", lan)
    assert not serve.host_allowed("attacker.test:8000", lan)
