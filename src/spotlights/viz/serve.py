"""``spotlights view --serve``: serve one self-contained page with Python's ``http.server``.

The page is the one ``spotlights view`` writes (plotly.js embedded, no network needed); it is
held in memory and answered at ``/`` (and ``/index.html``) until Ctrl-C. Only the standard
library is used. The server binds to the loopback interface by default, so the page is
reached from a laptop through an SSH tunnel (``ssh -L PORT:localhost:PORT user@host``);
another address is bound only when the caller names it (``--host``), with a warning, since
the server has no authentication. Requests must name the server in their ``Host`` header (an
address, ``localhost``, or the bound name): a web page cannot read the served cloud through DNS
rebinding (:func:`host_allowed`).
"""

from __future__ import annotations

import ipaddress
import socket
import sys
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from ..errors import SpotlightsError
from ..outputs import os_error_reason

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8000


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or a name) resolves to loopback addresses only."""
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False
    addresses = {info[4][0] for info in infos}
    return bool(addresses) and all(ipaddress.ip_address(a.split("%")[0]).is_loopback for a in addresses)


def allowed_host_names(host: str) -> frozenset[str]:
    """The names a request's ``Host`` header may carry for a server bound to ``host`` (lower case, no port), besides
    IP address literals, which are always accepted: ``localhost`` (and ``*.localhost``, checked by
    :func:`host_allowed`), and for an address other than loopback the name it was given and this machine's names."""
    names = {"localhost"}
    if not is_loopback(host):
        names |= {host.strip("[]").lower(), socket.gethostname().lower(), socket.getfqdn().lower()}
    return frozenset(n for n in names if n)


def host_allowed(header: str | None, allowed: frozenset[str]) -> bool:
    """Whether a request's ``Host`` header names this server: an IP address literal (a browser page can reach one
    only by its address, as any client can), ``localhost`` or ``*.localhost``, or one of ``allowed``; any port.

    DNS rebinding: a page of ``evil.example`` whose name is made to resolve to 127.0.0.1 reads what a loopback server
    answers, but its requests carry ``Host: evil.example``: refused. A missing header is refused too."""
    if not header:
        return False
    name = header.strip().lower()
    if name.startswith("["):  # [IPv6]:port
        name = name[1 : name.find("]")] if "]" in name else ""
    elif name.count(":") == 1:
        name = name.rsplit(":", 1)[0]
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        pass
    name = name.rstrip(".")
    return name in allowed or name.endswith(".localhost")


def make_server(body: bytes, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT) -> ThreadingHTTPServer:
    """A bound (not yet serving) HTTP server answering ``GET /`` with ``body`` (an HTML page), to requests whose
    ``Host`` header names it (:func:`host_allowed`; others get 403: no DNS rebinding).

    ``port`` 0 picks a free port (read it from ``server.server_address[1]``). Raises a
    one-line :class:`SpotlightsError` when the address cannot be bound.
    """
    allowed = allowed_host_names(host)

    class Handler(BaseHTTPRequestHandler):
        server_version = "spotlights-view"

        def _answer(self, send_body: bool) -> None:
            if not host_allowed(self.headers.get("Host"), allowed):
                self.send_error(403, "unknown Host: open the page at localhost or this machine's address")
                return
            if self.path.split("?", 1)[0] not in ("/", "/index.html"):
                self.send_error(404, "only / is served")
                return
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            if send_body:
                self.wfile.write(body)

        def do_GET(self):  # noqa: N802 (http.server's naming)
            self._answer(True)

        def do_HEAD(self):  # noqa: N802
            self._answer(False)

        def log_message(self, format, *args):  # no access log on stderr
            pass

    class Server(ThreadingHTTPServer):
        daemon_threads = True
        address_family = socket.AF_INET6 if ":" in host else socket.AF_INET

    try:
        return Server((host.strip("[]"), port), Handler)
    except OSError as exc:
        raise SpotlightsError(
            f"cannot serve on {host}:{port}: {os_error_reason(exc)} (choose another --port)"
        ) from None


def url_host(host: str) -> str:
    """``host`` as written in a URL (IPv6 addresses in brackets)."""
    h = host.strip("[]")
    return f"[{h}]" if ":" in h else h


def serve(body: bytes, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, quiet: bool = False) -> int:
    """Serve ``body`` at ``http://HOST:PORT/`` until Ctrl-C; returns 0 on Ctrl-C.

    Prints the URL and the ``ssh -L`` line that forwards the port to a laptop (unless ``quiet``).
    """
    server = make_server(body, host, port)
    port = server.server_address[1]
    loopback = is_loopback(host)
    if not loopback:
        print(
            f"spotlights: warning: serving on {host}, not on loopback: anyone who can reach this address "
            "can read the page (no authentication)",
            file=sys.stderr,
            flush=True,
        )
    if not quiet:
        print(f"serving the page at http://{url_host(host)}:{port}/ (Ctrl-C stops)")
        if loopback:
            print(f"from a laptop: ssh -L {port}:localhost:{port} user@host, then open http://localhost:{port}/")
        sys.stdout.flush()
    try:
        server.serve_forever(poll_interval=0.2)
    except KeyboardInterrupt as exc:
        if type(exc) is not KeyboardInterrupt:  # SIGTERM (the CLI's Terminated): its own exit code
            raise
        if not quiet:
            print("stopped", flush=True)
        return 0
    finally:
        server.server_close()
    return 0
