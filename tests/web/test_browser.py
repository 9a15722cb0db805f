"""The web app in a real headless Chromium (Debian's chromium + chromium-driver) driven by Selenium.

The numbers the page shows must equal ``facestats query --format json`` for the
same filters; plots must be drawn; a subject page must show its maps.  A
screenshot of each page is saved under ``test-artefacts/`` (or
``$FACESTATS_ARTEFACTS``).
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import threading

import pytest

from facestats.cli import main as cli_main

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (test extra)")
pytest.importorskip("flask", reason="Flask is not installed (web extra)")
if not (CHROMIUM and CHROMEDRIVER) and os.environ.get("CI"):
    # CI installs them (the README's test command): their absence there is a failure, not a skip.
    raise RuntimeError("CI: headless Chromium and its driver are missing (apt-get install chromium chromium-driver)")
pytestmark = pytest.mark.skipif(
    not (CHROMIUM and CHROMEDRIVER),
    reason="headless Chromium and its driver are not installed (apt-get install chromium chromium-driver)",
)
ARTEFACTS = pathlib.Path(
    os.environ.get("FACESTATS_ARTEFACTS", pathlib.Path(__file__).resolve().parents[2] / "test-artefacts")
)


@pytest.fixture(scope="module")
def store_path(tmp_path_factory):
    from tests.helpers import store_from_default

    return store_from_default(tmp_path_factory.mktemp("web") / "small.zarr")


@pytest.fixture(scope="module")
def server(store_path):
    from facestats.web import create_app, make_server

    app = create_app(store_path)
    srv = make_server(app, "127.0.0.1", 0)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{srv.server_port}/"
    srv.shutdown()
    srv.server_close()


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = CHROMIUM
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--window-size=1400,2400",
        f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}",
    ):
        opts.add_argument(flag)  # fmt: skip
    drv = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    drv.set_page_load_timeout(60)
    yield drv
    drv.quit()


def _wait(drv, condition, timeout=60):
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(drv, timeout, poll_frequency=0.1).until(lambda d: condition(d))


def _cli_json(store_path, *args, capsys):
    capsys.readouterr()
    rc = cli_main(["query", "--store", store_path, "--format", "json", *args])
    return rc, json.loads(capsys.readouterr().out)


def _lookup(doc, key):
    """The value at a cell's ``data-key``: list steps are region numbers (rows with a "region") or 1-based."""
    node = doc
    for part in key.split("."):
        if part.isdigit() and isinstance(node, list):
            rows = [r for r in node if isinstance(r, dict) and r.get("region") == int(part)]
            node = rows[0] if rows else node[int(part) - 1]
        else:
            node = node[part]
    return node


def _screenshot(drv, name):
    ARTEFACTS.mkdir(parents=True, exist_ok=True)
    drv.save_screenshot(str(ARTEFACTS / name))


def test_population_page_numbers_equal_cli_json_and_plots_render(driver, server, store_path, capsys):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    driver.get(server)
    _wait(driver, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-count") is not None)
    for skin, gender in (("III", ""), ("IV", "M")):
        Select(driver.find_element(By.NAME, "skin_type")).select_by_value(skin)
        Select(driver.find_element(By.NAME, "gender")).select_by_value(gender)
        want = "skin_type=" + skin + (f"&gender={gender}" if gender else "") + "&condition=normal"  # the default
        _wait(driver, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-query") == want)
        _, doc = _cli_json(store_path, "--skin-type", skin, *(["--gender", gender] if gender else []), capsys=capsys)
        assert driver.find_element(By.TAG_NAME, "body").get_attribute("data-count") == str(doc["count"])
        cells = driver.find_elements(By.CSS_SELECTOR, "td[data-value]")
        assert len(cells) >= 10 * 12 + 3 * 2 + 9
        # Within-subject uncertainty beside the between-subject spread: every region and BRDF parameter.
        se = driver.find_elements(By.CSS_SELECTOR, "td[data-key$='.mean_se'][data-value]")
        assert len(se) == 10 * 4 and all(float(c.get_attribute("data-value")) > 0 for c in se)
        for cell in cells:
            expected = _lookup(doc, cell.get_attribute("data-key"))
            assert float(cell.get_attribute("data-value")) == expected  # exactly the CLI's number
            assert float(cell.text) == pytest.approx(expected, rel=5e-4)  # shown to 4 digits
        links = [a.text for a in driver.find_elements(By.CSS_SELECTOR, "a.subject-link")]
        assert links == doc["subject_ids"]
    # Condition and region filters: the page shows what the CLI prints for them.
    Select(driver.find_element(By.NAME, "skin_type")).select_by_value("")
    Select(driver.find_element(By.NAME, "gender")).select_by_value("")
    Select(driver.find_element(By.NAME, "condition")).select_by_value("normal")
    Select(driver.find_element(By.NAME, "region")).select_by_value("6")
    _wait(
        driver, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-query") == "condition=normal&region=6"
    )
    _, doc = _cli_json(store_path, "--condition", "normal", "--region", "6", capsys=capsys)
    assert driver.find_element(By.TAG_NAME, "body").get_attribute("data-count") == str(doc["count"])
    cells = driver.find_elements(By.CSS_SELECTOR, "td[data-value]")
    assert cells and all(
        float(c.get_attribute("data-value")) == _lookup(doc, c.get_attribute("data-key")) for c in cells
    )
    Select(driver.find_element(By.NAME, "condition")).select_by_value("any")
    Select(driver.find_element(By.NAME, "region")).select_by_value("")
    _wait(driver, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-query") == "condition=any")
    # Plots: three albedo histograms with bars, four region bar charts, the scatter, the PCA ellipses.
    hist = driver.find_elements(By.CSS_SELECTOR, "svg.histogram")
    assert [h.get_attribute("data-channel") for h in hist] == ["R", "G", "B"]
    assert all(len(h.find_elements(By.TAG_NAME, "rect")) > 5 for h in hist)
    assert len(driver.find_elements(By.CSS_SELECTOR, "svg.bars")) == 4
    _wait(driver, lambda d: len(d.find_elements(By.CSS_SELECTOR, "#scatter-plot .point")) > 0)
    _wait(driver, lambda d: len(d.find_elements(By.CSS_SELECTOR, "#pca-plot path.ellipse")) == 10)
    n_points = len(driver.find_elements(By.CSS_SELECTOR, "#scatter-plot .point"))
    assert n_points == 3 * doc["count"]
    box = driver.find_element(By.ID, "pca-plot").size
    assert box["width"] > 100 and box["height"] > 100
    _screenshot(driver, "population.png")


def test_invalid_filter_shows_the_api_error_text(driver, server, store_path, capsys):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    from facestats.errors import FacestatsError
    from facestats.io import open_store
    from facestats.web.app import error_text

    driver.get(server)
    _wait(driver, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-count") is not None)
    box = driver.find_element(By.NAME, "age")
    box.send_keys("ninety", Keys.TAB)
    _wait(driver, lambda d: d.find_element(By.TAG_NAME, "body").get_attribute("data-count") == "error")
    with open_store(store_path) as st, pytest.raises(FacestatsError) as api:
        st.query(age="ninety")
    assert driver.find_element(By.ID, "error").text == error_text(api.value)
    capsys.readouterr()  # the command line prints the same message, naming its option (--age) for the field
    assert cli_main(["query", "--store", store_path, "--age", "ninety"]) == 2
    assert capsys.readouterr().err.strip() == error_text(api.value).replace("error: age must", "error: --age must")


def test_subject_page_shows_its_maps_and_preview(driver, server):
    from selenium.webdriver.common.by import By

    driver.get(server + "subject/S002")
    _wait(driver, lambda d: d.execute_script("return document.readyState") == "complete")
    imgs = driver.find_elements(By.CSS_SELECTOR, "img.map") + [driver.find_element(By.ID, "preview")]
    names = [i.get_attribute("alt") for i in imgs]
    assert {"albedo", "normal", "ts_rho_s", "ts_m", "region", "modulation", "preview"} <= set(names)
    _wait(driver, lambda d: all(d.execute_script("return arguments[0].complete", i) for i in imgs))
    widths = [driver.execute_script("return arguments[0].naturalWidth", i) for i in imgs]
    assert all(w == 48 * 4 for w in widths), widths  # 48² maps shown at 4×
    _screenshot(driver, "subject.png")
    driver.get(server + "subject/S999")
    assert "facestats: error: subject 'S999' is not in store" in driver.find_element(By.ID, "error").text
