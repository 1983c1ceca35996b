"""`twin relearn` against a server that is not a twin: it printed ten lines of the server's
HTML as "the twin refused" and blamed --machine."""

from __future__ import annotations

import http.server
import threading

from typer.testing import CliRunner

from drafttwin.cli import app


class _Page(http.server.BaseHTTPRequestHandler):
    def do_POST(self) -> None:  # noqa: N802  (http.server's name)
        body = b"<!DOCTYPE HTML>\n<html><body>" + b"<p>not a twin</p>\n" * 10 + b"</body></html>"
        self.send_response(501 if self.path.endswith("relearn") else 200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args: object) -> None:
        pass


def test_relearn_names_http_when_the_server_is_not_a_twin() -> None:
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Page)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        res = CliRunner().invoke(app, ["twin", "relearn", "--http",
                                       f"127.0.0.1:{server.server_port}", "--machine", "m1"])  # fmt: skip
    finally:
        server.shutdown()
        server.server_close()
    text = " ".join(res.output.split())
    assert res.exit_code == 2, res.output
    assert "--http" in text and "is not a twin" in text and "DOCTYPE" not in text
    assert "--machine" not in text.split("fix:")[0]
