"""What a person sees, in a real headless Chromium: the skill's review and the API docs.

The viewer must show the canal with the demonstrations and the reproduction visible through
it (found by their colours in the screenshot), its plots must hold data, and every page must
load from the service's own origin only (no CDN, no web fonts, no analytics).
"""

from __future__ import annotations

import time
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np
from chromium import Chromium, colour_share

#: Colours as the recorder logs them (recording/rerun_log.py) and Rerun draws them.
DEMO_BLUE = (90, 140, 240)
INSIDE_GREEN = (25, 190, 75)
RING_GREY = (60, 60, 60)
#: The radius bars' fill as Rerun's bar chart draws the recorder's radius colour.
RADIUS_BAR_FILL = (238, 226, 195)
#: Swagger UI's colours for GET and POST operations.
SWAGGER_GET = (97, 175, 254)
SWAGGER_POST = (73, 204, 144)
#: Rerun's web viewer compiles ~40 MB of WebAssembly on the CPU: tens of seconds on a busy
#: 2-core machine.
VIEWER_TIMEOUT_S = 180.0


def foreign_requests(browser: Chromium, origin: str) -> list[str]:
    """Every URL the page asked for that is not on ``origin`` (data: and blob: are local)."""
    own = urlsplit(origin)
    return [url for url in browser.requests
            if urlsplit(url).scheme not in ("data", "blob")
            and (urlsplit(url).scheme, urlsplit(url).netloc) != (own.scheme, own.netloc)]


def canal_view(pixels: np.ndarray) -> np.ndarray:
    """The 3-D view's part of a viewer screenshot (left of the plots, above the time panel)."""
    h, w = pixels.shape[:2]
    return pixels[int(0.07 * h):int(0.74 * h), int(0.15 * w):int(0.70 * w)]


def radius_plot(pixels: np.ndarray) -> np.ndarray:
    h, w = pixels.shape[:2]
    return pixels[int(0.07 * h):int(0.38 * h), int(0.72 * w):]


def review_shares(pixels: np.ndarray) -> dict[str, float]:
    view = canal_view(pixels)
    return {"demos": colour_share(view, DEMO_BLUE, 40),
            "reproduction": colour_share(view, INSIDE_GREEN, 40),
            "canal rings": colour_share(view, RING_GREY, 25),
            "radius bars": colour_share(radius_plot(pixels), RADIUS_BAR_FILL, 12)}


#: Least share of each colour for a review that shows it (a few hundred pixels at 1400x900).
REVIEW_MINIMUM = {"demos": 0.003, "reproduction": 0.0005, "canal rings": 0.003,
                  "radius bars": 0.05}


def test_viewer_shows_the_canal_with_demos_and_reproduction_inside(
        service_url: str, skill: str, browser: Chromium, tmp_path: Path) -> None:
    browser.requests.clear()
    browser.open(f"{service_url}/skills/{skill}/view")
    deadline = time.monotonic() + VIEWER_TIMEOUT_S
    shot = tmp_path / "review.png"
    while True:
        browser.pump(2.0)
        if browser.evaluate("window._handle !== undefined"):
            shares = review_shares(browser.save_screenshot(shot))
            if all(shares[k] >= v for k, v in REVIEW_MINIMUM.items()):
                break
        else:
            shares = {}
        assert time.monotonic() < deadline, (
            f"the viewer did not show the review within {VIEWER_TIMEOUT_S:.0f} s: colour shares "
            f"{shares} (least {REVIEW_MINIMUM}); last screenshot {shot}")
    browser.pump(1.0)  # anything the viewer asks for once running (analytics, updates)
    assert foreign_requests(browser, service_url) == []


def test_docs_pages_load_offline_from_the_service(
        service_url: str, browser: Chromium, tmp_path: Path) -> None:
    browser.requests.clear()
    browser.open(f"{service_url}/docs")
    deadline = time.monotonic() + 60.0
    while not browser.evaluate("document.querySelectorAll('.opblock').length > 5"):
        assert time.monotonic() < deadline, "Swagger UI listed no operations"
        browser.pump(0.5)
    pixels = browser.save_screenshot(tmp_path / "docs.png")
    assert colour_share(pixels, SWAGGER_GET, 12) > 0.001
    assert colour_share(pixels, SWAGGER_POST, 12) > 0.001
    assert browser.evaluate("document.body.innerText.includes('/skills/{name}/view')")

    browser.open(f"{service_url}/redoc")
    deadline = time.monotonic() + 60.0
    while not browser.evaluate("document.body.innerText.includes('/skills/{name}/view')"):
        assert time.monotonic() < deadline, "ReDoc showed no operations"
        browser.pump(0.5)
    browser.save_screenshot(tmp_path / "redoc.png")
    assert foreign_requests(browser, service_url) == []
