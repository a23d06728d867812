"""Headless Chromium (Debian's ``chromium`` + ``chromium-driver``) driven by Selenium.

Why Debian's browser: nothing may be downloaded at run time here, so Selenium Manager and
Playwright's browser downloads are out; ``make test-browser`` installs the two packages.
``chromium_missing()`` is the one reason a browser test may skip.
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--hide-scrollbars"]


def chromium_missing() -> str | None:
    """Why the browser cannot run, or None when it can."""
    for path, pkg in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")):
        if not Path(path).exists() and not shutil.which(Path(path).name):
            return (f"{path} not installed (Debian package {pkg}): run `make test-browser`, "
                    "which installs chromium and chromium-driver")
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[test]')"
    return None


def start_chromium(width: int = 1400, height: int = 1000) -> tuple[Any, Path]:
    """A fresh headless Chromium with its own profile dir; returns (driver, profile dir).
    The browser log is captured at level ALL so a test can assert there is no error."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = Path(tempfile.mkdtemp(prefix="siva-chromium-"))
    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or CHROMIUM
    for f in FLAGS:
        opts.add_argument(f)
    opts.add_argument(f"--user-data-dir={profile}")
    opts.add_argument(f"--window-size={width},{height}")
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    service = Service(executable_path=shutil.which("chromedriver") or CHROMEDRIVER)
    driver = webdriver.Chrome(options=opts, service=service)
    return driver, profile


def full_page_screenshot(driver: Any, path: Path, width: int = 1400) -> None:
    """Resize the window to the page's height, then save a PNG of the whole page."""
    height = int(driver.execute_script(
        "return Math.max(document.body.scrollHeight, document.documentElement.scrollHeight)"))
    driver.set_window_size(width, min(max(height + 40, 600), 6000))
    path.parent.mkdir(parents=True, exist_ok=True)
    driver.save_screenshot(str(path))


def console_errors(driver: Any) -> list[dict[str, Any]]:
    """Entries of the browser console at level SEVERE (JS errors, failed loads)."""
    return [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]


#: JS: how many canvases have non-blank pixels, how many uPlot instances are on the page
DRAWN_JS = """
const out = {canvases: 0, drawn: 0, uplots: document.querySelectorAll('.uplot').length};
for (const c of document.querySelectorAll('canvas')) {
  out.canvases++;
  if (!c.width || !c.height) continue;
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 3; i < d.length; i += 4) if (d[i] !== 0) { n++; if (n > 50) break; }
  if (n > 50) out.drawn++;
}
return out;
"""
