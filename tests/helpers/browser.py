"""The viewer's page in a real browser: headless Chromium through Selenium (Debian's
chromium and chromium-driver), and what the tests read off the page's state
(`window.exabricks` on `exabricks view`'s page, `window.exabricksViews[i]` in a
notebook)."""

from __future__ import annotations

import base64
import io
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

PAGE = "window.exabricks"


def chromium():
    """A headless Chromium (the `browser` fixture, tests/conftest.py); skips without one."""
    webdriver = pytest.importorskip("selenium.webdriver")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    if not chromium or not driver_path:
        pytest.skip("Debian's chromium and chromium-driver are not installed")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1280,800",
                "--disable-gpu"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=driver_path))
    yield driver
    driver.quit()


def wait_for(driver, script, timeout=60):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for: {script}")


def converged(driver, after_version=-1, timeout=60, state=PAGE):
    """The header of the page's converged frame of its latest scene, newer than `after_version`."""
    return wait_for(driver, f"const s = {state}, f = s && s.frame; return f && f.stage === 'converged' && "
                            f"f.version > {after_version} && s.version === f.version ? f : null",
                    timeout)


def shown_png(driver, state=PAGE) -> bytes:
    """The PNG the page shows."""
    data = driver.execute_async_script(
        "const done = arguments[0], r = new FileReader(); r.onload = () => done(r.result); "
        f"r.readAsDataURL({state}.blob);")
    return base64.b64decode(data.split(",", 1)[1])


def screenshot(driver, name):
    keep = os.environ.get("EXABRICKS_VIEW_SCREENSHOTS")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(Path(keep) / name))


def assert_same_pixels(png: bytes, path):
    """The viewer's frame `png` is the picture in the .png at `path`, pixel for pixel."""
    from PIL import Image as PILImage

    viewer = np.asarray(PILImage.open(io.BytesIO(png)).convert("RGB"))
    np.testing.assert_array_equal(viewer, np.asarray(PILImage.open(path).convert("RGB")))
