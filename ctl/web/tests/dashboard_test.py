"""The dashboard in a real headless browser (issue 36).

`foc-ctl dashboard --simulate` is started on a free port (the simulated
drive at 4 times real time); Debian's Chromium is driven over WebDriver
(chromedriver, W3C protocol, plain HTTP from the standard library). The
test checks that the page loads, that a signal is plotted live, that a
console command round-trips, that a refusal is shown with its reason, and
that the setup wizard completes (offsets, sensor check, identification,
tuning report, save), that the configuration tree refuses a bad value with
its reason and applies a good one, and that a scope capture is plotted. Screenshots go to $OUT (default out/dashboard) for a
person to look at.

Environment: FOC_CTL (the foc-ctl binary), CHROMIUM, CHROMEDRIVER, OUT.
Run by `cargo xtask dashboard` and `cargo xtask test`.
"""

import base64
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import unittest
import urllib.error
import urllib.request

FOC_CTL = os.environ.get("FOC_CTL", "target/debug/foc-ctl")
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("CHROMEDRIVER", "/usr/bin/chromedriver")
OUT = os.environ.get("OUT", "out/dashboard")
ELEMENT = "element-6066-11e4-a52e-4f735466cecf"


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port(port, proc, what, timeout_s=60):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise RuntimeError(f"{what} exited ({proc.returncode})")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    raise RuntimeError(f"{what} did not listen within {timeout_s} s")


class WebDriver:
    """The few W3C WebDriver calls the test needs."""

    def __init__(self, port):
        self.base = f"http://127.0.0.1:{port}"
        self.profile = tempfile.mkdtemp(prefix="foc-dash-chromium-")
        caps = {
            "capabilities": {
                "alwaysMatch": {
                    "browserName": "chrome",
                    "goog:chromeOptions": {
                        "binary": CHROMIUM,
                        "args": [
                            "--headless=new",
                            "--no-sandbox",
                            "--disable-gpu",
                            "--disable-dev-shm-usage",
                            "--disable-quic",
                            "--no-first-run",
                            "--disable-background-networking",
                            "--disable-component-update",
                            "--disable-sync",
                            "--window-size=1500,1300",
                            f"--user-data-dir={self.profile}",
                        ],
                    },
                }
            }
        }
        self.sid = self._call("POST", "/session", caps)["sessionId"]

    def _call(self, method, path, body=None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.base + path, data=data, method=method)
        req.add_header("Content-Type", "application/json")
        try:
            with urllib.request.urlopen(req, timeout=120) as r:
                return json.loads(r.read() or b"{}").get("value")
        except urllib.error.HTTPError as e:
            raise RuntimeError(f"WebDriver {method} {path}: {e.read()[:500]!r}") from e

    def s(self, method, path, body=None):
        return self._call(method, f"/session/{self.sid}{path}", body)

    def get(self, url):
        self.s("POST", "/url", {"url": url})

    def js(self, script, *args):
        return self.s("POST", "/execute/sync", {"script": script, "args": list(args)})

    def find(self, css):
        return self.s("POST", "/element", {"using": "css selector", "value": css})[ELEMENT]

    def click(self, css):
        self.s("POST", f"/element/{self.find(css)}/click", {})

    def type(self, css, text, enter=False):
        el = self.find(css)
        self.s("POST", f"/element/{el}/clear", {})
        self.s("POST", f"/element/{el}/value", {"text": text + ("\ue007" if enter else "")})

    def text(self, css):
        return self.s("GET", f"/element/{self.find(css)}/text")

    def screenshot(self, path):
        png = base64.b64decode(self.s("GET", "/screenshot"))
        with open(path, "wb") as f:
            f.write(png)

    def quit(self):
        try:
            self.s("DELETE", "")
        finally:
            shutil.rmtree(self.profile, ignore_errors=True)


def until(pred, timeout_s, what, every_s=0.1):
    end = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < end:
        last = pred()
        if last:
            return last
        time.sleep(every_s)
    raise AssertionError(f"{what}: not within {timeout_s} s (last: {last!r})")


class Dashboard(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        os.makedirs(OUT, exist_ok=True)
        cls.port = free_port()
        cls.log = open(os.path.join(OUT, "foc-ctl.log"), "w")
        cls.dash = subprocess.Popen(
            [FOC_CTL, "dashboard", "--simulate", "--time-scale", "4", "--listen", f"127.0.0.1:{cls.port}"],
            stdout=cls.log,
            stderr=cls.log,
        )
        wait_port(cls.port, cls.dash, "foc-ctl dashboard")
        cls.dport = free_port()
        cls.driver_proc = subprocess.Popen(
            [CHROMEDRIVER, f"--port={cls.dport}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        wait_port(cls.dport, cls.driver_proc, "chromedriver")
        cls.wd = WebDriver(cls.dport)
        cls.wd.get(f"http://127.0.0.1:{cls.port}/")

    @classmethod
    def tearDownClass(cls):
        try:
            cls.wd.quit()
        finally:
            for p in (cls.driver_proc, cls.dash):
                p.terminate()
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
            cls.log.close()

    def console(self, line):
        before = self.wd.js("return document.getElementById('console-out').children.length")
        self.wd.type("#console-input", line)
        self.wd.click("#console-form button")
        until(
            lambda: self.wd.js("return document.getElementById('console-out').children.length") >= before + 2,
            30,
            f"the console's answer to `{line}`",
        )
        return self.wd.js(
            "const o = document.getElementById('console-out').children;"
            "const t = o[o.length - 1]; return [t.textContent, t.className];"
        )

    def test_1_the_page_loads_and_plots_live(self):
        until(lambda: self.wd.text("#mode") == "Disabled", 30, "the drive's mode on the page")
        self.assertEqual(self.wd.text("#calibrated"), "no")
        # Samples arrive and are drawn.
        until(lambda: self.wd.js("return window.dash.plotted") > 100, 30, "samples plotted")
        n0, f0 = self.wd.js("return [window.dash.plotted, window.dash.frames]")
        time.sleep(1.0)
        n1, f1 = self.wd.js("return [window.dash.plotted, window.dash.frames]")
        # 100 Hz at 4 times real time: about 400 samples a second (the
        # bound leaves room for a slow machine: the drive's divider, below,
        # is the exact check).
        self.assertGreater(n1 - n0, 20, "samples plotted in 1 s")
        self.assertGreater(f1 - f0, 2, "redraws in 1 s")
        info = self.wd.text("#rate-info")
        self.assertIn("every 200 periods", info)
        self.assertIn(", 0 lost", info)
        # Pick another signal: the plot gets its series.
        self.wd.click("#signals input[value='bus']")
        until(lambda: self.wd.js("return window.dash.plot.series.length") == 4, 10, "the bus series")
        bus = self.wd.js("const c = window.dash.cols.bus; return c[c.length - 1]")
        self.assertAlmostEqual(bus, 24.0, delta=0.5)
        self.wd.screenshot(os.path.join(OUT, "1-live.png"))

    def test_2_a_command_round_trips_and_a_refusal_shows_its_reason(self):
        text, cls = self.console("param pole-pairs")
        self.assertIn("pole-pairs         7", text)
        self.assertNotIn("refused", cls)
        text, cls = self.console("mode torque 500")
        self.assertIn("`iq_a` = 500 A is out of range (allowed: -10 .. 10 A, the current limit)", text)
        self.assertIn("refused", cls)
        text, cls = self.console("mode velocity 20")
        self.assertIn("refused by the device: not calibrated", text)
        self.wd.screenshot(os.path.join(OUT, "2-console.png"))

    def test_3_the_wizard_refuses_a_limit_then_completes(self):
        # Above the board's 10 A: the motor step shows the refusal.
        self.wd.type("#max-current", "50")
        self.wd.click("#wizard-run")
        until(lambda: "stopped" in self.wd.text("#wizard-done"), 30, "the wizard stopping")
        motor = self.wd.text("#step-motor .result")
        self.assertIn("above this board's hardware limit of 10 A", motor)
        self.assertEqual(self.wd.text("#step-motor .state"), "failed")
        self.wd.screenshot(os.path.join(OUT, "3-wizard-refused.png"))
        # A motor file with a bad value: named, nothing sent.
        self.wd.type("#max-current", "")
        self.wd.click("#step-motor details summary")
        self.wd.type("#motor-file", 'name = "x"\nsource = "y"\npole_pairs = 0\n')
        self.wd.click("#wizard-run")
        until(lambda: "stopped" in self.wd.text("#wizard-done"), 30, "the wizard stopping")
        motor = self.wd.text("#step-motor .result")
        self.assertIn("the motor file", motor)
        self.assertIn("nothing was sent", motor)
        self.wd.type("#motor-file", "")
        # Nameplate values and a good limit: every step to the end.
        self.wd.type("#step-motor input[data-key='motor.pole_pairs']", "7")
        self.wd.type("#max-current", "8")
        self.wd.click("#wizard-run")
        # A step is seen running with its progress.
        until(lambda: self.wd.text("#step-identification .state") == "running", 120, "the identification running")
        until(lambda: self.wd.text("#wizard-done") != "", 300, "the wizard's end", every_s=0.5)
        done = self.wd.text("#wizard-done")
        states = {s: self.wd.text(f"#step-{s} .state") for s in ["motor", "offsets", "sensor", "identification", "tuning", "save"]}
        results = {s: self.wd.text(f"#step-{s} .result") for s in states}
        self.wd.screenshot(os.path.join(OUT, "4-wizard-done.png"))
        self.assertIn("setup complete", done, f"{states}\n{results}")
        self.assertEqual(set(states.values()), {"done"}, results)
        self.assertIn("the sensor follows the field", results["sensor"])
        self.assertIn("r ", results["identification"])
        self.assertIn("overshoot", results["tuning"])
        self.assertIn("`limits.max_current_a` = 8, `motor.pole_pairs` = 7 applied", results["motor"])
        self.assertRegex(results["motor"], r"max-current +8 A")
        until(lambda: self.wd.text("#calibrated") == "yes", 10, "calibrated on the page")
        # Closed loop now: a velocity command runs, and is plotted.
        text, _ = self.console("mode velocity 20")
        self.assertIn("ok:", text)
        until(
            lambda: (self.wd.js("const c = window.dash.cols.velocity; return c[c.length - 1]") or 0) > 18,
            20,
            "the velocity on the plot",
        )
        # The open page keeps the link alive: still running 2 s later (8 s
        # of the drive's time, the link watchdog 1 s).
        time.sleep(2.0)
        self.assertEqual(self.wd.text("#mode"), "Velocity")
        self.wd.screenshot(os.path.join(OUT, "5-velocity.png"))
        # The Disable button.
        self.wd.click("#disable")
        until(lambda: self.wd.text("#mode") == "Disabled", 10, "disabled by the button")

    def test_4_the_configuration_tree_and_a_scope_capture(self):
        until(lambda: (self.wd.js("return window.dash.configRows") or 0) > 30, 30, "the configuration tree")
        key = "#config-tree input[data-key='limits.max_current_a']"
        unit = self.wd.js(
            "return document.querySelector(arguments[0]).closest('tr').querySelector('.unit').textContent", key
        )
        self.assertEqual(unit, "A")
        # Above the board's limit: refused, with the reason; nothing changed.
        self.wd.type(key, "50", enter=True)
        until(lambda: "hardware limit of 10 A" in self.wd.text("#config-msg"), 30, "the refusal")
        self.assertIn("refused", self.wd.js("return document.getElementById('config-msg').className"))
        # A value the host's checks refuse, named by its key (its section
        # opened first: the tree shows the limits open).
        self.wd.click("details[data-section='motor'] summary")
        self.wd.type("#config-tree input[data-key='motor.r_ohm']", "-1", enter=True)
        until(lambda: "motor.r_ohm" in self.wd.text("#config-msg"), 30, "the host's check")
        self.assertIn("nothing was sent", self.wd.text("#config-msg"))
        self.wd.js("document.getElementById('config').scrollIntoView()")
        self.wd.screenshot(os.path.join(OUT, "6-config-refused.png"))
        # A good one: applied, and in force.
        self.wd.type(key, "9", enter=True)
        until(lambda: "applied" in self.wd.text("#config-msg"), 30, "the change applied")
        text, _ = self.console("limits")
        self.assertIn("max current      9 A", text)
        # A scope capture triggered by a command, plotted.
        self.wd.click("#scope-arm")
        until(lambda: "waiting for the trigger" in self.wd.text("#scope-state"), 30, "the scope armed")
        text, _ = self.console("mode velocity 10")
        self.assertIn("ok:", text, self.console("faults")[0])
        until(lambda: self.wd.js("return window.dash.scopePoints || 0") == 400, 30, "the capture plotted")
        names = self.wd.js("return window.dash.scope.channels.map(c => c.name)")
        self.assertEqual(len(names), 4, names)
        self.assertEqual(self.wd.js("return window.dash.scopePlot.series.length"), 5)
        self.wd.js("document.getElementById('scope').scrollIntoView()")
        self.wd.screenshot(os.path.join(OUT, "7-scope.png"))
        self.console("mode disable")


if __name__ == "__main__":
    unittest.main(verbosity=2)
