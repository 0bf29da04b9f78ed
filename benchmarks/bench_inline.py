"""The viewer in a notebook: frame latency over the widget's comm (eb.view) against
the viewer's own server reached through jupyter-server-proxy.

    .venv/bin/python -m benchmarks.bench_inline [--runs N] [--only KEY] [--write-docs]

A real JupyterLab (tests/helpers/jupyter.py) with jupyter-server-proxy, in headless
Chromium on this machine. One notebook shows the same dataset twice, with the
field of benchdoc, a 512² frame at 2 samples per pixel: (1) `eb.view`, the
widget, whose messages ride the kernel's channels; (2) `exabricks view`'s server
(exabricks.viewer.server.Viewer) started in the kernel and shown in an iframe at
the Jupyter server's `/proxy/PORT/`, with the Jupyter server's host added to the
hosts it accepts (what that route would need). Each run orbits the camera by 10
degrees from the page and times, in the page, from the change being sent to each
stage shown (received, decoded, on screen): the first (coarse) frame and the
converged one; "its transport" is the first frame's time less the time the
kernel took to draw the frame and make its PNG (the frame message's `ms`): the
route's own share, with the scene's checks and the page's decoding. Median and
min-max over the runs, after one warm-up, the routes alternating run by run.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from benchmarks import benchdoc

TITLE = "Viewer in a notebook: comm against jupyter-server-proxy"

SETUP = """import asyncio, threading
import exabricks as eb
from exabricks.viewer.server import Viewer
from exabricks.viewer.session import Session

ds = eb.open(r"{path}"{open_options})
options = dict(field="{field}", size=(512, 512), spp=2)
widget = eb.view(ds, **options)

class Proxied(Viewer):  # the Jupyter server's host and origin accepted
    def _allowed_hosts(self):
        return super()._allowed_hosts() | {{"127.0.0.1:{jupyter_port}"}}

loop = asyncio.new_event_loop()
threading.Thread(target=loop.run_forever, daemon=True).start()
server = Proxied(Session(ds, options=options))
url = asyncio.run_coroutine_threadsafe(server.start(), loop).result()
from IPython.display import IFrame, display
display(widget, IFrame(f"/proxy/{{server.port}}/?token={{server.token}}", width=1100, height=700))
"""

WIDGET = "window.exabricksViews && window.exabricksViews[0]"
# One change from the page: the camera orbited by 10 degrees, drawn not moving.
ORBIT = """const s = {state}, c = s.doc.camera, a = Math.PI / 18;
const dx = c.position[0] - c.look_at[0], dz = c.position[2] - c.look_at[2];
c.position = [c.look_at[0] + dx * Math.cos(a) - dz * Math.sin(a), c.position[1],
              c.look_at[2] + dx * Math.sin(a) + dz * Math.cos(a)];
s.send(false);"""
CONVERGED = "const s = {state}; return !!(s && s.frame && s.frame.stage === 'converged')"
DONE = ("const s = {state}, f = s.frame; return f && f.stage === 'converged' && s.sent && "
        "f.version === s.sent[0] && s.version === f.version ? s.latency.filter((l) => l.version === f.version) : null")


def measure(dataset, runs: int) -> dict[str, list[float]]:
    browser, jupyter = benchdoc.tests_module("helpers.browser"), benchdoc.tests_module("helpers.jupyter")
    chromium, wait_for, Lab = browser.chromium, browser.wait_for, jupyter.Lab

    driver_gen = chromium()
    driver = next(driver_gen)
    times = {f"{route}: {what}": [] for route in ("comm", "proxy")
             for what in ("first frame", "its transport", "converged")}
    with tempfile.TemporaryDirectory() as tmp:
        lab = Lab(Path(tmp), [])
        try:
            open_options = ', format="yt"' if dataset.key == "enzo" else ""
            lab.write([SETUP.format(path=dataset.path, open_options=open_options, field=dataset.field,
                                    jupyter_port=lab.port)])
            driver.set_window_size(1400, 1000)
            driver.get(lab.url())
            lab.run_all(driver)
            wait_for(driver, CONVERGED.format(state=WIDGET), timeout=300)
            frame = driver.find_element("css selector", "iframe")
            for run in range(runs + 1):
                for route in ("comm", "proxy"):
                    state = WIDGET
                    if route == "proxy":
                        driver.switch_to.frame(frame)
                        state = "window.exabricks"
                        wait_for(driver, CONVERGED.format(state=state), timeout=300)
                    driver.execute_script(ORBIT.format(state=state))
                    shown = wait_for(driver, DONE.format(state=state), timeout=120)
                    if run:
                        times[f"{route}: first frame"].append(shown[0]["ms"] / 1e3)
                        times[f"{route}: its transport"].append((shown[0]["ms"] - shown[0]["drawn"]) / 1e3)
                        times[f"{route}: converged"].append(shown[-1]["ms"] / 1e3)
                    driver.switch_to.default_content()
        finally:
            lab.stop()
            driver_gen.close()
    return times


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    benchdoc.add_common_args(parser, runs=10)
    args = parser.parse_args(argv)
    sets = benchdoc.datasets()
    keys = benchdoc.chosen(args.only, ["gerris", "amrex"])
    rows = []
    for key in keys:
        times = measure(sets[key], args.runs)
        rows.append((sets[key].name, times))
        print(key, json.dumps({k: round(benchdoc.median_spread(v)[0] * 1e3, 1) for k, v in times.items()}),
              flush=True)
    body = [__doc__.split("\n\n", 2)[2].strip(), "",
            f"{benchdoc.machine(opencl=True)}, headless Chromium, JupyterLab; "
            f"`python -m benchmarks.bench_inline --runs {args.runs}`.", "", *benchdoc.ms_table(rows)]
    benchdoc.publish(TITLE, "\n".join(body), args.write_docs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
