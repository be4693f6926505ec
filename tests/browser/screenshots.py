"""Draw docs/img/review.png and docs/img/api-docs.png: the README's skill ``stir`` as a person
sees it in a browser.

``python tests/browser/screenshots.py`` starts the service (uvicorn on 127.0.0.1, a temporary
data folder), does what the README's command-line section does (the four example demo files,
an ellipse fit, reproductions), opens ``/skills/stir/view`` and ``/docs`` in headless Chromium
and saves what they show, the review once it shows the canal and the demos (the same colour
check as tests/browser).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path[:0] = [str(HERE), str(ROOT / "tests")]

from canal_client import CanalClient  # noqa: E402
from canal_service.app import create_app  # noqa: E402
from canal_service.core.config import Settings  # noqa: E402
from canal_testing import LiveServer  # noqa: E402
from chromium import Chromium  # noqa: E402
from PIL import Image  # noqa: E402
from test_browser_pages import REVIEW_MINIMUM, VIEWER_TIMEOUT_S, review_shares  # noqa: E402

OUT = ROOT / "docs" / "img"
WIDTH = 1100  # pixels of the saved pictures


def save(pixels: object, path: Path) -> None:
    image = Image.fromarray(pixels)  # type: ignore[arg-type]
    image = image.resize((WIDTH, round(image.height * WIDTH / image.width)), Image.LANCZOS)
    image.save(path, optimize=True)
    print(f"wrote {path}")


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="canal-screenshots-") as data:
        app = create_app(Settings(data_dir=Path(data), zenoh_enabled=False))
        with LiveServer(app) as server, CanalClient(server.url) as client:
            client.create_skill("stir", dim=3)
            for path in sorted((ROOT / "examples" / "demos").glob("demo_*")):
                client.upload_demo_file("stir", path, **(
                    {"topic": "/ee_pose"} if path.suffix == ".mcap" else {}))
            client.fit("stir", cross_section="ellipse")
            for start in ([0.0, 0.02, 0.0], [0.02, -0.03, 0.01], [-0.05, 0.2, 0.0]):
                client.reproduce("stir", start)
            with Chromium(width=1400, height=860) as browser:
                browser.open(f"{server.url}/skills/stir/view")
                deadline = time.monotonic() + VIEWER_TIMEOUT_S
                while True:
                    browser.pump(2.0)
                    pixels = browser.screenshot()
                    shares = review_shares(pixels)
                    if all(shares[k] >= v for k, v in REVIEW_MINIMUM.items()):
                        break
                    if time.monotonic() > deadline:
                        print(f"the review did not show everything: {shares}")
                        return 1
                browser.pump(3.0)  # let the last frame settle
                save(browser.screenshot(), OUT / "review.png")
                browser.open(f"{server.url}/docs")
                while not browser.evaluate("document.querySelectorAll('.opblock').length > 5"):
                    browser.pump(0.5)
                save(browser.screenshot(), OUT / "api-docs.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
