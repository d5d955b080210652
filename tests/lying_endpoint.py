"""A hostile endpoint for tests: a rewriting HTTP proxy in front of the real loopback Hub.

Plain HTTP on a lab network is a documented setup, so an attacker in the middle (or a compromised
server) can change any request or answer. :class:`LyingEndpoint` forwards every request to the real
server and lets a test rewrite the request path and the answer's status, headers and body on the way,
or answer a request itself (``serve``: a compromised server, e.g. the target of a redirect it sent).
Everything else is real: the unmodified huggingface_hub client talks to it as to any Hub.
"""

from __future__ import annotations

import http.client
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import urlsplit

#: (method, path) -> new path
PathRewrite = Callable[[str, str], str]
#: (method, path, status, headers, body) -> (status, headers, body)
AnswerRewrite = Callable[[str, str, int, dict[str, str], bytes], tuple[int, dict[str, str], bytes]]
#: (method, path) -> (status, headers, body) answered without asking the real server, or None to forward
Serve = Callable[[str, str], "tuple[int, dict[str, str], bytes] | None"]

_HOP_BY_HOP = {"connection", "keep-alive", "transfer-encoding", "content-length", "proxy-connection", "upgrade"}


class LyingEndpoint:
    """``with LyingEndpoint(upstream, rewrite_path=..., rewrite_answer=..., serve=...) as lie: HF_ENDPOINT=lie.endpoint``."""

    def __init__(
        self,
        upstream: str,
        *,
        rewrite_path: PathRewrite | None = None,
        rewrite_answer: AnswerRewrite | None = None,
        serve: Serve | None = None,
    ):
        self.upstream = urlsplit(upstream)
        self.serve = serve or (lambda method, path: None)
        self.rewrite_path = rewrite_path or (lambda method, path: path)
        self.rewrite_answer = rewrite_answer or (lambda method, path, status, headers, body: (status, headers, body))
        self.requests: list[tuple[str, str]] = []
        proxy = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args) -> None:
                pass

            def _forward(self) -> None:
                length = int(self.headers.get("Content-Length") or 0)
                body = self.rfile.read(length) if length else b""
                own = proxy.serve(self.command, self.path)
                if own is not None:  # a compromised server's own answer (a HEAD announces the body's length)
                    proxy.requests.append((self.command, self.path))
                    status, out_headers, data = own
                    self.send_response(status)
                    for k, v in out_headers.items():
                        self.send_header(k, v)
                    self.send_header("Content-Length", str(len(data)))
                    self.end_headers()
                    if self.command != "HEAD":
                        self.wfile.write(data)
                    return
                path = proxy.rewrite_path(self.command, self.path)
                proxy.requests.append((self.command, path))
                conn = http.client.HTTPConnection(proxy.upstream.hostname, proxy.upstream.port, timeout=60)
                headers = {k: v for k, v in self.headers.items() if k.lower() not in _HOP_BY_HOP and k.lower() != "host"}
                conn.request(self.command, path, body=body or None, headers=headers)
                answer = conn.getresponse()
                data = answer.read()
                head_length = answer.getheader("Content-Length") or "0"  # a HEAD answer names the file's size
                status, out_headers, data = proxy.rewrite_answer(
                    self.command,
                    path,
                    answer.status,
                    {k: v for k, v in answer.getheaders() if k.lower() not in _HOP_BY_HOP},
                    data,
                )
                conn.close()
                self.send_response(status)
                for k, v in out_headers.items():
                    self.send_header(k, v)
                self.send_header("Content-Length", head_length if self.command == "HEAD" else str(len(data)))
                self.end_headers()
                if self.command != "HEAD":
                    self.wfile.write(data)

            do_GET = do_HEAD = do_POST = do_PUT = do_DELETE = _forward

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.endpoint = f"http://127.0.0.1:{self.server.server_address[1]}"
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()

    def __enter__(self) -> LyingEndpoint:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
