"""The `siva diagnose` HTML report in a real browser (headless Chromium), and the CLI's
progress lines.

The report is a self-contained page (embedded PNGs, no scripts): in a browser every figure
must decode, nothing may be logged at SEVERE level, and nothing may scroll sideways.  The
diagnosis behind it is the Duffing case (1 DOF, ~2 s).  Skips only when chromium /
chromium-driver are not installed (like the dashboard test) or the shared data is absent.
With ``SIVA_SCREENSHOT_DIR`` set, the full page is saved as ``diagnosis_report.png`` there.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from browser_support import (chromium_missing, console_errors,  # noqa: E402
                             full_page_screenshot, start_chromium)

from siva_core import diagnose, html_report  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("SIVA_SHARED_DATA") or ROOT.parent / "shared" / "data")
needs_duffing = pytest.mark.skipif(not (DATA / "duffing").is_dir(),
                                   reason="shared reference data not available")
needs_chromium = pytest.mark.skipif(chromium_missing() is not None, reason=str(chromium_missing()))

#: JS: figures (all decoded, with a size), widest element against the viewport
RENDERED_JS = """
const imgs = [...document.images];
return {images: imgs.length,
        decoded: imgs.filter(i => i.complete && i.naturalWidth > 0).length,
        scroll_width: document.documentElement.scrollWidth,
        client_width: document.documentElement.clientWidth,
        text: document.body.innerText};
"""


@needs_chromium
def test_report_renders_in_chromium_without_console_errors(tmp_path, duffing_without_cubic_damper):
    model, train, val = duffing_without_cubic_damper
    page = tmp_path / "diagnosis.html"
    page.write_text(html_report(diagnose(model, train, val, "auto")))
    driver, _ = start_chromium(width=1200, height=900)
    try:
        driver.get(page.as_uri())
        got = driver.execute_script(RENDERED_JS)
        errors = console_errors(driver)
        if os.environ.get("SIVA_SCREENSHOT_DIR"):
            full_page_screenshot(driver, Path(os.environ["SIVA_SCREENSHOT_DIR"])
                                 / "diagnosis_report.png", width=1200)
    finally:
        driver.quit()
    assert not errors, errors
    assert got["images"] >= 4 and got["decoded"] == got["images"], got
    assert got["scroll_width"] <= got["client_width"] + 1, "the page scrolls sideways"
    text = got["text"]
    assert "cubic_damper" in text and "[[elements]]" in text and "N s/m^3" in text


@needs_duffing
def test_cli_prints_progress_with_an_eta(tmp_path, capsys):
    from siva_core.cli import main

    folder = DATA / "duffing"
    model = ROOT / "examples" / "models" / "duffing.toml"
    rc = main(["diagnose", str(model), "--train", str(folder / "train_v5.csv"),
               "--val", str(folder / "val_v3.csv"), "--out", str(tmp_path / "d.json")])
    assert rc == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("diagnose: ")]
    assert lines and lines[-1].startswith("diagnose: 100 %"), err[-2000:]
    assert any("ETA" in ln for ln in lines[:-1]), lines  # the first update is printed at once


def test_fraction_progress_eta_from_the_mean_rate():
    from siva_core import FractionProgress

    now = [100.0]
    p = FractionProgress("diagnose", clock=lambda: now[0])
    now[0] += 10.0
    assert p.text(0.25) == "diagnose: 25 %, 10 s elapsed, ETA 30 s"
    now[0] += 80.0
    assert p.text(1.0) == "diagnose: 100 %, 1 min 30 s elapsed"
