"""The report page's image viewer in a real browser: headless Chromium (Debian's `chromium` and
`chromium-driver`) driven by Selenium opens a page written by `write_viewer` from a file:// URL, with
synthetic float images of known values, and does what a user does: switches images by keys, zooms in by
keys at the mouse, moves the mouse to a pixel, raises the exposure. It fails on any console error and
checks that the readout shows each image's exact float32 value and that the screen shows that pixel as
a nearest-neighbour square in its sRGB colour.

Skips only where Chromium or Selenium is absent and CI is not set; in CI (CI=true) it runs. `make
test-browser` runs it alone; VIEWER_SCREENSHOT=path.png saves the screenshot it takes."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from validation.viewer import BlockTest, Plot, Series, write_viewer

CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")
H, W = 48, 64
PIXEL = (53, 29)  # (x, y): the pixel the mouse reads; inside the rejected block (3, 2) of a 4 x 4 map


def _absent(reason: str):
    if CI:
        pytest.fail(f"CI=true but {reason} (scripts/setup.sh installs it)")
    pytest.skip(f"{reason}: install it to run the browser test (as root: bash scripts/setup.sh)")


@pytest.fixture(scope="module")
def browser():
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        _absent("selenium is not installed (the test extra: pip install -e .[test])")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    chromedriver = shutil.which("chromedriver")
    if not (chromium and chromedriver):
        _absent("headless Chromium is absent (Debian: apt-get install chromium chromium-driver)")
    options = Options()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1400,1100", "--force-device-scale-factor=1", "--hide-scrollbars"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    # the system driver, so that Selenium Manager downloads nothing
    driver = webdriver.Chrome(service=Service(executable_path=chromedriver), options=options)
    yield driver
    driver.quit()


def synthetic_images() -> dict[str, np.ndarray]:
    """A bright disc on a gradient (values up to 8, HDR), the 'tracer' with multiplicative noise, and an
    'albedo'; every value a float32 with a full mantissa, and one pixel with extreme values."""
    rng = np.random.default_rng(17)
    y, x = np.mgrid[0:H, 0:W] + 0.5
    disc = ((x - 22) ** 2 + (y - 20) ** 2 < 12 ** 2) * 8.0
    reference = np.stack([0.05 + 0.6 * x / W, 0.1 + 0.4 * y / H, 0.3 + 0 * x], -1) + disc[..., None] * [1, 0.8, 0.5]
    reference = (reference * rng.uniform(0.97, 1.03, reference.shape)).astype(np.float32)
    tracer = (reference * rng.uniform(0.8, 1.2, reference.shape)).astype(np.float32)
    tracer[PIXEL[1], PIXEL[0]] = [3.1415927e-07, 0.123456789, 12345.678]
    albedo = rng.uniform(0, 1, reference.shape).astype(np.float32)
    return {"tracer": tracer, "Mitsuba": reference, "albedo": albedo}


def srgb8(v: float) -> int:
    v = min(max(v, 0.0), 1.0)
    return round(255 * (12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055))


@pytest.mark.slow   # a browser start: `make test-browser` runs it alone
def test_viewer_in_chromium(browser, tmp_path: Path):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.actions.wheel_input import ScrollOrigin
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select, WebDriverWait

    images = synthetic_images()
    p = np.full((4, 4, 3), 0.5)
    p[2, 3, 1] = 1e-9
    page = write_viewer(
        tmp_path / "report", "synthetic images: the browser test's page", images, compare=("tracer", "Mitsuba"),
        block_test=BlockTest(p, threshold=1e-4, label="Welch's t-test"),
        plots=[Plot("RMSE against time", "seconds", "RMSE", [Series("tracer", [0.1, 1, 10], [0.3, 0.1, 0.03],
                                                                    hover=["1 spp", "10 spp", "100 spp"])],
                    log_x=True, log_y=True)],
        tables=[("Table 1", "| N | RMSE |\n|---|---:|\n| 8 | 0.43 |")], verdicts=["**FAIL**: 1 of 16 blocks rejected"],
        provenance={"machine": "test"})
    console = []

    def errors():
        console.extend(browser.get_log("browser"))
        return [e for e in console if e["level"] == "SEVERE"]

    browser.get(page.as_uri())
    WebDriverWait(browser, 20).until(lambda d: d.execute_script("return window.viewer !== undefined"))
    assert errors() == []
    names = browser.execute_script("return viewer.views")
    assert names[:3] == ["tracer", "Mitsuba", "albedo"] and len(names) == 6
    assert browser.execute_script("return document.querySelectorAll('.js-plotly-plot .main-svg').length") > 0

    view = lambda: browser.execute_script("return viewer.state.view")  # noqa: E731
    keys = ActionChains(browser)
    for key, expected in (("2", 1), ("\ue014", 2), ("\ue014", 3), ("\ue012", 2), ("1", 0)):  # ArrowRight, ArrowLeft
        keys.send_keys(key).perform()
        assert view() == expected, f"after key {key!r}"
    active = browser.find_element(By.CSS_SELECTOR, "#view-buttons button.active").text
    assert active == "1 tracer"

    def hover(x: int, y: int) -> None:  # the mouse to the centre of image pixel (x, y)
        cx, cy = browser.execute_script("return viewer.imageToClient(arguments[0], arguments[1])", x + 0.5, y + 0.5)
        actions = ActionChains(browser)
        actions.w3c_actions.pointer_action.move_to_location(int(cx), int(cy))
        actions.perform()

    def screen(dx: float, dy: float) -> list[int]:  # the canvas's colour at a point of PIXEL, in its units
        cx, cy = browser.execute_script(
            "const r = document.getElementById('canvas').getBoundingClientRect(), k = window.devicePixelRatio;"
            "const [x, y] = viewer.imageToClient(arguments[0], arguments[1]);"
            "return [(x - r.left) * k, (y - r.top) * k];", PIXEL[0] + dx, PIXEL[1] + dy)
        return browser.execute_script(
            "return Array.from(document.getElementById('canvas').getContext('2d')"
            ".getImageData(arguments[0], arguments[1], 1, 1).data.slice(0, 3))", int(cx), int(cy))

    canvas_box = "const r = document.getElementById('canvas').getBoundingClientRect(); return [r.width, r.height]"
    size = browser.execute_script(canvas_box)
    hover(*PIXEL)
    assert browser.execute_script(canvas_box) == size, "the readout filling in moved the image"
    scale = browser.execute_script("return viewer.state.scale")
    for _ in range(3):
        keys.send_keys("z").perform()
    assert browser.execute_script("return viewer.state.scale") == 8 * scale
    hover(*PIXEL)
    assert browser.find_element(By.ID, "readout-pixel").text == f"pixel ({PIXEL[0]}, {PIXEL[1]})"
    backing, css = browser.execute_script(  # the browser does not rescale the canvas's bitmap
        "const c = document.getElementById('canvas'), r = c.getBoundingClientRect(), k = window.devicePixelRatio;"
        "return [[c.width, c.height], [Math.round(r.width * k), Math.round(r.height * k)]]")
    assert backing == css

    def readout(view_index: int) -> np.ndarray:
        return np.array([np.float32(browser.find_element(
            By.CSS_SELECTOR, f'#readout td[data-view="{view_index}"][data-channel="{c}"]').text) for c in range(3)])

    x, y = PIXEL
    for i, image in enumerate(images.values()):
        np.testing.assert_array_equal(readout(i), image[y, x], err_msg=f"readout of {names[i]}")
    np.testing.assert_array_equal(readout(3), images["tracer"][y, x] - images["Mitsuba"][y, x])

    # nearest neighbour: the whole screen square of the pixel has its colour (away from the outlines)
    expected = [srgb8(float(v)) for v in images["tracer"][y, x]]
    assert screen(0.25, 0.25) == expected and screen(0.75, 0.8) == expected
    keys.send_keys("+").send_keys("+").perform()
    assert browser.execute_script("return document.getElementById('exposure-value').textContent") == "+1.0 EV"
    assert screen(0.5, 0.5) == [srgb8(2 * float(v)) for v in images["tracer"][y, x]]
    np.testing.assert_array_equal(readout(0), images["tracer"][y, x])  # linear values, not exposed ones

    keys.send_keys("4").perform()
    assert browser.find_element(By.ID, "transform").get_attribute("value") == "signed"
    keys.send_keys("t").perform()
    assert browser.find_element(By.ID, "transform").get_attribute("value") == "magnitude"
    keys.send_keys("6").perform()
    assert "block (2, 3)" in browser.find_element(By.ID, "readout-block").text
    assert "rejected at p < 0.000100" in browser.find_element(By.ID, "readout-block").text

    keys.send_keys("1").perform()
    Select(browser.find_element(By.ID, "transform")).select_by_value("signed")  # by the menu ...
    keys.send_keys("2").perform()  # ... and the keys still reach the viewer
    assert view() == 1
    keys.send_keys("1").perform()
    Select(browser.find_element(By.ID, "transform")).select_by_value("srgb")
    keys.send_keys("0").send_keys("f").perform()  # exposure back, fit
    hover(*PIXEL)
    before = browser.execute_script("return [viewer.state.tx, viewer.state.ty, viewer.state.scale]")
    ActionChains(browser).click_and_hold().move_by_offset(40, 30).release().perform()  # drag pans
    after = browser.execute_script("return [viewer.state.tx, viewer.state.ty, viewer.state.scale]")
    assert after == [before[0] + 40, before[1] + 30, before[2]]
    canvas = browser.find_element(By.ID, "canvas")
    ActionChains(browser).scroll_from_origin(ScrollOrigin.from_element(canvas), 0, -240).perform()  # wheel zooms in
    WebDriverWait(browser, 5).until(lambda d: d.execute_script("return viewer.state.scale") > before[2])
    keys.send_keys("f").perform()
    hover(*PIXEL)
    shot = tmp_path / "viewer.png"
    browser.save_screenshot(str(shot))
    if os.environ.get("VIEWER_SCREENSHOT"):
        shutil.copyfile(shot, os.environ["VIEWER_SCREENSHOT"])
    assert errors() == [], "the page logged errors"
