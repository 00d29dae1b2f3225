"""Screenshot of the `cogail play` page in headless Chromium, after scripted key presses (the README's figures).

    python experiments/play_screenshot.py --run RUN --out docs/play-fetchq.png --keys ArrowUp:1.2,ArrowLeft:0.5

--keys: comma-separated KEY:SECONDS holds, in order (selenium key names such as ArrowUp, or letters: w, e, ...).
Needs chromium and chromedriver (`make test` installs them).
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import threading
import time
from pathlib import Path

SELENIUM_KEYS = {"ArrowUp": "ARROW_UP", "ArrowDown": "ARROW_DOWN", "ArrowLeft": "ARROW_LEFT",
                 "ArrowRight": "ARROW_RIGHT", "Space": "SPACE"}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", required=True, action="append")
    p.add_argument("--out", required=True)
    p.add_argument("--keys", default="", help="KEY:SECONDS,... held in order before the screenshot")
    p.add_argument("--hz", type=float, default=15.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--size", default="1160,700", help="browser window W,H")
    a = p.parse_args(argv)

    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support.ui import WebDriverWait

    from cogail_jax import play

    trials = Path(tempfile.mkdtemp()) / "trials.hdf5"  # screenshots leave no trials behind
    srv = play.open_session(a.run, port=0, trials=trials, hz=a.hz, seed=a.seed)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium") or shutil.which("chromium-browser")
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--hide-scrollbars",
                f"--window-size={a.size}"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)
    try:
        driver.get(f"http://127.0.0.1:{srv.server_address[1]}/")
        WebDriverWait(driver, 120).until(
            lambda d: d.find_element(By.ID, "status").get_attribute("data-status") == "ready")
        for item in filter(None, a.keys.split(",")):
            key, secs = item.split(":")
            key = getattr(Keys, SELENIUM_KEYS[key]) if key in SELENIUM_KEYS else key
            ActionChains(driver).key_down(key).pause(float(secs)).key_up(key).perform()
        time.sleep(2.0 / a.hz + 0.3)  # let the last answer arrive
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(a.out)
        print(f"wrote {a.out}")
    finally:
        driver.quit()
        srv.shutdown()
        play.close(srv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
