#!/usr/bin/python3
"""A `needlesim live` session driven from a real browser (tests/test_browser.sh): Debian's
Chromium, headless, over the DevTools protocol on a pipe (--remote-debugging-pipe: commands
written to its fd 3, answers and events read from its fd 4, each one JSON message ended by a
NUL byte). Python's standard library only.

    live_browser.py URL WORKDIR [SCREENSHOT_DIR]

Loads the page, waits for frames (the #view image decoded and replaced, #fps shown), holds
ArrowUp for 2 s and presses Space as key events, checks that the HUD's #depth grew and that the
seed reached the server, clicks #end and waits for the page to say the session has ended.
With SCREENSHOT_DIR it saves PNGs of the page there: mid-insertion and after the seed.

Prints one line per check, `ok    ...` or `FAIL  ...: why`, stopping at the first failure
(each check needs the ones before it). Exits 0 when every check held. Chromium's process group
id goes to WORKDIR/chromium.pgid (the caller's trap kills it); its stderr to
WORKDIR/chromium.log."""
import base64
import fcntl
import json
import os
import re
import select
import signal
import subprocess
import sys
import time

WAIT = 120.0  # seconds: liveness only (the session steps slowly on a loaded machine)
VIEWPORT = (1344, 700)  # the view (960 px) and the HUD beside it, as a trainee's window
SHOT_SCALE = 0.75  # screenshots of 1008 px by ~450: about 250 KB each


class Failed(Exception):
    pass


def check(cond, what):
    if not cond:
        raise Failed(what)
    print("ok    browser: " + what, flush=True)


class Chromium:
    """The browser, one DevTools connection to it over the pipe, one page session."""

    def __init__(self, workdir):
        cmd_r, self.cmd_w = os.pipe()
        self.res_r, res_w = os.pipe()

        def fds():  # in the child: the pipe's ends as fds 3 and 4, whatever numbers they had
            a = fcntl.fcntl(cmd_r, fcntl.F_DUPFD, 10)
            b = fcntl.fcntl(res_w, fcntl.F_DUPFD, 10)
            os.dup2(a, 3)
            os.dup2(b, 4)

        args = ["chromium", "--headless=new", "--remote-debugging-pipe",
                # root in CI: Chromium refuses its sandbox to root; the page is our own
                "--no-sandbox",
                "--user-data-dir=" + os.path.join(workdir, "profile"),
                "--no-first-run", "--no-default-browser-check", "--disable-extensions",
                "--disable-background-networking", "--disable-sync", "--disable-dev-shm-usage",
                "--disable-gpu", "--mute-audio", "--hide-scrollbars",
                # a headless page is never in front: keep its timers and frames unthrottled
                "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                "--disable-backgrounding-occluded-windows",
                "--window-size=%d,%d" % VIEWPORT, "about:blank"]
        with open(os.path.join(workdir, "chromium.log"), "wb") as log:
            self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                         pass_fds=(3, 4), preexec_fn=fds,
                                         start_new_session=True)
        self.pgid_file = os.path.join(workdir, "chromium.pgid")
        with open(self.pgid_file, "w") as f:
            f.write("%d\n" % self.proc.pid)
        os.close(cmd_r)
        os.close(res_w)
        self.buf, self.next_id, self.session, self.events = b"", 1, None, []

    def _read(self, deadline):
        """The next message from the browser, or None at the deadline."""
        while b"\0" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.res_r], [], [], left)[0]:
                return None
            chunk = os.read(self.res_r, 1 << 20)
            if not chunk:
                raise Failed("Chromium closed the pipe (exit %s)" % self.proc.poll())
            self.buf += chunk
        msg, self.buf = self.buf.split(b"\0", 1)
        return json.loads(msg)

    def call(self, method, page=True, timeout=WAIT, **params):
        """Sends a command (to the page's session unless page=False); its result."""
        i, self.next_id = self.next_id, self.next_id + 1
        m = {"id": i, "method": method, "params": params}
        if page:
            m["sessionId"] = self.session
        os.write(self.cmd_w, json.dumps(m).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            r = self._read(deadline)
            if r is None:
                raise Failed("%s: no answer in %.0f s" % (method, timeout))
            if r.get("id") == i:
                if "error" in r:
                    raise Failed("%s: %s" % (method, r["error"].get("message")))
                return r.get("result", {})
            if "method" in r:
                self.events.append(r)

    def wait_event(self, method, timeout=WAIT):
        """Waits for an event of the page's session (kept from earlier reads too)."""
        deadline = time.monotonic() + timeout
        while True:
            for e in self.events:
                if e["method"] == method and e.get("sessionId") == self.session:
                    self.events.remove(e)
                    return e.get("params", {})
            r = self._read(deadline)
            if r is None:
                raise Failed("%s: not within %.0f s" % (method, timeout))
            if "method" in r:
                self.events.append(r)

    def js(self, expr):
        """The value of a page expression (JSON-able)."""
        r = self.call("Runtime.evaluate", expression=expr, returnByValue=True)
        if "exceptionDetails" in r:
            d = r["exceptionDetails"]
            raise Failed("page script: %s" % d.get("exception", {}).get("description", d))
        return r["result"].get("value")

    def key(self, kind, key, code, vk, text=None):
        p = {"type": kind, "key": key, "code": code, "windowsVirtualKeyCode": vk,
             "nativeVirtualKeyCode": vk}
        if text and kind == "keyDown":
            p["text"] = text
        self.call("Input.dispatchKeyEvent", **p)

    def screenshot(self, path):
        """A PNG of the page's content (its <main>), scaled to keep the file small."""
        box = self.js("""(() => { const r = document.querySelector("main").getBoundingClientRect();
                        return {x: r.x, y: r.y, width: r.width, height: r.height}; })()""")
        box["scale"] = SHOT_SCALE
        png = base64.b64decode(self.call("Page.captureScreenshot", format="png",
                                         clip=box)["data"])
        with open(path, "wb") as f:
            f.write(png)
        print("saved %s (%d KB)" % (path, len(png) // 1024), flush=True)

    def close(self):
        try:
            self.call("Browser.close", page=False, timeout=10)
        except Failed:
            pass
        os.close(self.cmd_w)  # Chromium exits when its pipe closes
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            pass
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)  # its renderer and helpers too
        except ProcessLookupError:
            pass
        self.proc.wait()
        os.unlink(self.pgid_file)


HUD = """(() => { const $ = (id) => document.getElementById(id), v = $("view");
  return {src: v.src, w: v.complete ? v.naturalWidth : 0, fps: $("fps").textContent,
          depth: $("depth").textContent, seeds: $("seeds").textContent,
          role: $("role").textContent, status: $("status").textContent}; })()"""


def mm(text):
    m = re.fullmatch(r"(-?[0-9.]+) mm", text)
    return float(m.group(1)) if m else None


def wait_hud(b, cond, what, timeout=WAIT):
    """Polls the HUD until cond(hud) holds; the HUD then."""
    deadline = time.monotonic() + timeout
    while True:
        h = b.js(HUD)
        if cond(h):
            return h
        if time.monotonic() > deadline:
            raise Failed("%s: not within %.0f s (HUD: %s)" % (what, timeout, h))
        time.sleep(0.05)


def drive(b, url, shots):
    target = next(t for t in b.call("Target.getTargets", page=False)["targetInfos"]
                  if t["type"] == "page")
    b.session = b.call("Target.attachToTarget", page=False, targetId=target["targetId"],
                       flatten=True)["sessionId"]
    b.call("Page.enable")
    b.call("Emulation.setFocusEmulationEnabled", enabled=True)  # key events reach the page
    b.call("Emulation.setDeviceMetricsOverride", width=VIEWPORT[0], height=VIEWPORT[1],
           deviceScaleFactor=1, mobile=False)
    r = b.call("Page.navigate", url=url)
    check("errorText" not in r, "the page loads (%s)" % r.get("errorText", url))
    b.wait_event("Page.loadEventFired")
    h = wait_hud(b, lambda h: h["role"] != "-", "the page's WebSocket connects")
    check(h["role"] == "controlling", "the page's WebSocket controls the session")

    # frames: the view's image replaced by decoded JPEGs, the HUD filled in
    srcs = set()

    def frames(h):
        if h["src"].startswith("blob:") and h["w"] > 0:
            srcs.add(h["src"])
        return len(srcs) >= 5 and mm(h["depth"]) is not None and float(h["fps"]) > 0

    h = wait_hud(b, lambda h: h["fps"] != "-" and frames(h), "5 frames shown")
    check(True, "frames arrive: 5 images shown, %d px wide, %s frames a second" %
          (h["w"], h["fps"]))
    d0 = mm(h["depth"])

    # hold ArrowUp for 2 s: insertion at the page's speed while held
    t0 = time.monotonic()
    b.key("rawKeyDown", "ArrowUp", "ArrowUp", 38)
    shot = shots is None
    while time.monotonic() - t0 < 2.0:
        if not shot and time.monotonic() - t0 > 1.5:
            b.screenshot(os.path.join(shots, "live-inserting.png"))
            shot = True
        time.sleep(0.02)
    b.key("keyUp", "ArrowUp", "ArrowUp", 38)
    print("      ArrowUp held for %.2f s" % (time.monotonic() - t0), flush=True)

    # the HUD's depth grows (the state shown lags the key by the session's latency)
    h = wait_hud(b, lambda h: (mm(h["depth"]) or d0) > d0 + 0.1, "the depth grows")
    check(True, "the HUD's depth grew: %.1f mm -> %s" % (d0, h["depth"]))

    # space: a seed at the tip (or, with the tip not yet in the tissue, the server's answer)
    seeds0, status0 = h["seeds"], h["status"]
    b.key("keyDown", " ", "Space", 32, text=" ")
    b.key("keyUp", " ", "Space", 32)
    h = wait_hud(b, lambda h: h["seeds"].startswith("1 of") or
                 (h["status"] != status0 and "drop_seed" in h["status"]),
                 "Space reaches the server")
    check(True, "Space reached the server: seeds %s -> %s%s" %
          (seeds0, h["seeds"], ", " + h["status"] if h["status"] else ""))
    if shots is not None:
        b.screenshot(os.path.join(shots, "live-seed.png"))

    # 4: the 3D cutaway and the ultrasound side by side ({"views": ...}); frames keep coming
    b.key("keyDown", "4", "Digit4", 52, text="4")
    b.key("keyUp", "4", "Digit4", 52)
    check(b.js('document.querySelectorAll("button.view")[3].style.fontWeight') == "bold",
          "key 4 chooses the view on the page")
    n0 = len(srcs)
    h = wait_hud(b, lambda h: frames(h) and len(srcs) >= n0 + 5 and "views" not in h["status"],
                 "frames in the chosen view")
    check(True, "key 4: %d more frames, no error from the server" % (len(srcs) - n0))
    if shots is not None:
        time.sleep(0.5)
        b.screenshot(os.path.join(shots, "live-views.png"))

    # End, clicked with the mouse
    r = b.js("""(() => { const e = document.getElementById("end"); e.scrollIntoView();
               const r = e.getBoundingClientRect();
               return {x: r.x + r.width / 2, y: r.y + r.height / 2}; })()""")
    for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
        b.call("Input.dispatchMouseEvent", type=kind, x=r["x"], y=r["y"], button="left",
               clickCount=1)
    h = wait_hud(b, lambda h: h["status"] == "the session has ended", "the session ends")
    check(True, "End clicked: the page says the session has ended")


def main():
    url, workdir = sys.argv[1], sys.argv[2]
    shots = sys.argv[3] if len(sys.argv) > 3 else None
    b = None
    try:
        b = Chromium(workdir)
        v = b.call("Browser.getVersion", page=False)
        print("browser: %s over --remote-debugging-pipe" % v["product"], flush=True)
        drive(b, url, shots)
    except (Failed, OSError, ValueError, KeyError, StopIteration) as e:
        print("FAIL  browser: %s: %s" % (type(e).__name__, e), flush=True)
        return 1
    finally:
        if b is not None:
            b.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
