"""A real JupyterLab (or Notebook 7) server for the tests and the benchmarks: started
on a free loopback port with a token of its own, a notebook of given cells in its
root, the app exposed to the page (`window.jupyterapp`), and a client on the
notebook's kernel (jupyter_client) to read what the kernel holds."""

from __future__ import annotations

import json
import os
import secrets
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path


class Lab:
    def __init__(self, root: Path, cells: list[str], *, env: dict | None = None, name: str = "view.ipynb"):
        self.root = Path(root)
        self.runtime = self.root / "runtime"
        self.token = secrets.token_hex(16)
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        # no "news?" prompt over the page
        settings = self.root / "settings" / "@jupyterlab" / "apputils-extension"
        settings.mkdir(parents=True)
        (settings / "notification.jupyterlab-settings").write_text('{"fetchNews": "false"}')
        self.name = name
        self.write(cells)
        self.log = open(self.root / "jupyter.log", "w")  # noqa: SIM115 (closed in stop)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "jupyterlab", "--no-browser", "--ServerApp.ip=127.0.0.1",
             f"--ServerApp.port={self.port}", f"--IdentityProvider.token={self.token}", "--allow-root",
             f"--ServerApp.root_dir={self.root}", "--LabApp.expose_app_in_browser=True",
             "--JupyterNotebookApp.expose_app_in_browser=True",
             "--ServerApp.port_retries=0"],
            stdout=self.log, stderr=subprocess.STDOUT,
            env={**os.environ, **(env or {}), "JUPYTER_RUNTIME_DIR": str(self.runtime),
                 "JUPYTERLAB_SETTINGS_DIR": str(self.root / "settings")})
        deadline = time.monotonic() + 120
        while True:
            try:
                urllib.request.urlopen(f"{self.base}/api/status?token={self.token}", timeout=5)
                break
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise AssertionError("JupyterLab did not start: " + self.output()) from None
                time.sleep(0.2)

    def write(self, cells: list[str]) -> None:
        """The notebook: a code cell of each of `cells`."""
        import nbformat

        notebook = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
        notebook.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
        nbformat.write(notebook, self.root / self.name)

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def url(self, app: str = "lab") -> str:
        """The notebook's page in JupyterLab ("lab") or Notebook 7 ("notebooks")."""
        where = "lab/tree" if app == "lab" else "notebooks"
        return f"{self.base}/{where}/{self.name}?token={self.token}"

    def output(self) -> str:
        self.log.flush()
        return (self.root / "jupyter.log").read_text()[-6000:]

    def run_all(self, driver, timeout=120) -> None:
        """Run the notebook's cells in `driver`'s page once its kernel is idle."""
        deadline = time.monotonic() + timeout
        ready = ("const app = window.jupyterapp, w = app && app.shell.currentWidget, "
                 "k = w && w.sessionContext && w.sessionContext.session && w.sessionContext.session.kernel; "
                 "return !!k && k.connectionStatus === 'connected' && k.status === 'idle';")
        while not driver.execute_script(ready):
            if time.monotonic() > deadline:
                raise AssertionError("the notebook's kernel did not start: " + self.output())
            time.sleep(0.1)
        driver.execute_script("window.jupyterapp.commands.execute('notebook:run-all-cells')")

    def kernel(self, timeout=60):
        """A client on the notebook's kernel (the only one this server started)."""
        from jupyter_client import BlockingKernelClient

        deadline = time.monotonic() + timeout
        while not (files := sorted(self.runtime.glob("kernel-*.json"))):
            if time.monotonic() > deadline:
                raise AssertionError("no kernel: " + self.output())
            time.sleep(0.1)
        client = BlockingKernelClient(connection_file=str(files[0]))
        client.load_connection_file()
        client.start_channels()
        client.wait_for_ready(timeout=timeout)
        return client

    def evaluate(self, code: str, timeout=120):
        """The JSON that `code`, run in the notebook's kernel, prints."""
        client = self.kernel()
        printed = []

        def hook(msg):
            if msg["msg_type"] == "stream":
                printed.append(msg["content"]["text"])
            elif msg["msg_type"] == "error":
                printed.append("\n".join(msg["content"]["traceback"]))

        try:
            reply = client.execute_interactive(code, output_hook=hook, timeout=timeout)
        finally:
            client.stop_channels()
        assert reply["content"]["status"] == "ok", "".join(printed)
        return json.loads("".join(printed))

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.log.close()
