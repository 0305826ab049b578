#!/usr/bin/python3
"""A scripted client of a `needlesim live` session (tests/test_live.sh): the page, the MJPEG
stream, the WebSocket protocol (docs/live.md), hostile messages, a watcher, a reconnect, and
the end. Uses apt's python3-websockets (tools/quickstart.sh).

    live_client.py session URL      drive a session through the checks, then end it
    live_client.py token URL        the token checks of a session bound to 0.0.0.0
    live_client.py scripted URL     a live.script set-up: controls refused until it hands over
    live_client.py isodose URL DIR  brachytherapy: the needle in 35 mm, a seed dropped; the
                                    frames before and after it into DIR/before.jpg, after.jpg

Exits 0 when every check held, 1 with the failed check on stderr. No timing is asserted
beyond generous liveness timeouts."""
import asyncio
import json
import sys
import urllib.error
import urllib.parse
import urllib.request

import websockets

STATE_KEYS = {"t_s", "depth_m", "tip_m", "axial_force_n", "rtf", "fps", "score", "targets",
              "events"}
WAIT = 120.0  # seconds: liveness only (a sanitizer build steps slowly)


def check(cond, what):
    if not cond:
        raise AssertionError(what)


def http(url):
    try:
        with urllib.request.urlopen(url, timeout=WAIT) as r:
            return r.status, r.read(200000)
    except urllib.error.HTTPError as e:
        return e.code, b""


def mjpeg_first_frame(url):
    with urllib.request.urlopen(url, timeout=WAIT) as r:
        check("multipart/x-mixed-replace" in r.headers.get("Content-Type", ""), "MJPEG type")
        data = b""
        while b"\xff\xd9" not in data[data.find(b"\xff\xd8"):] or b"\xff\xd8" not in data:
            chunk = r.read(4096)
            check(chunk, "MJPEG stream ended before a frame")
            data += chunk
        check(b"Content-Type: image/jpeg" in data, "MJPEG part header")


class Client:
    """One WebSocket connection: frames counted (the latest kept), the latest state, roles and
    errors kept."""

    def __init__(self, ws):
        self.ws, self.frames, self.state, self.role, self.errors = ws, 0, None, None, []
        self.ended, self.jpeg = False, None

    async def pump(self, until, timeout=WAIT):
        """Reads messages until until(self) holds."""
        async def loop():
            while not until(self):
                m = await self.ws.recv()
                if isinstance(m, bytes):
                    check(m[:2] == b"\xff\xd8" and m[-2:] == b"\xff\xd9", "a JPEG frame (SOI, EOI)")
                    self.frames += 1
                    self.jpeg = m
                    continue
                d = json.loads(m)
                if "error" in d:
                    self.errors.append(d["error"])
                elif "role" in d:
                    self.role = d["role"]
                elif "depth_m" in d:
                    check(STATE_KEYS <= set(d), "state keys: missing %s" % (STATE_KEYS - set(d)))
                    self.state = d
                elif d.get("ended"):
                    self.ended = True
        await asyncio.wait_for(loop(), timeout)

    async def errors_after(self, text):
        n = len(self.errors)
        await self.ws.send(text)
        await self.pump(lambda c: len(c.errors) > n)
        return self.errors[-1]


def ws_url(url):
    u = urllib.parse.urlsplit(url)
    return "ws://%s/ws%s" % (u.netloc, "?" + u.query if u.query else "")


HOSTILE = [
    "", "null", "{}", "[1,2,3]", "{\"insert_speed\": \"fast\"}", "{\"insert_speed\": 1e999}",
    "{\"insert_speed\": 0.9}", "{\"base_velocity\": [0, 0]}", "{\"twist\": NaN}",
    "{\"unknown\": true}", "{\"pause\": 1}", "{\"end\": true} trailing", "{\"a\":" * 500,
    "\x00\x01\x02", "{\"insert_speed\": 0.01, \"insert_speed\": 0.02}", "x" * 5000,
    "{\"views\": \"echo\"}", "{\"views\": \"side,top,axis,trus\"}",
]


async def session(url):
    status, page = http(url)
    check(status == 200 and b"<html" in page and b"/ws" in page, "GET / serves the page")
    check(http(url.rstrip("/") + "/nope")[0] == 404, "404 for another path")
    check(http(url.rstrip("/") + "/../etc/passwd")[0] == 404, "404 for a file path")
    check(http(url.rstrip("/") + "/ws/x")[0] == 404, "404 below /ws")
    mjpeg_first_frame(url.rstrip("/") + "/stream.mjpg")
    async with websockets.connect(ws_url(url), max_size=None) as ws:
        c = Client(ws)
        await c.pump(lambda c: c.role is not None and c.state is not None and c.frames >= 2)
        check(c.role == "control", "the first client controls")
        d0 = c.state["depth_m"]
        await ws.send(json.dumps({"insert_speed": 0.02}))
        await c.pump(lambda c: c.state["depth_m"] > d0 + 0.004)
        for h in HOSTILE:
            err = await c.errors_after(h)
            check(isinstance(err, str) and err, "an error for %r" % h[:40])
        n = len(c.errors)
        await ws.send(b"\x01\x02")  # binary from a client
        await c.pump(lambda c: len(c.errors) > n)
        # the session survives: frames still come and the needle still moves
        f0, d1 = c.frames, c.state["depth_m"]
        await c.pump(lambda c: c.frames >= f0 + 3 and c.state["depth_m"] > d1)
        # a watcher's controls are refused
        async with websockets.connect(ws_url(url), max_size=None) as ws2:
            w = Client(ws2)
            await w.pump(lambda w: w.role is not None and w.frames >= 1)
            check(w.role == "watch", "the second client watches")
            err = await w.errors_after(json.dumps({"insert_speed": 0.0}))
            check("watching" in err, "a watcher's control is refused")
        await ws.send(json.dumps({"insert_speed": 0.0, "twist": 1.0}))
        await ws.send(json.dumps({"drop_seed": True}))
        await c.pump(lambda c: c.state["seeds"] >= 1)
        await ws.send(json.dumps({"pause": True}))
        await c.pump(lambda c: c.state["paused"])
        # the view changes the frames, not the physics: drawn again while paused
        await asyncio.sleep(0.3)
        await c.pump(lambda c: True)
        f0, t0, e0 = c.frames, c.state["t_s"], len(c.errors)
        await ws.send(json.dumps({"views": "cutaway3d,trus"}))
        await c.pump(lambda c: c.frames >= f0 + 1)
        check(c.state["t_s"] == t0 and len(c.errors) == e0, "a new view drawn while paused")
        await ws.send(json.dumps({"views": ""}))  # the scenario's own again
        await ws.send(json.dumps({"pause": False}))
        await c.pump(lambda c: not c.state["paused"])
        t_left = c.state["t_s"]
    # the controller left: the session goes on, and the next client to connect controls
    async with websockets.connect(ws_url(url), max_size=None) as ws:
        c = Client(ws)
        await c.pump(lambda c: c.role is not None and c.state is not None
                     and c.state["t_s"] > t_left)
        check(c.role == "control", "a reconnecting client takes over")
        await ws.send(json.dumps({"insert_speed": -0.01}))
        await c.pump(lambda c: c.frames >= 3)
        await ws.send(json.dumps({"end": True}))
        try:
            await c.pump(lambda c: c.ended)
        except websockets.ConnectionClosed:
            pass


async def token(url):
    u = urllib.parse.urlsplit(url)
    check(u.query.startswith("token=") and len(u.query) == 6 + 32, "the URL carries a token")
    bare = "http://%s/" % u.netloc
    check(http(url)[0] == 200, "GET / with the token")
    check(http(bare)[0] == 401, "GET / without the token: 401")
    check(http(bare + "?token=" + "0" * 32)[0] == 401, "a wrong token: 401")
    check(http(bare + "stream.mjpg")[0] == 401, "the stream without the token: 401")
    try:
        async with websockets.connect("ws://%s/ws" % u.netloc) as ws:
            await ws.recv()
        check(False, "a WebSocket without the token is refused")
    except websockets.InvalidStatusCode as e:
        check(e.status_code == 401, "WebSocket without the token: 401 (got %d)" % e.status_code)
    async with websockets.connect(ws_url(url), max_size=None) as ws:
        c = Client(ws)
        await c.pump(lambda c: c.frames >= 1)


async def scripted(url):
    async with websockets.connect(ws_url(url), max_size=None) as ws:
        c = Client(ws)
        await c.pump(lambda c: c.state is not None)
        if c.state["scripted"]:
            err = await c.errors_after(json.dumps({"insert_speed": 0.01}))
            check("script" in err, "controls are refused during the set-up: %s" % err)
        await c.pump(lambda c: not c.state["scripted"])
        d0 = c.state["depth_m"]
        await ws.send(json.dumps({"insert_speed": 0.02}))
        await c.pump(lambda c: c.state["depth_m"] > d0 + 0.002)
        await ws.send(json.dumps({"end": True}))
        try:
            await c.pump(lambda c: c.ended)
        except websockets.ConnectionClosed:
            pass


async def isodose(url, out):
    async with websockets.connect(ws_url(url), max_size=None) as ws:
        c = Client(ws)
        await c.pump(lambda c: c.state is not None and c.frames >= 2)
        await ws.send(json.dumps({"insert_speed": 0.02}))
        await c.pump(lambda c: c.state["depth_m"] > 0.035)
        await ws.send(json.dumps({"insert_speed": 0}))
        f = c.frames
        await c.pump(lambda c: c.frames >= f + 2)
        open(out + "/before.jpg", "wb").write(c.jpeg)
        await ws.send(json.dumps({"drop_seed": True}))
        await c.pump(lambda c: c.state["seeds"] >= 1)
        f = c.frames
        await c.pump(lambda c: c.frames >= f + 3)
        open(out + "/after.jpg", "wb").write(c.jpeg)
        await ws.send(json.dumps({"end": True}))
        try:
            await c.pump(lambda c: c.ended)
        except websockets.ConnectionClosed:
            pass


def main():
    mode, url = sys.argv[1], sys.argv[2]
    try:
        if mode == "isodose":
            asyncio.run(isodose(url, sys.argv[3]))
        else:
            run = {"session": session, "token": token, "scripted": scripted}[mode]
            asyncio.run(run(url))
    except (AssertionError, asyncio.TimeoutError, OSError, websockets.WebSocketException) as e:
        print("live_client %s: %s: %s" % (mode, type(e).__name__, e), file=sys.stderr)
        return 1
    print("live_client %s: ok" % mode)
    return 0


if __name__ == "__main__":
    sys.exit(main())
