"""Who the live view answers: real HTTP requests against a running session (the bundled
clip played at 30 frames/s, as in tests/test_view.py), on loopback and off it.

Counts asserted: the status of each request, the re-zero events in the session's
report (a refused command must leave none), and the sidecar's ``rejected_requests``.
"""

from __future__ import annotations

import http.client
import json
import logging

import pytest
from test_view import SAMPLES, Running, _until

from camwhisker.bench.view import headless_chromium, quit_chromium
from camwhisker.live.view import is_loopback
from camwhisker.sensor.file import load_sensor

# Plays video at camera rate or times a live loop: run alone (README's test command).
pytestmark = pytest.mark.timing


@pytest.fixture(scope="module")
def sensor():
    return load_sensor(SAMPLES / "nominal.sensor.toml")


def _ask(port: int, method: str, path: str, **headers) -> int:
    """The status of one request to 127.0.0.1:port with exactly these headers (Host too)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        conn.request(method, path, headers={k.replace("_", "-"): v for k, v in headers.items()})
        response = conn.getresponse()
        response.read()
        return response.status
    finally:
        conn.close()


def _rezeros(run) -> int:
    return sum(e["event"] == "rezero" for e in run.session.report.events)


def test_foreign_origin_or_host_is_refused_and_counted(tmp_path, sensor):
    out = tmp_path / "live.csv"
    run = Running(sensor, out, duration_s=600)
    port = run.session.view.port
    own = f"127.0.0.1:{port}"
    try:
        _until(lambda: run.session.report.rows >= 5, "5 rows")
        refused = [
            # Another page in the browser: its own origin.
            _ask(port, "POST", "/command/rezero", Host=own, Origin="http://evil.example.com"),
            # No origin at all (a form or script that hides it).
            _ask(port, "POST", "/command/rezero", Host=own),
            # A foreign Referer where no Origin is sent.
            _ask(port, "POST", "/command/redetect", Host=own, Referer="http://evil.example.com/"),
            # DNS rebinding: the attacker's name resolving to 127.0.0.1, its own origin.
            _ask(port, "POST", "/command/rezero", Host=f"evil.example.com:{port}",
                 Origin=f"http://evil.example.com:{port}"),
            _ask(port, "GET", "/", Host=f"evil.example.com:{port}"),
            _ask(port, "GET", "/state?after=-1", Host=f"evil.example.com:{port}"),
            _ask(port, "GET", "/", Host="127.0.0.1:1"),  # another port's origin
        ]
        assert refused == [403] * 7
        # 30 rows later still no event: a refused command is never queued.
        rows = run.session.report.rows
        _until(lambda: run.session.report.rows >= rows + 30, "30 more rows")
        assert _rezeros(run) == 0
        # The page's own origin (by Origin, or by Referer without it) on each of its names.
        assert _ask(port, "POST", "/command/rezero", Host=own, Origin=f"http://{own}") == 200
        assert _ask(port, "POST", "/command/rezero", Host=f"localhost:{port}",
                    Referer=f"http://localhost:{port}/") == 200  # fmt: skip
        assert _ask(port, "GET", "/", Host=f"[::1]:{port}") == 200
        _until(lambda: _rezeros(run) == 2, "the two accepted re-zeros")
    finally:
        run.finish()
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["view"]["rejected_requests"] == 7  # every refusal counted, none else
    assert [e["event"] for e in meta["events"]] == ["rezero", "rezero"]


def test_off_loopback_every_request_needs_the_printed_token(tmp_path, sensor, caplog):
    out = tmp_path / "live.csv"
    caplog.set_level(logging.INFO, logger="camwhisker.live.loop")
    run = Running(sensor, out, duration_s=600, view_host="0.0.0.0")
    view, port = run.session.view, run.session.view.port
    try:
        _until(lambda: run.session.report.rows >= 5, "5 rows")
        printed = [r.getMessage() for r in caplog.records if "view at" in r.getMessage()]
        assert printed == [f"view at http://0.0.0.0:{port}/?token={view.token}"]  # once
        assert len(view.token) >= 32  # 24 random bytes, URL-safe base64
        own, token = f"127.0.0.1:{port}", f"token={view.token}"
        origin = f"http://{own}"
        without = [
            _ask(port, "GET", "/", Host=own),
            _ask(port, "GET", "/state?after=-1", Host=own),
            _ask(port, "GET", "/frame.jpg?after=-1&token=wrong", Host=own),
            _ask(port, "POST", "/command/rezero", Host=own, Origin=origin),
        ]
        assert without == [401] * 4
        # With it: the page, the state, a command; from an address typed in (any IP).
        assert _ask(port, "GET", f"/?{token}", Host=own) == 200
        assert _ask(port, "GET", f"/state?after=-1&{token}", Host=f"192.0.2.7:{port}") == 200
        assert _ask(port, "POST", f"/command/rezero?{token}", Host=own, Origin=origin) == 200
        # The token does not make a foreign name or origin acceptable.
        assert _ask(port, "GET", f"/?{token}", Host=f"evil.example.com:{port}") == 403
        assert _ask(port, "POST", f"/command/rezero?{token}", Host=own,
                    Origin="http://evil.example.com") == 403  # fmt: skip
        _until(lambda: _rezeros(run) == 1, "the one accepted re-zero")
        _page_works_with_the_token(run, f"http://{own}/?{token}")
    finally:
        run.finish()
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["view"]["rejected_requests"] == 6
    assert "token" not in meta["view"]["url"]  # the sidecar never holds the credential
    assert [e["event"] for e in meta["events"]] == ["rezero", "rezero"]


def _page_works_with_the_token(run, url):
    """The page in headless Chromium, opened from the printed URL: pictures, plots and
    the re-zero button all pass the token on."""
    driver = headless_chromium()
    try:
        driver.get(url)
        js = driver.execute_script
        _until(lambda: js("return window.view.pictures") >= 2, "two pictures")
        _until(lambda: len(js("return window.view.rows")) >= 10, "ten rows plotted")
        driver.find_element("id", "rezero").click()
        _until(lambda: _rezeros(run) == 2, "the page's re-zero")
        _until(lambda: js("return document.getElementById('message').textContent")
               == "rezero sent", "the page's acknowledgement")  # fmt: skip
    finally:
        quit_chromium(driver)


@pytest.mark.parametrize("host, loop", [("127.0.0.1", True), ("127.1.2.3", True),
                                        ("localhost", True), ("::1", True), ("0.0.0.0", False),
                                        ("192.168.1.20", False), ("::", False)])  # fmt: skip
def test_loopback_addresses(host, loop):
    assert is_loopback(host) is loop
