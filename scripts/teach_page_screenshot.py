"""The README's teaching-page screenshot (``docs/teach-page.png``), taken in a real browser.

Starts ``gpl-dist serve`` for a run on a free loopback port, and with Debian's headless Chromium
(playwright drives it): a new episode, the first attempt, a correction with an unknown word typed
(highlighted, the closest phrasing offered), the corrected text sent, the oracle's correction run
beside, every still loaded; then a full-page screenshot. Needs the test extra (playwright) and
chromium::

    gpl-dist suite restore docs/paper-report/runs --out runs/paper
    python scripts/teach_page_screenshot.py --run-dir runs/paper/multiroom-gpl/seed0 --out docs/teach-page.png

For another domain, give its task and, optionally, the corrections to type: without
``--correction`` the first correction typed is what the run's oracle would say (its hint), and
without ``--misspelt`` no unknown word is typed::

    python scripts/teach_page_screenshot.py --run-dir runs/babyai/babyai-gpl/seed0 --task 1170 --seed 0 \
        --correction "" --misspelt "" --out babyai-teach.png
"""

from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import sys
import tempfile
import time


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait(port: int, server: subprocess.Popen, seconds: float = 300) -> None:
    deadline = time.time() + seconds
    while time.time() < deadline:
        if server.poll() is not None:
            raise SystemExit(f"gpl-dist serve exited with {server.returncode}")
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise SystemExit(f"gpl-dist serve did not listen on {port} within {seconds:.0f} s")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run-dir", required=True, help="the run to teach (a restored suite run will do)")
    parser.add_argument("--out", required=True, help="the PNG to write")
    parser.add_argument("--task", type=int, default=263, help="task id (default 263, a held-out test task)")
    parser.add_argument("--seed", type=int, default=1, help="episode seed (default 1)")
    parser.add_argument("--correction", default="enter the grey room",
                        help="the first correction typed ('': what the run's oracle would say, its hint)")
    parser.add_argument("--misspelt", default="enter the rd room",
                        help="a correction with an unknown word, left typed in the box ('': none)")
    args = parser.parse_args()
    from playwright.sync_api import expect, sync_playwright

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if not chromium:
        raise SystemExit("needs Debian's chromium (apt-get install chromium)")
    gpl_dist = shutil.which("gpl-dist") or f"{sys.executable} -m gpl_dist.cli"
    port = _free_port()
    with tempfile.TemporaryDirectory() as logs:
        server = subprocess.Popen([gpl_dist, "serve", "--run-dir", args.run_dir, "--port", str(port), "--out", logs],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            _wait(port, server)
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=chromium, headless=True, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1480, "height": 900})
                page.goto(f"http://127.0.0.1:{port}/")
                page.fill("#task", str(args.task))
                page.fill("#seed", str(args.seed))
                page.click("#new")
                expect(page.locator(".attempt")).to_have_count(1, timeout=120_000)
                correction = args.correction
                if not correction:  # the oracle's sentence, as the page's Hint shows it
                    page.click("#hint-button")
                    expect(page.locator("#hint")).to_contain_text("The oracle would say: ", timeout=120_000)
                    correction = page.locator("#hint").inner_text().split("The oracle would say: ", 1)[1].strip()
                page.fill("#correction", correction)
                page.click("#send")
                expect(page.locator(".attempt")).to_have_count(2, timeout=120_000)
                page.click("#oracle-button")
                expect(page.locator(".attempt.oracle")).to_have_count(1, timeout=120_000)
                if args.misspelt:  # shown highlighted, with the closest phrasing
                    page.fill("#correction", args.misspelt)
                    expect(page.locator("#echo .unknown")).to_have_count(1, timeout=10_000)
                page.wait_for_function("[...document.querySelectorAll('.attempt img')].every(i => i.complete && "
                                       "i.naturalWidth > 0) && document.querySelectorAll('.loading').length === 0",
                                       timeout=120_000)
                page.locator("#scrub").fill("100")  # every attempt at its last step
                page.screenshot(path=args.out, full_page=True)
                browser.close()
        finally:
            server.terminate()
            server.wait(timeout=30)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
